import json

import numpy as np
import pytest

from pipeline.evaluation.cells import CellGrid
from pipeline.sensormodels import Attempts, Joho2009Model, Liu2006Model, fit_joho2009

GRID = CellGrid(d_max_m=3.0, d_bin_m=0.25, alpha_bin_deg=15.0)  # cone edges +-45 deg are bin edges


@pytest.fixture(scope="module")
def model(big_attempts, synth):
    return fit_joho2009(big_attempts, synth.RSSI_RANGE, GRID)


def _cell_truth(synth, lo, hi, inside):
    """Truth averaged over the part [max(lo, D_LO), hi) of a cell the data cover:
    detection rate, mean RSSI of the reads and the RSSI variance within the cell."""
    lo = max(lo, synth.D_LO)
    d = lo + (np.arange(4000) + 0.5) / 4000 * (hi - lo)  # midpoint rule, 4000 nodes
    p = synth.p_true(d, 0.0 if inside else np.pi)
    r = synth.rssi_true(d)
    mean = np.sum(p * r) / np.sum(p)
    return p.mean(), mean, np.sum(p * (r - mean) ** 2) / np.sum(p)


def test_detection_rate_per_cell_matches_truth(model, synth):
    D, A = GRID.centre_mesh()
    edges = GRID.d_edges_m
    pt = np.empty(GRID.shape)
    for i in range(GRID.n_d):
        for j in range(GRID.n_alpha):
            pt[i, j] = _cell_truth(synth, edges[i], edges[i + 1], abs(A[i, j]) < synth.CONE)[0]
    n = model.n_attempts
    assert n.min() >= 100  # every cell is well sampled, so the SE below is meaningful
    se = np.sqrt(pt * (1 - pt) / n)
    p_hat = model.fT(D, A)
    # binomial count per cell: 4.5 SE keeps all 288 cells inside with prob. > 0.99
    assert np.all(np.abs(p_hat - pt) <= 4.5 * se), np.max(np.abs(p_hat - pt) / se)
    # beyond the grid nothing is detected
    assert np.all(model.fT([3.0, 5.0], [0.0, 0.0]) == 0.0)


def test_rssi_gaussian_per_cell_matches_truth(model, synth):
    D, A = GRID.centre_mesh()
    edges = GRID.d_edges_m
    mu_hat = model.expected_rssi_dbm(D, A)
    sd_hat = model.rssi_sigma_db(D, A)
    n = model.n_rssi
    assert n.min() >= model.min_reads  # every cell has its own Gaussian, none borrowed
    for i in range(GRID.n_d):
        for j in range(GRID.n_alpha):
            _, mean, var_in = _cell_truth(synth, edges[i], edges[i + 1],
                                          abs(A[i, j]) < synth.CONE)
            sd = np.sqrt(synth.SIGMA_DB ** 2 + var_in)  # reader noise + spread inside the cell
            # sample mean of n[i, j] reads: 4.5 standard errors over 288 cells
            assert abs(mu_hat[i, j] - mean) <= 4.5 * sd / np.sqrt(n[i, j]), (i, j)
            if edges[i] >= 0.5:  # nearly Gaussian there (spread in the cell <= 2 dB), so
                # the sample SD has SE sd / sqrt(2 (n - 1)); 4.5 SE as above
                assert abs(sd_hat[i, j] - sd) <= 4.5 * sd / np.sqrt(2 * (n[i, j] - 1)), (i, j)
    # fs is the mean normalised with the given range, clipped to [0, 1] (the first cells
    # are above -30 dBm); fs_dbm maps it back
    lo, hi = synth.RSSI_RANGE
    fs = np.clip((mu_hat - lo) / (hi - lo), 0, 1)
    assert (fs == 1).any() and (fs < 1).any()
    np.testing.assert_allclose(model.fs(D, A), fs, rtol=0, atol=1e-12)
    np.testing.assert_allclose(model.fs_dbm(D, A), lo + fs * (hi - lo), rtol=0, atol=1e-9)
    np.testing.assert_allclose(model.rho(D, A), model.fs(D, A) * model.fT(D, A), atol=0)


def test_log_likelihood_is_the_joint_model_and_close_to_the_truths(model, synth):
    d, a, r, s = synth.sample(50_000, seed=9)
    ll = model.log_likelihood(d, a, r, s)
    p = np.clip(model.fT(d, a), model.p_floor, 1 - model.p_floor)
    mu, sd = model.expected_rssi_dbm(d, a), model.rssi_sigma_db(d, a)
    manual = np.where(r, np.log(p) - 0.5 * ((s - mu) / sd) ** 2 - np.log(sd * np.sqrt(2 * np.pi)),
                      np.log(1 - p))
    np.testing.assert_allclose(ll, manual, rtol=1e-12, atol=1e-12)  # same formula, round-off
    pt = synth.p_true(d, a)
    z = (s - synth.rssi_true(d)) / synth.SIGMA_DB
    ll_true = np.where(r, np.log(pt) - 0.5 * z ** 2 - np.log(synth.SIGMA_DB * np.sqrt(2 * np.pi)),
                       np.log1p(-pt))
    gap = ll_true.mean() - ll.mean()
    # the data-generating model must win (gap > 0; its SE here is ~0.001 nats), and the
    # cells lose little: measured ~0.018 nats/attempt (mostly the RSSI mean changing by up
    # to 8 dB inside the first 0.25 m cell); 0.04 leaves a factor 2
    assert 0.0 < gap < 0.04
    # a read whose RSSI is not reported scores its detection only
    np.testing.assert_allclose(model.log_likelihood(1.0, 0.1, True, np.nan),
                               np.log(model.fT(1.0, 0.1)), rtol=1e-12)
    # RSSI of a miss is ignored
    assert model.log_likelihood(1.0, 0.1, False, -45.0) == model.log_likelihood(1.0, 0.1, False,
                                                                                np.nan)


def test_log_likelihood_broadcasts(model):
    d = np.linspace(0.2, 2.8, 7)[:, None]  # (7, 1)
    a = np.linspace(-1.0, 1.0, 5)  # (5,)
    rd = np.array([True, False, True, True, False])
    ll = model.log_likelihood(d, a, rd, -50.0)
    assert ll.shape == (7, 5)
    for i in range(7):
        np.testing.assert_array_equal(ll[i], model.log_likelihood(np.full(5, d[i, 0]), a, rd,
                                                                  np.full(5, -50.0)))
    assert np.ndim(model.log_likelihood(1.0, 0.0, True, -45.0)) == 0
    assert np.isnan(model.log_likelihood(np.nan, 0.0, False, np.nan))


def test_json_round_trip_gives_identical_predictions(model, tmp_path):
    path = model.save(tmp_path / "joho2009.json")
    d = json.loads(path.read_text())
    assert d["kind"] == "joho2009" and "Joho" in d["reference"]
    back = Joho2009Model.load(path)
    rng = np.random.default_rng(3)
    dd, aa = rng.uniform(0, 4, 2000), rng.uniform(-4, 4, 2000)
    rd, ss = rng.random(2000) < 0.5, rng.normal(-50, 5, 2000)
    for name in ("fT", "fs", "fs_dbm", "rho", "rssi_sigma_db"):
        np.testing.assert_array_equal(getattr(back, name)(dd, aa), getattr(model, name)(dd, aa))
    np.testing.assert_array_equal(back.log_likelihood(dd, aa, rd, ss),
                                  model.log_likelihood(dd, aa, rd, ss))
    with pytest.raises(ValueError, match=r"joho2009\.json.*'joho2009'.*'liu2006'"):
        Liu2006Model.load(path)


def test_sparse_cells_borrow_from_the_nearest_and_floor_sigma(synth):
    # all reads in one cell, at one RSSI: everything else borrows it; sigma floored
    d = np.array([1.1, 1.1, 1.1, 1.1, 1.1, 2.0])
    a = np.zeros(6)
    read = np.array([True] * 5 + [False])
    m = fit_joho2009(Attempts(d, a, read, np.full(6, -50.0)), synth.RSSI_RANGE, GRID,
                     min_reads=5, sigma_floor_db=0.5)
    np.testing.assert_array_equal(m.expected_rssi_dbm([0.3, 2.9], [3.0, -1.0]), [-50.0, -50.0])
    np.testing.assert_array_equal(m.rssi_sigma_db([0.3, 2.9], [3.0, -1.0]), [0.5, 0.5])
    # detection: the two cells with attempts, nearest one elsewhere
    np.testing.assert_array_equal(m.fT([1.1, 2.0, 1.3], [0.0, 0.0, 0.0]), [1.0, 0.0, 1.0])
    with pytest.raises(ValueError, match="no read with an RSSI"):
        fit_joho2009(Attempts(d, a, np.zeros(6, bool)), synth.RSSI_RANGE, GRID)
