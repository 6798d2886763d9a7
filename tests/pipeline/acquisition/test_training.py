"""Training-set builders on hand-built read tables: exact counts -> fT, SSM filtering."""

import numpy as np
import pandas as pd
import pytest

from pipeline.acquisition import TrainingSet, ssm_samples, tdm_samples


def _reads(rows):
    """rows: (d_est_m, alpha_est_rad, read, rssi_dbm); true pose = est pose + 1 m."""
    d, a, r, s = (np.array(c) for c in zip(*rows, strict=True))
    return pd.DataFrame(
        {
            "read": r.astype(bool),
            "rssi_dbm": np.where(r, s, np.nan).astype(float),
            "d_est_m": d.astype(float),
            "alpha_est_rad": a.astype(float),
            "d_true_m": d.astype(float) + 1.0,
            "alpha_true_rad": a.astype(float),
        }
    )


def test_tdm_exact_counts():
    # Cell A: d in [0, 0.25), alpha in [0, 10 deg): 3 reads, 1 miss -> fT 0.75.
    # Cell B: d in [1.0, 1.25), alpha in [-10 deg, 0): 0 reads, 2 misses -> fT 0.
    # A row with d >= d_max (3 m) is out of range and counts nowhere.
    a5 = np.deg2rad(5.0)
    rows = [(0.1, a5, 1, -40), (0.2, a5, 1, -41), (0.05, a5, 1, -42), (0.24, a5, 0, 0)]
    rows += [(1.1, -a5, 0, 0), (1.2, -a5, 0, 0), (3.5, a5, 0, 0)]
    ts = tdm_samples(_reads(rows), d_bin_m=0.25, alpha_bin_deg=10, d_max_m=3.0, pose="est")
    assert len(ts) == 2
    # Cells come ordered by d bin, then alpha bin; tolerance: float rounding of centres.
    np.testing.assert_allclose(ts.X, [[0.125, a5], [1.125, -a5]], atol=1e-12)
    np.testing.assert_array_equal(ts.n_pos, [3, 0])
    np.testing.assert_array_equal(ts.n_neg, [1, 2])
    np.testing.assert_allclose(ts.y, [0.75, 0.0])
    assert ts.description["n_attempts"] == 6
    np.testing.assert_array_equal(ts.weights, [4, 2])


def test_tdm_min_attempts_and_true_pose():
    a5 = np.deg2rad(5.0)
    rows = [(0.1, a5, 1, -40)] * 4 + [(1.1, a5, 0, 0)] * 2
    df = _reads(rows)
    ts = tdm_samples(df, d_max_m=3.0, min_attempts=3)
    assert len(ts) == 1 and ts.n_pos[0] == 4
    # True poses are 1 m farther: the four reads move to d bin [1.0, 1.25).
    tt = tdm_samples(df, d_max_m=3.0, pose="true")
    np.testing.assert_allclose(tt.X[:, 0], [1.125, 2.125])


def test_ssm_filters_and_normalises():
    rows = [(0.5, 0.1, 1, -40.0), (1.0, 0.2, 1, -60.0), (2.9, 0.3, 1, -80.0)]
    rows += [(3.0, 0.0, 1, -50.0), (1.0, 0.0, 0, 0.0)]
    ss = ssm_samples(_reads(rows), d_max_m=3.0, rssi_range_dbm=(-80.0, -40.0))
    # d = 3.0 is excluded (d < d_max) and misses never enter the SSM set.
    assert len(ss) == 3
    np.testing.assert_allclose(ss.X, [[0.5, 0.1], [1.0, 0.2], [2.9, 0.3]])
    np.testing.assert_allclose(ss.y, [1.0, 0.5, 0.0])
    assert ss.rssi_range_dbm == (-80.0, -40.0)
    # Default range from the data: (floor(min), ceil(max)).
    sd = ssm_samples(_reads(rows), d_max_m=3.0)
    assert sd.rssi_range_dbm == (-80.0, -40.0)


def test_roundtrip_parquet(tmp_path):
    a5 = np.deg2rad(5.0)
    rows = [(0.1, a5, 1, -40), (0.2, a5, 0, 0), (1.1, -a5, 1, -55)]
    ts = tdm_samples(_reads(rows))
    back = TrainingSet.from_parquet(ts.to_parquet(tmp_path / "tdm.parquet"))
    np.testing.assert_array_equal(back.X, ts.X)
    np.testing.assert_array_equal(back.n_pos, ts.n_pos)
    assert back.kind == "tdm" and back.description == ts.description
    ss = ssm_samples(_reads(rows), rssi_range_dbm=(-90, -30))
    back = TrainingSet.from_parquet(ss.to_parquet(tmp_path / "ssm.parquet"))
    assert back.rssi_range_dbm == (-90.0, -30.0) and back.n_pos is None
    np.testing.assert_array_equal(back.y, ss.y)


def test_bad_input_named():
    df = _reads([(0.1, 0.0, 1, -40)])
    with pytest.raises(ValueError, match="pose"):
        ssm_samples(df, pose="odom")
    with pytest.raises(ValueError, match="alpha_bin_deg"):
        tdm_samples(df, alpha_bin_deg=7)
    with pytest.raises(ValueError, match="d_bin_m"):
        tdm_samples(df, d_bin_m=0)
    with pytest.raises(ValueError, match="d_est_m"):
        ssm_samples(df.drop(columns=["d_est_m"]))


def _tdm_set(seed=0):
    """A TDM set of 60 cells with 1 to 300 attempts each (weights), via tdm_samples."""
    rng = np.random.default_rng(seed)
    rows = []
    d_c = np.arange(0.125, 3.0, 0.25)
    a_c = np.deg2rad(np.arange(-40.0, 50.0, 20.0))
    for d in d_c:
        for a in a_c:
            n = int(rng.integers(1, 300))
            p = 1.0 / (1.0 + np.exp(3.0 * (d - 1.5)))
            reads = rng.random(n) < p
            rows += [(d, a, int(r), -50.0) for r in reads]
    return tdm_samples(_reads(rows), d_bin_m=0.25, alpha_bin_deg=20, d_max_m=3.0)


def test_tdm_weights_are_attempts_and_survive_parquet(tmp_path):
    ts = _tdm_set()
    assert ts.weights.dtype == np.float64 and ts.weights.shape == (len(ts),)
    np.testing.assert_array_equal(ts.weights, ts.n_pos + ts.n_neg)
    assert ts.weights.sum() == ts.description["n_attempts"]
    back = TrainingSet.from_parquet(ts.to_parquet(tmp_path / "tdm.parquet"))
    np.testing.assert_array_equal(back.weights, ts.weights)
    assert ssm_samples(_reads([(0.1, 0.0, 1, -40)])).weights is None


def test_model_fit_weights_tdm_cells_by_attempts_split_with_their_cells():
    from types import SimpleNamespace

    from pipeline.stages.models import _fit

    ts = _tdm_set(1)
    cfg = SimpleNamespace(n_clusters=2, fcm_exponent=2.0, epochs=5, step_size=0.01,
                          check_fraction=0.25, max_samples=0)
    model, hist = _fit(ts, cfg, np.random.default_rng(5), lambda **_: None)
    # the same split as pipeline.stages.models._split draws from the same generator
    n = len(ts)
    n_check = int(round(0.25 * n))
    perm = np.random.default_rng(5).permutation(n)
    c, t = perm[:n_check], perm[n_check:]
    w = ts.weights
    assert hist["weighted"] and hist["n_train"] == len(t) and hist["n_check"] == len(c)
    assert hist["train_weight_sum"] == pytest.approx(w[t].sum())
    # reported RMSEs of the kept epoch are the attempt-weighted ones on each part
    b = hist["best_epoch"]
    for idx, key in ((t, "train_rmse"), (c, "check_rmse")):
        r = ts.y[idx] - model.predict(ts.X[idx])
        want = np.sqrt(np.sum(w[idx] * r * r) / np.sum(w[idx]))
        assert hist[key][b] == pytest.approx(want, rel=1e-9)
    assert model.provenance["training"]["weighted"]
