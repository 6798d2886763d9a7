"""Held-out scores: the floor is fitted on training data only; the error budget adds up."""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest

from pipeline.evaluation.cells import CellGrid
from pipeline.evaluation.heldout import error_budget, heldout_scores
from pipeline.evaluation.truth import detection_truth, true_rssi_dbm
from propagation import LinkBudget
from tests.helpers.constant_sensor import ConstantSensor


def _reads(rng, n, gain_offset_db):
    d = rng.uniform(0.3, 2.9, n)
    a = rng.uniform(-1.4, 1.4, n)
    gain = -20 - 20 * np.log10(d) + gain_offset_db + rng.normal(0, 2, n)
    return pd.DataFrame({"tag_id": rng.choice(["A", "B"], n), "read": rng.random(n) < 0.8,
                         "rssi_dbm": np.nan, "d_true_m": d, "alpha_true_rad": a, "gain_db": gain})


def test_floor_comes_from_the_training_truth():
    rng = np.random.default_rng(0)
    budget = LinkBudget()
    grid = CellGrid(d_max_m=3.0, d_bin_m=0.5, alpha_bin_deg=30.0)
    train = _reads(rng, 4000, 0.0)
    held = _reads(rng, 4000, 3.0)  # the held-out building is 3 dB stronger everywhere
    tt = detection_truth(train, budget, grid=grid)
    et = detection_truth(held, budget, grid=grid)
    s = ConstantSensor(-50.0, 0.5)
    out = heldout_scores({"m": s}, held, tt, et, budget, d_max_m=3.0, min_attempts=5)
    # a floor fitted on the held-out data would have ~0 bias; fitted on training it is
    # off by the 3 dB (x2 in RSSI: the backscatter link crosses the channel twice)
    assert out["floor"]["rssi_dbm"]["bias"] == pytest.approx(-6.0, abs=0.5)
    truth = true_rssi_dbm(held["gain_db"].to_numpy(), budget)
    closed = budget.detected(held["gain_db"].to_numpy())
    np.testing.assert_allclose(out["models"]["m"]["rssi_dbm"]["bias"],
                               np.mean(-50.0 - truth[closed]), rtol=1e-9)
    # matched comparison: the model scored on exactly the floor's links
    assert out["models"]["m"]["rssi_dbm_floor_links"]["n"] == out["floor"]["rssi_dbm"]["n"]


def test_error_budget_steps():
    held = {"models": {"anfis": {"rssi_dbm": {"rmse": 6.0}, "rssi_dbm_floor_links": {"rmse": 5.0}},
                       "anfis_truepose": {"rssi_dbm": {"rmse": 6.5},
                                          "rssi_dbm_floor_links": {"rmse": 4.0}}},
            "floor": {"rssi_dbm": {"rmse": 3.0, "n": 10}}, "data": {"reader_noise": {"rmse": 1.0}}}
    b = error_budget(held)
    assert b["model_form"]["step_db"] == pytest.approx(1.0)
    assert b["model_form"]["step_quadrature_db"] == pytest.approx(np.sqrt(16 - 9))
    assert b["localisation"]["step_quadrature_db"] == pytest.approx(3.0)
    # the steps compare matched links; the total is the model on all links
    assert b["total"]["rmse_db"] == 6.0 and b["reader_noise"]["rmse_db"] == 1.0
    assert b["n_links"]["value"] == 10
