"""Read likelihoods: closed-form values, robustness clips, the far rule, the oracle, and the
chunked (slots x candidates) evaluation against a brute-force sum."""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest
from scipy.special import logsumexp
from scipy.stats import norm

from pipeline.localisation import (
    EPS,
    Z_CLIP,
    ModelLikelihood,
    Observations,
    OracleLikelihood,
    fit_far_detection,
    localise_tags,
    observations_from_reads,
    pair_geometry,
    rssi_residual_std,
)
from pipeline.localisation.observations import local_xy_axes
from propagation import LinkBudget, antenna_frame_angles
from propagation.patterns import pose_rotation
from tests.helpers.localisation import (
    corridor_scenario,
    free_space_gain_db,
    sample_attempts,
)


class DetectionOnly:
    """fT = 0.8 inside 2 m, 0 beyond; no RSSI prediction."""

    rssi_range_dbm = (-80.0, -30.0)
    predicts_rssi = False

    def fT(self, d, a):  # noqa: N802
        return np.where(np.asarray(d) < 2.0, 0.8, 0.0) + 0 * np.asarray(a)

    def fs_dbm(self, d, a):
        return np.full(np.broadcast(np.asarray(d), np.asarray(a)).shape, np.nan)

    fs = rho = fT


class Constant:
    """fT = p, fs_dbm = r everywhere (no sigma of its own)."""

    rssi_range_dbm = (-80.0, -30.0)

    def __init__(self, p, r):
        self.p, self.r = p, r

    def fT(self, d, a):  # noqa: N802
        return np.full(np.broadcast(np.asarray(d), np.asarray(a)).shape, self.p)

    def fs_dbm(self, d, a):
        return np.full(np.broadcast(np.asarray(d), np.asarray(a)).shape, self.r)

    fs = rho = fT


class BatchDependent(Constant):
    """Predictions that depend on the batch they are computed in, as a model rounding
    differently per batch size (ANFIS's matrix product for a single row) does."""

    def fT(self, d, a):  # noqa: N802
        return super().fT(d, a) + 1e-6 * np.size(d)

    def fs_dbm(self, d, a):
        return super().fs_dbm(d, a) - 1e-3 * np.size(d)


def test_pair_geometry_matches_propagation_frame():
    rng = np.random.default_rng(0)
    poses = np.column_stack([rng.uniform(-3, 3, (7, 3)), rng.uniform(-np.pi, np.pi, 7),
                             rng.uniform(-0.5, 0.5, 7), rng.uniform(-0.3, 0.3, 7)])
    pts = rng.uniform(-4, 4, (50, 3))
    ref = antenna_frame_angles(poses, pts)
    d, a = pair_geometry(poses, pts)
    # same arithmetic, reordered: agreement to rounding
    np.testing.assert_allclose(d, ref.d_m, atol=1e-12)
    np.testing.assert_allclose(a, ref.alpha_rad, atol=1e-12)
    d2, a2 = pair_geometry(poses, pts, alpha_within_m=3.0)
    near = d2 < 3.0
    np.testing.assert_allclose(a2[near], ref.alpha_rad[near], atol=1e-12)
    assert np.all(np.isnan(a2[~near]))


@pytest.mark.parametrize("one_mount", [True, False])
def test_local_xy_axes_are_pose_rotation_columns_bit_for_bit(one_mount):
    # the filter's geometry takes the mount's pitch and roll sines once: the axes must be
    # exactly rotation_matrix's (same operations, same order), or the filter's resampling
    # would drift from the bearings every other caller computes
    rng = np.random.default_rng(3)
    n = 257
    pitch = np.full(n, 0.31) if one_mount else rng.uniform(-0.5, 0.5, n)
    roll = np.full(n, -0.07) if one_mount else rng.uniform(-0.3, 0.3, n)
    poses = np.column_stack([rng.uniform(-3, 3, (n, 3)), rng.uniform(-np.pi, np.pi, n),
                             pitch, roll])
    rot = pose_rotation(poses)
    axes = local_xy_axes(poses)
    assert axes.shape == (n, 6)
    np.testing.assert_array_equal(axes[:, :3], rot[:, :, 0])
    np.testing.assert_array_equal(axes[:, 3:], rot[:, :, 1])
    assert local_xy_axes(np.zeros((0, 6))).shape == (0, 6)


def test_gaussian_likelihood_closed_form():
    lk = ModelLikelihood(Constant(0.7, -60.0), sigma_rssi_db=2.0)
    d, a = np.array([1.0, 1.0, 1.0, 1.0]), np.zeros(4)
    read = np.array([True, True, False, True])
    rssi = np.array([-61.0, np.nan, np.nan, -100.0])
    got = lk.log_likelihood(d, a, read, rssi)
    want = [np.log(0.7) + norm.logpdf(-61.0, -60.0, 2.0),
            np.log(0.7),  # read without an RSSI: detection only
            np.log(0.3),
            np.log(0.7) + norm.logpdf(Z_CLIP) - np.log(2.0)]  # 20 sigma residual clipped
    np.testing.assert_allclose(got, want, rtol=1e-12)


def test_probabilities_clipped_to_eps():
    for p, read, want in ((0.0, True, np.log(EPS)), (1.0, False, np.log(EPS)),
                          (0.0, False, np.log1p(-EPS)), (1.0, True, np.log1p(-EPS))):
        lk = ModelLikelihood(Constant(p, -60.0), use_rssi=False)
        got = lk.log_likelihood(1.0, 0.0, read, np.nan)
        assert got == pytest.approx(want, rel=1e-12)
        assert np.isfinite(got)


def test_model_without_rssi_uses_detection_only():
    lk = ModelLikelihood(DetectionOnly())  # no sigma needed: no RSSI term
    got = lk.log_likelihood(np.array([1.0, 1.0, 3.0]), 0.0, [True, True, False], [-50.0, -70.0, np.nan])
    np.testing.assert_allclose(got, [np.log(0.8), np.log(0.8), np.log1p(-EPS)])


def test_rssi_model_needs_a_sigma():
    with pytest.raises(ValueError, match="sigma_rssi_db"):
        ModelLikelihood(Constant(0.5, -60.0))
    ModelLikelihood(Constant(0.5, -60.0), use_rssi=False)  # detection only: fine


def test_model_sigma_is_used(sensor):
    lk = ModelLikelihood(sensor)  # SyntheticSensor has rssi_sigma_db = 2 dB
    d, a = 1.5, 0.2
    mu = float(sensor.fs_dbm(d, a))
    p = float(sensor.fT(d, a))
    got = lk.log_likelihood(d, a, True, mu + 1.0)
    assert got == pytest.approx(np.log(p) + norm.logpdf(1.0, 0.0, 2.0), rel=1e-12)


def test_own_log_likelihood_is_used(joho):
    lk = ModelLikelihood(joho)
    assert lk.own
    rng = np.random.default_rng(1)
    d, a = rng.uniform(0.1, 2.9, 200), rng.uniform(-np.pi, np.pi, 200)
    read = rng.random(200) < 0.5
    rssi = np.where(read, rng.uniform(-75, -40, 200), np.nan)
    np.testing.assert_allclose(lk.log_likelihood(d, a, read, rssi),
                               joho.log_likelihood(d, a, read, rssi), rtol=1e-12)
    det = ModelLikelihood(joho, use_rssi=False)  # its detection term only
    np.testing.assert_allclose(det.log_likelihood(d, a, read, rssi),
                               joho.log_likelihood(d, a, read, np.nan), rtol=1e-12)


def test_far_rule_beyond_d_max(sensor):
    lk = ModelLikelihood(sensor, d_max_m=3.0, p_far=0.2, d_far_m=5.0)
    flat = -np.log(50.0)  # RSSI uniform over the model's 50 dB range
    got = lk.log_likelihood(np.array([4.0, 4.0, 4.0, 6.0, 6.0]), np.nan,
                            [True, True, False, True, False], [-70.0, np.nan, np.nan, -70.0, np.nan])
    np.testing.assert_allclose(got, [np.log(0.2) + flat, np.log(0.2), np.log(0.8),
                                     np.log(EPS) + flat, np.log1p(-EPS)])
    near = lk.log_likelihood(1.0, 0.1, True, -50.0)
    assert near == pytest.approx(ModelLikelihood(sensor).log_likelihood(1.0, 0.1, True, -50.0))
    with pytest.raises(ValueError, match="p_far"):
        ModelLikelihood(sensor, d_max_m=3.0)


@pytest.mark.parametrize("case", ["constant", "batch_dependent", "detection_only", "own_sigma",
                                  "own_likelihood", "own_likelihood_detection", "no_rssi",
                                  "no_far_rule", "no_d_far"])
def test_pair_loglik_is_the_terms_value_for_value(case, sensor, joho):
    """The robot filter's per-slot shortcut gives exactly what the terms give: the far
    rule's two values per tag, the model on the near pairs in the terms' batch (a model
    whose numbers depend on the batch included). Exact equality: the same operations on
    the same numbers."""
    far = {"d_max_m": 3.0, "p_far": 0.2, "d_far_m": 5.0}
    lk = {"constant": lambda: ModelLikelihood(Constant(0.7, -60.0), sigma_rssi_db=2.0, **far),
          "batch_dependent": lambda: ModelLikelihood(BatchDependent(0.4, -60.0), sigma_rssi_db=2.0,
                                                     **far),
          "detection_only": lambda: ModelLikelihood(DetectionOnly(), **far),
          "own_sigma": lambda: ModelLikelihood(sensor, **far),
          "own_likelihood": lambda: ModelLikelihood(joho, **far),
          "own_likelihood_detection": lambda: ModelLikelihood(joho, use_rssi=False, **far),
          "no_rssi": lambda: ModelLikelihood(sensor, use_rssi=False, **far),
          "no_far_rule": lambda: ModelLikelihood(sensor),
          "no_d_far": lambda: ModelLikelihood(sensor, d_max_m=3.0, p_far=0.2)}[case]()
    rng = np.random.default_rng(3)
    poses = np.column_stack([rng.uniform(-4, 4, (300, 2)), np.full(300, 0.4),
                             rng.uniform(-np.pi, np.pi, 300)])
    tags = rng.uniform(-4, 4, (9, 3))
    d, a = pair_geometry(poses, tags, alpha_within_m=lk.alpha_needed_within_m)
    read = np.array([True, False, True, True, False, False, True, False, True])
    rssi = np.where(read, rng.uniform(-75.0, -40.0, 9), np.nan)
    rssi[3] = np.nan  # read without an RSSI
    got = lk.pair_loglik(d, a, read, rssi)
    want = lk.terms(d, a).loglik(read[None, :], rssi[None, :])
    assert np.isfinite(want).all()
    np.testing.assert_array_equal(got, want)
    # the filter's per-pose sum, geometry included: the same numbers (a pose with a tilt
    # and a roll, so the bearing's frame is exercised whole)
    poses6 = np.column_stack([poses, rng.uniform(-0.3, 0.3, (300, 2))])
    d6, a6 = pair_geometry(poses6, tags, alpha_within_m=lk.alpha_needed_within_m)
    np.testing.assert_array_equal(lk.pose_loglik(poses6, tags, read, rssi),
                                  lk.pair_loglik(d6, a6, read, rssi).sum(axis=1))
    with pytest.raises(ValueError, match="pose_loglik: read and rssi_dbm must be \\(9,\\)"):
        lk.pose_loglik(poses6, tags, read[:-1], rssi[:-1])
    if lk.d_max_m is not None:  # both sides of the domain and of d_far are exercised
        assert (d < 3.0).any() and ((d > 3.0) & (d < 5.0)).any() and (d > 5.0).any()
    with pytest.raises(ValueError, match="pair_loglik"):
        lk.pair_loglik(d, a, read[:-1], rssi[:-1])
    with pytest.raises(ValueError, match="pair_loglik"):  # one slot's outcomes: (k,) only
        lk.pair_loglik(d, a, read[None, :], rssi[None, :])


def test_pair_geometry_bearing_behind_is_plus_pi():
    """A point straight behind the antenna lies at alpha = +pi (the range is (-pi, pi]),
    whichever way atan2 signs the zero, with and without the distance cut."""
    pose = np.array([[1.0, 2.0, 0.5, np.pi / 2]])  # boresight +y
    behind = np.array([[1.0, 0.0, 0.5], [1.0, 2.0 + 1e-300, 0.5], [1.0, 10.0, 0.5]])
    for within in (np.inf, 3.0):
        d, a = pair_geometry(pose, behind, alpha_within_m=within)
        assert a[0, 0] == np.pi
        assert a[0, 2] == pytest.approx(0.0, abs=1e-12) if within == np.inf else np.isnan(a[0, 2])


def test_oracle_closed_form():
    b = LinkBudget()
    orc = OracleLikelihood(b, miss_probability=0.05, rssi_noise_db=1.0, rssi_resolution_db=0.5)
    sigma = np.sqrt(1.0 + 0.25 / 12)
    thr = b.reader_rssi_dbm(b.min_gain_db())
    assert orc.threshold_dbm == pytest.approx(thr)
    # the closure threshold in the RSSI domain is where LinkBudget.detected switches
    assert not b.detected(b.min_gain_db() - 1e-6) and b.detected(b.min_gain_db() + 1e-6)
    g = np.array([-40.0, -40.0, b.min_gain_db(), -np.inf])
    mu = b.reader_rssi_dbm(g[:3])
    got = orc.log_likelihood(g, [True, False, True, True], [mu[0] + 0.5, np.nan, mu[2], -70.0])
    p0 = norm.cdf((mu[0] - thr) / sigma) * 0.95
    want = [np.log(p0) + norm.logpdf(0.5, 0, sigma), np.log1p(-p0),
            np.log(0.5 * 0.95) + norm.logpdf(0.0, 0, sigma),  # at the threshold: P(closed) 1/2
            np.log(EPS) + norm.logpdf(Z_CLIP) - np.log(sigma)]  # untraced: eps, RSSI floor
    np.testing.assert_allclose(got, want, rtol=1e-10)


def test_oracle_sampling_matches_its_probability():
    orc = OracleLikelihood(LinkBudget(), miss_probability=0.1, rssi_noise_db=1.0)
    g = np.full(40000, LinkBudget().min_gain_db() + 0.3)
    read, rssi = orc.sample(g, np.random.default_rng(3))
    p = float(orc.read_probability(g[0]))
    # binomial standard error sqrt(p (1 - p) / n) < 0.0025: 4 of them
    assert read.mean() == pytest.approx(p, abs=0.01)
    assert np.nanstd(rssi) == pytest.approx(orc.sigma_db, rel=0.03)  # 3 %: ~3x the SE


@pytest.fixture(scope="module")
def small_run(sensor):
    rng = np.random.default_rng(7)
    sc = corridor_scenario(rng, length_m=6.0, n_tags=4, n_cycles=60, candidate_spacing_m=0.25)
    d, a = pair_geometry(sc.slot_poses, sc.tag_positions_m)
    read, rssi = ModelLikelihood(sensor).sample(d.T, a.T, rng)
    rssi[0, np.flatnonzero(read[0])[:1]] = np.nan  # a read without RSSI
    att = np.ones(read.shape, dtype=bool)
    att[1, ::7] = False  # slots that did not attempt tag 1
    read &= att
    obs = Observations(sc.tag_ids, sc.slot_time_s, sc.slot_antenna, sc.slot_poses, read, rssi, att)
    return sc, obs


def _brute(obs, cand, loglik):
    """Sum over attempted slots of the elementwise log-likelihood, normalised per tag."""
    out = np.zeros((obs.n_tags, len(cand)))
    for t in range(obs.n_tags):
        s = obs.attempted[t]
        out[t] = loglik(s, obs.read[t, s][:, None], obs.rssi_dbm[t, s][:, None]).sum(axis=0)
    return out - logsumexp(out, axis=1, keepdims=True)


@pytest.mark.parametrize("kind", ["gaussian", "gaussian_far", "own_far", "oracle"])
def test_chunked_posterior_equals_brute_force(kind, small_run, sensor, joho):
    sc, obs = small_run
    cand = sc.candidates_m
    D, A = pair_geometry(sc.slot_poses, cand)
    if kind == "oracle":
        orc = OracleLikelihood(LinkBudget(), miss_probability=0.05, rssi_noise_db=1.0)
        gains = free_space_gain_db(sc.slot_poses, cand)
        src = orc.with_gains(gains)

        def loglik(s, r, z):
            return orc.log_likelihood(gains[s], r, z)
    else:
        model = joho if kind == "own_far" else sensor
        far = {} if kind == "gaussian" else {"d_max_m": 2.5, "p_far": 0.3, "d_far_m": 4.0}
        src = ModelLikelihood(model, **far)

        def loglik(s, r, z):
            return src.log_likelihood(D[s], A[s], r, z)
    post = localise_tags(obs, cand, {"x": src}, chunk_size=37)["x"]
    # same sums in another order: agreement to rounding
    np.testing.assert_allclose(post.log_posterior, _brute(obs, cand, loglik), atol=1e-8)
    np.testing.assert_allclose(post.posterior.sum(axis=1), 1.0, atol=1e-12)


def test_observations_from_reads_round_trip(small_run):
    sc, obs = small_run
    T, S = obs.n_tags, obs.n_slots
    rows = [(s, t) for s in range(S) for t in range(T) if obs.attempted[t, s]]
    s_i, t_i = np.array(rows).T
    p = obs.slot_poses[s_i]
    df = pd.DataFrame({
        "time_s": obs.slot_time_s[s_i], "cycle": s_i, "antenna": obs.slot_antenna[s_i],
        "tag_id": pd.Categorical([obs.tag_ids[t] for t in t_i]),
        "read": obs.read[t_i, s_i], "rssi_dbm": obs.rssi_dbm[t_i, s_i].astype(np.float32),
        "est_ant_x_m": p[:, 0], "est_ant_y_m": p[:, 1], "est_ant_z_m": p[:, 2],
        "est_ant_yaw_rad": p[:, 3]}).sample(frac=1.0, random_state=0)  # row order irrelevant
    back = observations_from_reads(df)
    assert back.tag_ids == obs.tag_ids
    np.testing.assert_array_equal(back.read, obs.read)
    np.testing.assert_array_equal(back.attempted, obs.attempted)
    np.testing.assert_allclose(back.rssi_dbm, obs.rssi_dbm, atol=1e-4)  # float32 column
    np.testing.assert_allclose(back.slot_poses, obs.slot_poses)
    sub = observations_from_reads(df, tag_ids=["E03", "E01"], pitch_rad={0: 0.1, 1: -0.1})
    assert sub.tag_ids == ("E03", "E01")
    np.testing.assert_allclose(sub.slot_poses[:, 4], np.where(sub.slot_antenna == 0, 0.1, -0.1))


def test_training_helpers(sensor):
    # from 0.5 m on the sensor's RSSI stays inside its range (no clipping of fs_dbm)
    att = sample_attempts(sensor, 40000, np.random.default_rng(11), d_lo_m=0.5)
    # the synthetic RSSI noise is 2 dB; ~7000 reads within 3 m: SE of the std < 1 %
    assert rssi_residual_std(sensor, att, 3.0) == pytest.approx(2.0, rel=0.04)
    p_far, d_far = fit_far_detection(att, 3.0)
    band = (att.d >= 3.0) & (att.d < d_far)
    assert p_far == pytest.approx(att.read[band].mean())
    assert 3.0 < d_far <= att.d[att.read].max()
