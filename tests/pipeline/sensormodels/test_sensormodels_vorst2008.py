import numpy as np
import pytest

from pipeline.sensormodels import Attempts, Joho2009Model, Vorst2008Model, fit_vorst2008


def _in_plane(att: Attempts) -> Attempts:
    """The attempts with every tag in the antenna's horizontal plane (dz = 0)."""
    return Attempts(att.d, att.alpha, att.read, att.rssi, att.group, dz_m=0.0)


@pytest.fixture(scope="module")
def model(big_attempts, synth):
    return fit_vorst2008(_in_plane(big_attempts), synth.RSSI_RANGE, np.random.default_rng(0),
                         d_max_m=3.0, cell_m=0.1)


def _interior_points(n, seed):
    """Points >= 0.35 m from the cone's edge and away from the data's d-limits."""
    rng = np.random.default_rng(seed)
    d = rng.uniform(1.0, 2.4, n)
    in_cone = rng.random(n) < 0.5
    a = np.where(in_cone, rng.uniform(0, np.deg2rad(20), n), rng.uniform(np.deg2rad(70), np.pi, n))
    return d, a * rng.choice([-1, 1], n)


def test_recovers_the_detection_probability(model, synth):
    d, a = _interior_points(4000, seed=5)
    err = model.fT(d, a) - synth.p_true(d, a)
    # ~65 attempts per 0.1 m cell at d ~ 1.7 m: binomial SE <= 0.06 in the cone (p ~ 0.5),
    # 0.027 outside (p = 0.05); the mean |error| of such a count is ~0.8 SE, plus up to
    # 0.018 from looking up the cell (slope 0.25/m x half a cell diagonal): 0.035
    assert np.mean(np.abs(err)) < 0.035
    # no systematic error: the kernel ratio is unbiased for a linear p (SE of the mean
    # of 4000 errors, correlated within ~1000 cells, ~0.002)
    assert abs(np.mean(err)) < 0.01
    assert 0 < model.bandwidth_m <= 0.6  # smoothing chosen by CV, among the candidates
    assert model.cv_log_likelihood[0] < max(model.cv_log_likelihood)  # it beat the histogram
    # no data beyond d_max: 0, as the grid-count baseline
    np.testing.assert_array_equal(model.fT([3.0, 4.2], [0.0, 0.0]), [0.0, 0.0])


def test_deterministic_reads_are_reproduced_away_from_edges(synth):
    def p(d, a):  # read iff in a 90-deg cone closer than 2.2 m: a step, no noise
        return ((d < 2.2) & (np.abs(a) < synth.CONE)).astype(float)

    att = Attempts(*synth.sample(100_000, seed=6, p=p), dz_m=0.0)
    m = fit_vorst2008(att, synth.RSSI_RANGE, np.random.default_rng(0), d_max_m=3.0,
                      cell_m=0.1)
    # smoothing only blurs a noise-free step: cross-validation keeps the histogram
    assert m.bandwidth_m == 0.0
    # points >= 0.7 m from the step: each cell holds >= 15 attempts (100 000 attempts
    # over 3 m x 2 pi), and only the prior of one pseudo-attempt at the overall rate moves
    # a cell off 0 or 1, by < 1 / (15 + 1)
    inside = m.fT([1.3, 1.0, 1.2], [0.0, 0.1, -0.1])
    outside = m.fT([2.95, 1.5, 2.0], [0.0, np.pi, -2.0])
    assert np.all(inside > 1 - 1 / 16) and np.all(outside < 1 / 16)


def test_histogram_bandwidth_is_the_count_ratio(synth):
    d = np.array([0.05, 0.06, 0.07, 1.0, 1.02])
    a = np.zeros(5)
    read = np.array([True, True, False, True, False])
    m = fit_vorst2008(Attempts(d, a, read, dz_m=0.0), synth.RSSI_RANGE, np.random.default_rng(0),
                      d_max_m=3.0, cell_m=0.1, bandwidths_m=[0.0], n_folds=2, prior_weight=1.0)
    p0 = 3 / 5
    # cell of d = 0.05..0.07 (x in [0, 0.1)): (2 reads + p0) / (3 attempts + 1)
    assert m.fT(0.06, 0.0) == pytest.approx((2 + p0) / 4, rel=1e-12)
    assert m.fT(1.01, 0.0) == pytest.approx((1 + p0) / 3, rel=1e-12)
    assert m.fT(2.0, 1.0) == pytest.approx(p0, rel=1e-12)  # no data: the prior


def test_no_rssi_prediction(model):
    d, a = np.array([0.5, 1.5, 2.5]), np.array([0.0, 1.0, -2.0])
    assert model.predicts_rssi is False
    np.testing.assert_array_equal(model.fs(d, a), np.ones(3))  # so that rho = fT
    assert np.all(np.isnan(model.fs_dbm(d, a)))
    np.testing.assert_array_equal(model.rho(d, a), model.fT(d, a))


def test_json_round_trip_and_wrong_kind(model, tmp_path):
    path = model.save(tmp_path / "vorst.json")
    back = Vorst2008Model.load(path)
    d, a = _interior_points(2000, seed=8)
    for name in ("fT", "fs", "rho"):
        np.testing.assert_array_equal(getattr(back, name)(d, a), getattr(model, name)(d, a))
    assert back.bandwidth_m == model.bandwidth_m
    assert back.cv_log_likelihood == model.cv_log_likelihood
    with pytest.raises(ValueError, match=r"vorst\.json.*'vorst2008'.*'joho2009'"):
        Joho2009Model.load(path)


def test_group_folds_never_split_a_group():
    """Every group lies in one fold; the folds are balanced by items (largest group first
    to the lightest fold) and all used."""
    from pipeline.sensormodels import group_folds

    rng = np.random.default_rng(3)
    groups = np.repeat([f"T{i:02d}" for i in range(24)], rng.integers(20, 400, 24))
    fold = group_folds(groups, 5, np.random.default_rng(0))
    for g in np.unique(groups):
        assert len(np.unique(fold[groups == g])) == 1
    sizes = np.bincount(fold, minlength=5)
    assert np.all(sizes > 0)
    # greedy balance: no fold exceeds the lightest by more than the largest group
    assert sizes.max() - sizes.min() <= np.unique(groups, return_counts=True)[1].max()
    with pytest.raises(ValueError, match="n_folds"):
        group_folds(["a", "b"], 3, rng)


def test_bandwidth_is_chosen_on_folds_that_keep_tags_whole(synth):
    """Tags read many times from one place (a tour's correlated attempts: one outcome per
    tag, repeated): folds that split a tag find its copies in training and keep the
    histogram; folds by tag must predict each tag from its neighbours and smooth."""
    rng = np.random.default_rng(11)
    n_tags, reps = 600, 25
    d = rng.uniform(0.2, 2.8, n_tags)
    a = rng.uniform(-np.pi, np.pi, n_tags)
    read = rng.random(n_tags) < synth.p_true(d, a)
    tag = np.repeat(np.arange(n_tags), reps)
    jitter = rng.normal(0.0, 0.005, (2, n_tags * reps))  # 5 mm: within one 0.1 m cell
    att = Attempts(np.repeat(d, reps) + jitter[0], np.repeat(a, reps) + jitter[1],
                   np.repeat(read, reps), group=tag, dz_m=0.0)
    grouped = fit_vorst2008(att, synth.RSSI_RANGE, np.random.default_rng(0), d_max_m=3.0)
    leaky = fit_vorst2008(Attempts(att.d, att.alpha, att.read, dz_m=0.0), synth.RSSI_RANGE,
                          np.random.default_rng(0), d_max_m=3.0)
    assert leaky.bandwidth_m == 0.0 and leaky.cv_n_groups == 0
    assert grouped.bandwidth_m > 0.0 and grouped.cv_n_groups == n_tags
    # scored on unseen tags the copies no longer help: a lower held-out likelihood
    assert max(grouped.cv_log_likelihood) < max(leaky.cv_log_likelihood)


def _ground_plane_sample(n, seed, heights):
    """Attempts of tags whose detection depends on the HORIZONTAL position only: read
    iff in the 45-deg half-cone and closer than 1.5 m horizontally; each tag at one of
    `heights` above the antenna (equal shares), its 3-D range sqrt(r^2 + dz^2)."""
    rng = np.random.default_rng(seed)
    r = rng.uniform(0.05, 2.6, n)
    a = rng.uniform(-np.pi, np.pi, n)
    dz = rng.choice(np.asarray(heights, float), n)
    read = (r < 1.5) & (np.abs(a) < np.pi / 4)
    return Attempts(np.hypot(r, dz), a, read, dz_m=dz)


def test_the_table_is_over_the_horizontal_range(synth):
    # tags 0.9 m above the antenna half the time: on the 3-D range the step at r = 1.5 m
    # would smear over d = 1.5 .. 1.75 m; on the ground plane it stays at 1.5 m
    att = _ground_plane_sample(150_000, 3, (0.0, 0.9))
    m = fit_vorst2008(att, synth.RSSI_RANGE, np.random.default_rng(0), d_max_m=3.0, cell_m=0.1,
                      bandwidths_m=[0.0])
    r = np.array([1.0, 1.3, 1.4, 1.6, 1.7, 2.0])
    np.testing.assert_allclose(m.ground_plane_fT(r, 0.0), [1, 1, 1, 0, 0, 0], atol=0.05)
    # a tag 0.9 m up at 1 m horizontally (d = 1.345 m) is read as at 1 m, not at 1.345 m
    # (35 % farther out): with every training tag 0.9 m up, fT(d) is the table at r(d)
    up = fit_vorst2008(_ground_plane_sample(150_000, 4, (0.9,)), synth.RSSI_RANGE,
                       np.random.default_rng(0), d_max_m=3.0, cell_m=0.1, bandwidths_m=[0.0])
    # (fT is tabulated in 2 cm range bins: these are bin centres; the step at
    # d = sqrt(1.5^2 + 0.9^2) = 1.749 m)
    d = np.array([1.21, 1.35, 1.71, 1.73, 1.77, 1.91])
    r_of_d = np.sqrt(d ** 2 - 0.81)
    np.testing.assert_allclose(up.fT(d, 0.0), up.ground_plane_fT(r_of_d, 0.0), atol=1e-12)
    # (a cell of ~25 attempts moves by the prior of one pseudo-attempt at the overall rate)
    np.testing.assert_allclose(up.fT(d, 0.0), [1, 1, 1, 1, 0, 0], atol=0.05)
    dz, w = up.height_mix(1.3)
    np.testing.assert_allclose(dz, [0.9])
    np.testing.assert_allclose(w, [1.0])


def test_fT_averages_the_table_over_the_training_heights(synth):
    # half the tags in the antennas' plane, half 0.9 m up: at d = 1.63 m the first are at
    # r = 1.63 (not read), the second at r = 1.36 (read): fT is the share of the second
    # among the training attempts of that range bin (1.63 m: a centre of fT's 2 cm bins)
    att = _ground_plane_sample(150_000, 5, (0.0, 0.9))
    m = fit_vorst2008(att, synth.RSSI_RANGE, np.random.default_rng(0), d_max_m=3.0, cell_m=0.1,
                      bandwidths_m=[0.0])
    dz, w = m.height_mix(1.63)
    np.testing.assert_allclose(dz, [0.0, 0.9], atol=1e-12)
    in_bin = (att.d >= 1.6) & (att.d < 1.7)
    np.testing.assert_allclose(w[1], np.mean(att.dz[in_bin] > 0.5), atol=1e-12)
    assert m.fT(1.63, 0.0) == pytest.approx(
        w @ m.ground_plane_fT(np.sqrt(1.63 ** 2 - dz ** 2), 0.0), abs=1e-12)
    assert 0.3 < m.fT(1.63, 0.0) < 0.7
    # below 0.9 m only the tags in the plane are possible
    np.testing.assert_allclose(m.height_mix(0.5)[0], [0.0])


def test_attempts_without_heights_are_refused(synth):
    d, a, read, _ = synth.sample(1000, seed=2)
    with pytest.raises(ValueError, match="tag heights"):
        fit_vorst2008(Attempts(d, a, read), synth.RSSI_RANGE, np.random.default_rng(0),
                      d_max_m=3.0)
