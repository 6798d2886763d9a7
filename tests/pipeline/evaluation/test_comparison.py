import json

import numpy as np
import pytest

from pipeline.evaluation import (
    BaselineSensorModel,
    CellGrid,
    LogDistanceModel,
    RhoPoints,
    TruthGrid,
    detection_truth,
    detection_vs_truth,
    fit_grid_count,
    rho_points_truth,
    rho_vs_truth,
    rssi_vs_truth,
    true_detected,
)
from tests.helpers.reads import gain_for_rssi, synthetic_reads

WIDE = (-120.0, 0.0)  # normalisation range wide enough that no prediction is clipped
TRUTH = LogDistanceModel(p0_dbm=-45.0, n=4.0, coefficients=(8.0,))
GRID = CellGrid(d_max_m=3.0, d_bin_m=0.25, alpha_bin_deg=30.0)


def _model(ld, reads, grid=GRID, col="true"):
    gc = fit_grid_count(reads[f"d_{col}_m"], reads[f"alpha_{col}_rad"], reads["read"], grid=grid)
    return BaselineSensorModel(ld, gc, WIDE)


@pytest.fixture
def reads(budget):
    return synthetic_reads(TRUTH.predict_dbm, budget, np.random.default_rng(5))


def test_synthetic_truth_has_both_outcomes(reads, budget):
    closed = true_detected(reads["gain_db"], budget)
    # the pattern's back lobe makes far tags behind the antenna unpowered
    assert 0.2 < closed.mean() < 0.95


def test_rssi_perfect_model_zero_error_and_3db_offset(reads, budget):
    perfect = _model(TRUTH, reads)
    r = rssi_vs_truth(reads, perfect, budget, d_max_m=3.0)
    assert r.n_rows > 1000
    # gain inverted from the RSSI and back: float64 round-off only
    assert r.stats.mae < 1e-9 and abs(r.stats.bias) < 1e-9
    high = LogDistanceModel(p0_dbm=TRUTH.p0_dbm + 3.0, n=TRUTH.n, coefficients=TRUTH.coefficients)
    r3 = rssi_vs_truth(reads, _model(high, reads), budget, d_max_m=3.0)
    assert r3.stats.bias == pytest.approx(3.0, abs=1e-9)
    assert r3.stats.mae == pytest.approx(3.0, abs=1e-9)
    assert r3.stats.rmse == pytest.approx(3.0, abs=1e-9)
    assert r3.n_rows == r.n_rows
    json.dumps(r3.to_dict(), allow_nan=False)


def test_detection_truth_counts_and_perfect_grid_model(reads, budget):
    truth = detection_truth(reads, budget, GRID, miss_probability=0.0)
    inside = reads["d_true_m"] < GRID.d_max_m
    assert truth.n_attempts.sum() == inside.sum()
    assert truth.n_closed.sum() == (true_detected(reads["gain_db"], budget) & inside).sum()
    # the grid-count model fitted on true geometry reproduces p_detect in every cell
    cmp = detection_vs_truth(reads, _model(TRUTH, reads), truth, min_attempts=5)
    assert cmp.n_cells > 50
    assert cmp.cells.mae < 1e-12
    assert cmp.brier == pytest.approx(cmp.brier_truth, abs=1e-12)
    assert cmp.brier <= cmp.brier_climatology
    # a model that always says 1 is off by 1 - p in each cell
    one = detection_vs_truth(reads, _model(TRUTH, reads.assign(read=True)), truth, min_attempts=5)
    ok = truth.n_attempts >= 5
    assert one.cells.mae == pytest.approx(np.mean(1.0 - truth.p_detect[ok]), abs=1e-12)


def test_detection_truth_with_miss_probability(budget):
    rng = np.random.default_rng(11)
    reads = synthetic_reads(TRUTH.predict_dbm, budget, rng, n=20000, miss_probability=0.2)
    truth = detection_truth(reads, budget, GRID, miss_probability=0.2)
    closed = truth.n_closed == truth.n_attempts
    full = closed & (truth.n_attempts > 0)
    np.testing.assert_allclose(truth.p_detect[full], 0.8)
    # the reader's reads in fully closed cells: binomial, 0.8 of attempts within 4 sigma
    n = truth.n_attempts[full].sum()
    frac = truth.n_reads[full].sum() / n
    assert abs(frac - 0.8) < 4 * np.sqrt(0.16 / n)
    cmp = detection_vs_truth(reads, _model(TRUTH, reads), truth, min_attempts=20)
    # Brier of the truth: q(1-q) per closed attempt, 0 elsewhere (exact expectation 0.16 x
    # the closed share; 4-sigma binomial band on the realised value)
    share = truth.n_closed.sum() / truth.n_attempts.sum()
    assert cmp.brier_truth == pytest.approx(0.16 * share, abs=0.02)


def test_truth_grid_round_trip(reads, budget, tmp_path):
    truth = detection_truth(reads, budget, GRID, miss_probability=0.1)
    p = truth.save(tmp_path / "truth" / "detection_grid.npz", {"anfis": _model(TRUTH, reads)})
    back = TruthGrid.load(p)
    assert back.grid == GRID and back.miss_probability == pytest.approx(0.1)
    np.testing.assert_array_equal(back.n_attempts, truth.n_attempts)
    np.testing.assert_array_equal(back.p_detect, truth.p_detect)
    with np.load(p) as z:
        assert z["anfis__fs_dbm"].shape == GRID.shape
        assert list(z["model_names"]) == ["anfis"]


def _polar_points(pose, d, a):
    D, A = np.meshgrid(d, a, indexing="ij")
    x = pose[0] + D * np.cos(A + pose[3])
    y = pose[1] + D * np.sin(A + pose[3])
    return np.column_stack([x.ravel(), y.ravel(), np.full(x.size, pose[2])])


def test_rho_truth_and_perfect_model(budget, tmp_path):
    pose = np.array([2.0, 1.0, 1.0, 0.3])
    d = GRID.d_centres_m
    a = GRID.alpha_centres_rad
    pts = _polar_points(pose, d, a)
    D, A = np.meshgrid(d, a, indexing="ij")
    rssi = TRUTH.predict_dbm(D.ravel(), A.ravel())
    g = gain_for_rssi(budget, rssi)
    rp = rho_points_truth(pose, pts, g, budget, WIDE, miss_probability=0.0,
                          grid_shape=D.shape)
    np.testing.assert_allclose(rp.d_m, D.ravel(), atol=1e-12)
    np.testing.assert_allclose(rp.alpha_rad, A.ravel(), atol=1e-12)
    closed = true_detected(g, budget)
    np.testing.assert_allclose(rp.rho_true, np.where(closed, np.clip((rssi + 120.0) / 120.0, 0, 1), 0.0),
                               atol=1e-12)
    # one point per cell: the grid-count model equals the closed indicator exactly
    gc = fit_grid_count(D.ravel(), A.ravel(), closed, grid=GRID, fallback="zero")
    perfect = BaselineSensorModel(TRUTH, gc, WIDE)
    cmp = rho_vs_truth([rp, rp], perfect)
    assert cmp.stats.mae < 1e-12 and cmp.stats.correlation == pytest.approx(1.0)
    assert len(cmp.per_pose) == 2
    # miss probability scales true rho
    rq = rho_points_truth(pose, pts, g, budget, WIDE, miss_probability=0.25)
    np.testing.assert_allclose(rq.rho_true, 0.75 * rp.rho_true, atol=1e-15)
    path = rp.save(tmp_path / "truth" / "rho_pose_0.npz", {"anfis": perfect})
    back = RhoPoints.load(path)
    assert back.grid_shape == D.shape
    np.testing.assert_array_equal(back.rho_true, rp.rho_true)
    with np.load(path) as z:
        np.testing.assert_allclose(z["anfis__rho"], rp.rho_true, atol=1e-12)
    with pytest.raises(ValueError, match="gain_db has 3 entries"):
        rho_points_truth(pose, pts, g[:3], budget, WIDE)


def test_cell_mean_floor_is_the_within_cell_spread(budget):
    from pipeline.evaluation import rssi_cell_mean_floor

    rng = np.random.default_rng(11)
    # RSSI constant per cell plus +-2 dB "fading" that (d, alpha) cannot explain:
    # the cell mean misses each link by exactly 2 dB when both signs are equally many.
    grid = CellGrid(d_max_m=3.0, d_bin_m=0.5, alpha_bin_deg=60.0)
    centres_d = rng.choice(grid.d_centres_m, 2000)
    centres_a = rng.choice(grid.alpha_centres_rad, 2000)
    sign = np.tile([1.0, -1.0], 1000)
    rssi = -50.0 - 5.0 * centres_d + 2.0 * sign
    reads = synthetic_reads(lambda d, a: rssi, budget, rng, n=2000)
    reads["d_true_m"], reads["alpha_true_rad"] = centres_d, centres_a
    reads["gain_db"] = gain_for_rssi(budget, rssi)
    truth = detection_truth(reads, budget, grid, miss_probability=0.0)
    floor = rssi_cell_mean_floor(reads, truth, budget, d_max_m=3.0, min_count=5)
    assert floor.n == 2000  # every link closes (-65 dBm at worst) and every cell is full
    # each cell's mean sits within the sampling error of the +-2 dB pairs; MAE ~ 2 dB
    assert floor.mae == pytest.approx(2.0, abs=0.15)
    assert abs(floor.bias) < 1e-9  # the mean of a cell's residuals is zero by construction
