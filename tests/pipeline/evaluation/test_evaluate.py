import json

import numpy as np
import pandas as pd
import pytest

from fuzzymodel import ANFIS, SensorModel, normalise_rssi
from pipeline.evaluation import (
    CellGrid,
    EvaluationInputs,
    LogDistanceModel,
    detection_truth,
    evaluate_all,
    fit_baselines,
    localisation_split,
    rho_points_truth,
    tags_table,
)
from tests.helpers.reads import gain_for_rssi, synthetic_reads

RANGE = (-90.0, -10.0)
TRUTH = LogDistanceModel(p0_dbm=-45.0, n=4.0, coefficients=(8.0,))
GRID = CellGrid(d_max_m=3.0, d_bin_m=0.25, alpha_bin_deg=30.0)


def train_sensor(reads, col="est", epochs=5):
    """A real fuzzymodel.SensorModel: FCM-initialised ANFIS for fs and fT (3 rules each)."""
    rd = reads[reads["read"] & (reads[f"d_{col}_m"] < 3.0)]
    X = rd[[f"d_{col}_m", f"alpha_{col}_rad"]].to_numpy()
    ssm = ANFIS.from_fcm(X, normalise_rssi(rd["rssi_dbm"], RANGE), n_clusters=3,
                         rng=np.random.default_rng(0))
    ssm.fit(X, normalise_rssi(rd["rssi_dbm"], RANGE), epochs=epochs)
    idx = GRID.index(reads[f"d_{col}_m"], reads[f"alpha_{col}_rad"])
    n = np.bincount(idx.flat[idx.valid], minlength=GRID.n_d * GRID.n_alpha)
    k = np.bincount(idx.flat[idx.valid], weights=reads["read"].to_numpy(float)[idx.valid],
                    minlength=GRID.n_d * GRID.n_alpha)
    D, A = GRID.centre_mesh()
    seen = n > 0
    Xc = np.column_stack([D.ravel()[seen], A.ravel()[seen]])
    tdm = ANFIS.from_fcm(Xc, k[seen] / n[seen], n_clusters=3, rng=np.random.default_rng(0))
    tdm.fit(Xc, k[seen] / n[seen], epochs=epochs)
    return SensorModel(ssm, tdm, RANGE)




def _inputs(budget, rng):
    reads = synthetic_reads(TRUTH.predict_dbm, budget, rng, n=3000, est_noise_m=0.3)
    truth = detection_truth(reads, budget, GRID)
    tags = tags_table([f"t{i}" for i in range(7)],
                      np.column_stack([np.linspace(0.5, 2.5, 7), np.full(7, 0.5), np.ones(7)]))
    ev = reads.iloc[:200].copy()
    pose = np.array([0.0, 0.0, 1.0, 0.0])
    D, A = GRID.centre_mesh()
    pts = np.column_stack([D.ravel() * np.cos(A.ravel()), D.ravel() * np.sin(A.ravel()),
                           np.ones(D.size)])

    rp = rho_points_truth(pose, pts, gain_for_rssi(budget, TRUTH.predict_dbm(D, A).ravel()),
                          budget, RANGE, grid_shape=D.shape)
    return reads, EvaluationInputs(reads=reads, truth=truth, budget=budget, eval_reads=ev,
                                   tags=tags, rho_points=[rp], min_attempts=5)


def test_evaluate_all_on_anfis_and_baseline_is_json(budget):
    reads, inputs = _inputs(budget, np.random.default_rng(1))
    sensors = {
        "anfis": train_sensor(reads, "est"),
        "anfis_truepose": train_sensor(reads, "true"),
        "baseline": fit_baselines(reads, RANGE, GRID, pose="est"),
    }
    m = evaluate_all(sensors, inputs)
    d = m.to_dict()
    text = json.dumps(d, allow_nan=False)
    assert set(d["models"]) == {"anfis", "anfis_truepose", "baseline"}
    for name in d["models"]:
        sec = d["models"][name]
        assert sec["rssi_dbm"]["n"] > 500
        assert 0 <= sec["detection"]["brier"] <= 1
        assert sec["rho"]["n"] == GRID.n_d * GRID.n_alpha
        assert sec["fig7"]["n_groups"] > 0
    assert "rssi_dbm.mae" in d["localisation_split"]["difference"]
    assert d["truth"]["n_attempts"] == int((reads["d_true_m"] < 3.0).sum())
    assert "NaN" not in text


def test_localisation_noise_costs_accuracy_for_the_log_distance_fit(budget):
    # Errors in the regressor (0.3 m on d) bias the least-squares path-loss exponent
    # towards 0 (regression dilution), so the model trained on noisy poses is worse at
    # the true geometry than the one trained on true poses.
    reads, inputs = _inputs(budget, np.random.default_rng(2))
    est = fit_baselines(reads, RANGE, GRID, pose="est")
    true = fit_baselines(reads, RANGE, GRID, pose="true")
    assert est.rssi.n < true.rssi.n
    assert true.rssi.n == pytest.approx(4.0, abs=1e-6)  # noiseless truth: exact
    split = localisation_split(est, true, inputs)
    assert split.true.rssi.stats.mae < 1e-6
    assert split.difference["rssi_dbm.mae"] > 0.5
    json.dumps(split.to_dict(), allow_nan=False)


def test_inputs_errors(budget):
    reads, inputs = _inputs(budget, np.random.default_rng(3))
    with pytest.raises(ValueError, match="no models"):
        evaluate_all({}, inputs)
    with pytest.raises(TypeError, match="lacks"):
        evaluate_all({"x": object()}, inputs)
    with pytest.raises(ValueError, match="missing column.*gain_db"):
        detection_truth(pd.DataFrame(reads.drop(columns="gain_db")), budget, GRID)
