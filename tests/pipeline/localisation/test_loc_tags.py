"""Tag localisation: the free-space oracle converges to the true tag as reads accumulate;
a tag never read gets a broad, finite, normalised posterior; summaries and estimates."""

from __future__ import annotations

import numpy as np
import pytest

from pipeline.acquisition.config import ReaderConfig
from pipeline.acquisition.reader import reader_response
from pipeline.localisation import (
    ModelLikelihood,
    Observations,
    OracleLikelihood,
    localisation_summary,
    localise_tags,
    read_region_mask,
    tag_position_errors,
)
from pipeline.robot.kinematics import antenna_poses, default_antennas
from tests.helpers.localisation import free_space_gain_db, straight_path, wall_candidates

L, W = 6.0, 2.4
IDS = ("a", "b", "c", "d")
# candidates on both walls at 5 cm, heights 0.7-1.5 m: the sensor geometry is symmetric
# about the antennas' height (0.7 m) in free space, so z = 0.7 + h and 0.7 - h would be
# indistinguishable; the half-plane keeps one of each pair
CAND = wall_candidates(L, W, 0.05, (0.7, 1.5))
_WANT = np.array([[2.0, 0.0, 0.9], [3.0, W, 1.2], [4.0, 0.0, 1.4], [5.0, W, 1.0]])
TRUE_IDX = np.argmin(((CAND[None] - _WANT[:, None]) ** 2).sum(-1), axis=1)
TAGS = CAND[TRUE_IDX]  # tags on candidates: the oracle's likelihood is then exact


def _path(n_cycles: int):
    """One pass at 0.3 m/s along y = 0.9 m (off-centre: no mirror symmetry between the
    walls), round-robin antennas."""
    t = np.arange(n_cycles) / n_cycles * (L - 1.0) / 0.3
    robot = straight_path(0.5, L - 0.5, 0.9, 0.3, t)
    ant = np.arange(n_cycles) % 2
    return t, ant, antenna_poses(robot, default_antennas())[np.arange(n_cycles), ant]


def _oracle_run(n_cycles: int, seed: int, sampler: str = "oracle"):
    t, ant, poses = _path(n_cycles)
    gains = free_space_gain_db(poses, CAND)  # (S, C): Friis + the reader's pattern
    reader = ReaderConfig()
    orc = OracleLikelihood.from_reader(reader)
    rng = np.random.default_rng(seed)
    if sampler == "oracle":  # exactly the likelihood's own model
        read, rssi = orc.sample(gains[:, TRUE_IDX].T, rng)
    else:  # the project's reader: hard thresholds, quantised RSSI
        resp = reader_response(gains[:, TRUE_IDX].T, reader, rng)
        read, rssi = resp.read, resp.rssi_dbm
    obs = Observations(IDS, t, ant, poses, read, rssi, np.ones(read.shape, bool))
    return obs, localise_tags(obs, CAND, {"oracle": orc.with_gains(gains)})["oracle"]


def test_oracle_converges_to_the_true_tag_with_more_reads():
    # bounds for 3 seeds x 4 tags, each about twice the worst error seen over seeds 0-4:
    # 10 cycles ~ 0.2 m, 40 ~ 0.07 m, 160 cycles: the true candidate itself
    bounds = {10: 0.5, 40: 0.15, 160: 0.075}  # 0.075 m = 1.5 grid steps
    worst = {}
    for n, bound in bounds.items():
        errs, mass = [], []
        for seed in range(3):
            obs, post = _oracle_run(n, seed)
            errs.append(tag_position_errors(post, (IDS, TAGS)))
            near = np.linalg.norm(CAND[None] - TAGS[:, None], axis=-1) <= 0.2
            mass.append((post.posterior * near).sum(axis=1))
        e = np.concatenate(errs)
        worst[n] = e.max()
        assert worst[n] <= bound, (n, e)
        if n == 160:
            # consistency: the posterior mass concentrates on the truth (seen: >= 0.999)
            assert np.concatenate(mass).min() >= 0.95
    assert worst[160] <= worst[40] <= worst[10]


def test_oracle_localises_reads_of_the_project_reader():
    # hard link thresholds and 0.5 dB quantisation: the oracle's soft step and Gaussian
    # RSSI approximate them; 160 cycles put every tag within one grid step (seen: 0 m)
    for seed in range(2):
        _, post = _oracle_run(160, seed, sampler="reader")
        assert tag_position_errors(post, (IDS, TAGS)).max() <= 0.075


def test_never_read_tag_gets_a_broad_finite_posterior(sensor):
    t, ant, poses = _path(40)
    far_tag = np.array([[60.0, 0.0, 1.0]])  # 55 m beyond the path: never read
    rng = np.random.default_rng(0)
    lk = ModelLikelihood(sensor)
    from pipeline.localisation import pair_geometry

    d, a = pair_geometry(poses, np.vstack([TAGS[:1], far_tag]))
    read, rssi = lk.sample(d.T, a.T, rng)
    assert read[0].any() and not read[1].any()
    obs = Observations(("seen", "never"), t, ant, poses, read, rssi, np.ones(read.shape, bool))
    for src in (lk, ModelLikelihood(sensor, d_max_m=3.0, p_far=0.2, d_far_m=5.0)):
        post = localise_tags(obs, CAND, {"m": src})["m"]
        lp = post.log_posterior
        assert np.all(np.isfinite(lp))
        np.testing.assert_allclose(post.posterior.sum(axis=1), 1.0, atol=1e-12)
        # the never-read tag: mass spread over the candidates no antenna would read (here
        # behind the start of the pass; seen: 53 effective candidates, 0.65 m spread), the
        # read tag's concentrated (13, 0.1 m); factors of ~2 below what is seen
        n_eff = 1.0 / np.sum(post.posterior ** 2, axis=1)
        assert n_eff[1] > 2 * n_eff[0]
        assert post.spread_m[1] > 0.3 and post.spread_m[1] > 3 * post.spread_m[0]
        assert post.n_reads.tolist() == [int(read[0].sum()), 0]


def test_tag_with_no_attempts_keeps_the_prior():
    t, ant, poses = _path(10)
    z = np.zeros((1, 10), dtype=bool)
    obs = Observations(("x",), t, ant, poses, z, np.full((1, 10), np.nan), z)
    post = localise_tags(obs, CAND, {"m": ModelLikelihood(_Flat(), use_rssi=False)})["m"]
    np.testing.assert_allclose(post.posterior, 1.0 / len(CAND))


class _Flat:
    rssi_range_dbm = (-80.0, -30.0)

    def fT(self, d, a):  # noqa: N802
        return np.full(np.broadcast(np.asarray(d), np.asarray(a)).shape, 0.5)

    fs = rho = fs_dbm = fT


def test_estimates_and_region_prior():
    obs, post = _oracle_run(40, seed=1)
    for kind in ("map", "mean", "local_mean"):
        est = post.estimate(kind)
        assert est.shape == (4, 3) and np.all(np.isfinite(est))
    # a concentrated posterior: the local mean is close to the MAP (within the 0.25 m radius)
    assert np.all(np.linalg.norm(post.local_mean_m - post.map_m, axis=1) < 0.25)
    mask = read_region_mask(obs, CAND, radius_m=4.0)
    assert mask[np.arange(4), TRUE_IDX].all()  # the truth lies within reach of its reads
    orc = OracleLikelihood.from_reader(ReaderConfig())
    gains = free_space_gain_db(obs.slot_poses, CAND)
    post2 = localise_tags(obs, CAND, {"o": orc.with_gains(gains)},
                          log_prior=np.where(mask, 0.0, -np.inf))["o"]
    assert np.all(post2.posterior[~mask] == 0.0)
    np.testing.assert_array_equal(post2.map_index, post.map_index)


def test_summary_values():
    e = np.array([0.1, 0.2, 0.4, 0.6, 1.5])
    s = localisation_summary(e)
    assert set(s) == {"median_m", "p90_m", "rmse_m", "within_0_5m", "within_1m", "n_tags"}
    assert s["median_m"] == pytest.approx(0.4)
    assert s["p90_m"] == pytest.approx(np.percentile(e, 90))
    assert s["rmse_m"] == pytest.approx(np.sqrt(np.mean(e ** 2)))
    assert s["within_0_5m"] == pytest.approx(0.6) and s["within_1m"] == pytest.approx(0.8)
    assert s["n_tags"] == 5
    empty = localisation_summary([])
    assert empty["n_tags"] == 0 and np.isnan(empty["median_m"])


def test_oracle_plan_traces_few_pairs_and_finds_the_same_tags():
    from pipeline.localisation import oracle_plan

    obs, full = _oracle_run(160, seed=0)
    plan = oracle_plan(obs, CAND, TAGS, window_m=0.3, reach_m=3.0)
    assert plan.n_pairs < 0.15 * obs.n_slots * len(CAND)  # seen: 8.8 % of all pairs
    gains = free_space_gain_db(obs.slot_poses, plan.candidates_m)
    gains = np.where(plan.pairs, gains, -np.inf)  # only the planned pairs are "traced"
    orc = OracleLikelihood.from_reader(ReaderConfig())
    post = localise_tags(obs, plan.candidates_m, {"o": orc.with_gains(gains)},
                         log_prior=plan.log_prior)["o"]
    np.testing.assert_allclose(post.map_m, full.map_m)  # the full grid's MAPs: the truth
    assert np.all(post.posterior[~np.isfinite(plan.log_prior)] == 0.0)
    assert plan.cost_s() == pytest.approx(plan.n_pairs * 5e-3 + 1.0)
