import json

import numpy as np
import pytest

from pipeline.evaluation import (
    BaselineSensorModel,
    CellGrid,
    GridCountModel,
    LogDistanceModel,
    fit_grid_count,
    fit_log_distance,
    tr38901_horizontal_db,
)


def _samples(rng, n=500):
    d = rng.uniform(0.3, 3.0, n)
    a = rng.uniform(-np.pi, np.pi, n)
    return d, a


def test_log_distance_recovers_parameters_exactly_without_noise():
    rng = np.random.default_rng(0)
    d, a = _samples(rng)
    p0, n, c = -45.0, 3.7, (6.0, -2.5)
    y = p0 - 10 * n * np.log10(d) + c[0] * np.cos(a) + c[1] * np.cos(2 * a)
    m = fit_log_distance(d, a, y, pattern="cosine", n_harmonics=2)
    # noiseless data from the model itself: least squares is exact up to round-off
    assert m.p0_dbm == pytest.approx(p0, abs=1e-9)
    assert m.n == pytest.approx(n, abs=1e-9)
    np.testing.assert_allclose(m.coefficients, c, atol=1e-9)
    assert m.rmse_db < 1e-9
    np.testing.assert_allclose(m.predict_dbm(d, a), y, atol=1e-9)


def test_log_distance_tr38901_scale_recovered_exactly():
    rng = np.random.default_rng(1)
    d, a = _samples(rng)
    y = -40.0 - 10 * 4.0 * np.log10(d / 0.5) + 2.0 * tr38901_horizontal_db(a)
    m = fit_log_distance(d, a, y, pattern="tr38901", d0_m=0.5)
    assert m.p0_dbm == pytest.approx(-40.0, abs=1e-9)
    assert m.n == pytest.approx(4.0, abs=1e-9)
    assert m.coefficients[0] == pytest.approx(2.0, abs=1e-9)


def test_tr38901_cut_closed_form():
    # 3GPP TR 38.901 Table 7.3-1: -3 dB at half the 65 deg beamwidth, floor at -30 dB
    np.testing.assert_allclose(tr38901_horizontal_db(np.radians([0.0, 32.5, -32.5, 180.0])),
                               [0.0, -3.0, -3.0, -30.0], atol=1e-12)
    prop = pytest.importorskip("propagation.patterns")
    phi = np.radians(np.linspace(-179, 179, 37))
    ref = prop.pattern_gain_db("tr38901", np.full_like(phi, np.pi / 2), phi)
    ref0 = prop.pattern_gain_db("tr38901", np.array([np.pi / 2]), np.array([0.0]))
    # same closed form; float32 inside the ray-tracer-side helper at most
    np.testing.assert_allclose(np.asarray(ref) - np.asarray(ref0), tr38901_horizontal_db(phi),
                               atol=1e-4)


def test_log_distance_with_noise_within_tolerance():
    rng = np.random.default_rng(2)
    d, a = _samples(rng, n=20000)
    y = -45.0 - 37.0 * np.log10(d) + 6.0 * np.cos(a) + rng.normal(0, 2.0, d.size)
    m = fit_log_distance(d, a, y, n_harmonics=1)
    # standard error of n with sigma = 2 dB over 2e4 samples spread over log10 d in
    # [-0.5, 0.5] is ~0.005; 0.05 is ten of them
    assert m.n == pytest.approx(3.7, abs=0.05)
    assert m.p0_dbm == pytest.approx(-45.0, abs=0.1)
    assert m.rmse_db == pytest.approx(2.0, rel=0.03)


def test_log_distance_errors():
    with pytest.raises(ValueError, match="pattern"):
        fit_log_distance([1.0], [0.0], [-50.0], pattern="dipole")
    with pytest.raises(ValueError, match="usable samples"):
        fit_log_distance([1.0, 2.0], [0.0, 0.1], [-50.0, -55.0], n_harmonics=2)
    with pytest.raises(ValueError, match="missing key.*'n'"):
        LogDistanceModel.from_dict({"p0_dbm": 1, "d0_m": 1, "pattern": "cosine",
                                    "coefficients": []})


def test_grid_count_reproduces_counts_and_fallbacks():
    g = CellGrid(d_max_m=2.0, d_bin_m=1.0, alpha_bin_deg=90.0)  # 2 x 4 cells
    d = np.array([0.5, 0.5, 0.5, 0.6, 1.5])
    a = np.array([0.1, 0.2, 0.3, 0.4, -3.0])
    read = np.array([True, False, True, True, False])
    m = fit_grid_count(d, a, read, grid=g, fallback="zero")
    assert m.n_attempts[0, 2] == 4 and m.n_reads[0, 2] == 3
    assert m.n_attempts[1, 0] == 1 and m.n_reads[1, 0] == 0
    assert m.n_attempts.sum() == 5
    assert m.predict(0.5, 0.5) == pytest.approx(0.75)
    assert m.predict(0.5, -2.0) == 0.0  # unseen cell
    assert m.predict(2.5, 0.5) == 0.0  # beyond the grid
    near = GridCountModel(g, m.n_reads, m.n_attempts, fallback="nearest")
    # cell (0, 3) is one bearing bin from the seen (0, 2): 0.75
    assert near.predict(0.5, 2.0) == pytest.approx(0.75)
    # cell (0, 0): the seen (1, 0) is one distance bin away (p = 0), the seen (0, 2) two
    # bearing bins away (p = 0.75): nearest wins
    assert near.predict(0.5, -3.0) == pytest.approx(0.0)
    assert near.predict([[0.5, 1.5]], [[0.5, 0.5]]).shape == (1, 2)


def test_grid_count_validation():
    g = CellGrid(2.0, 1.0, 90.0)
    with pytest.raises(ValueError, match="n_reads <= n_attempts"):
        GridCountModel(g, np.ones((2, 4), int) * 2, np.ones((2, 4), int))
    with pytest.raises(ValueError, match="do not match the grid"):
        GridCountModel(g, np.zeros((3, 4), int), np.zeros((3, 4), int))


def test_baseline_sensor_model_interface_and_json_round_trip(tmp_path):
    ld = LogDistanceModel(p0_dbm=-45.0, n=3.0, pattern="cosine", coefficients=(5.0,))
    gc = fit_grid_count([0.5, 1.5, 1.5], [0.0, 0.0, 0.0], [True, True, False],
                        grid=CellGrid(2.0, 1.0, 90.0))
    b = BaselineSensorModel(ld, gc, rssi_range_dbm=(-80.0, -30.0))
    d = np.array([0.5, 1.5, 1.0])
    a = np.zeros(3)
    np.testing.assert_allclose(b.fs(d, a), (ld.predict_dbm(d, a) + 80) / 50)
    np.testing.assert_allclose(b.fs_dbm(d, a), ld.predict_dbm(d, a))
    np.testing.assert_allclose(b.fT(d, a), [1.0, 0.5, 0.5])
    np.testing.assert_allclose(b.rho(d, a), b.fs(d, a) * b.fT(d, a))
    path = b.save(tmp_path / "models" / "baselines.json")
    json.loads(path.read_text())
    b2 = BaselineSensorModel.load(path)
    assert b2.rssi.to_dict() == ld.to_dict()
    np.testing.assert_array_equal(b2.detection.n_reads, gc.n_reads)
    np.testing.assert_allclose(b2.rho(d, a), b.rho(d, a))
    bad = json.loads(path.read_text())
    bad["log_distance"]["extra"] = 1
    (tmp_path / "bad.json").write_text(json.dumps(bad))
    with pytest.raises(ValueError, match="bad.json: log_distance: unknown key.*'extra'"):
        BaselineSensorModel.load(tmp_path / "bad.json")
