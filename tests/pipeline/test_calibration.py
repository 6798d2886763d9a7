"""Calibration: the fit finds the parameters of reads drawn from its own model, inside its
intervals; a gain common to all antennas moves into the sensitivity and RSSI offsets as
documented; the calibrated overlay is a valid study config with the fitted values."""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest
from scipy.special import ndtr

from pipeline.config import StudyConfig, config_from_mapping, config_to_toml
from pipeline.evaluation.calibration import CalibrationFit, calibrate, fit_calibration
from propagation.linkbudget import LinkBudget

BUDGET = LinkBudget()


def _attempts(rng, *, offsets=(0.0, -3.0), dsens=-2.0, roff=1.5, sigma_r=1.0, sigma_t=1.5, q=0.1,
              n_tags=60, per_tag=80):
    """Attempts drawn from the calibration's own model: each tag's gains around the read
    threshold (the one-way gain at which the tag wakes), half the tags held out."""
    g0 = BUDGET.min_gain_db()
    tag = np.repeat(np.arange(n_tags), per_tag)
    gain = g0 + rng.uniform(-8.0, 12.0, tag.size)
    ant = rng.integers(0, 2, tag.size)
    g = gain + np.asarray(offsets)[ant]
    m = np.minimum(BUDGET.tag_power_dbm(g) - (BUDGET.tag_sensitivity_dbm + dsens),
                   BUDGET.reader_rssi_dbm(g) - BUDGET.reader_sensitivity_dbm)
    read = rng.random(tag.size) < (1 - q) * ndtr(m / sigma_t)
    rssi = np.where(read, BUDGET.reader_rssi_dbm(g) + roff + sigma_r * rng.standard_normal(tag.size),
                    np.nan)
    return pd.DataFrame({"tag_id": [f"T{t}" for t in tag], "antenna": ant, "gain_db": gain,
                         "read": read, "rssi_dbm": rssi,
                         "split": np.where(tag % 2 == 0, "train", "eval"),
                         "p_sim": np.where(BUDGET.detected(gain), 0.95, 0.0),
                         "rssi_sim_dbm": np.where(BUDGET.detected(gain), BUDGET.reader_rssi_dbm(gain), np.nan)})


def test_fit_recovers_its_own_model_inside_the_intervals():
    att = _attempts(np.random.default_rng(1))
    fit, rep = calibrate(att, BUDGET, 2, miss_probability=0.05, seed=3, n_boot=40)
    truth = {"antenna_offset_db[1]": -3.0, "tag_sensitivity_offset_db": -2.0, "rssi_offset_db": 1.5,
             "rssi_noise_db": 1.0, "detection_spread_db": 1.5, "miss_probability": 0.1}
    for key, want in truth.items():
        p = rep["parameters"][key]
        assert p["low"] <= want <= p["high"], (key, p)
        # 30 training tags x 80 attempts: the RSSI terms to a few tenths of a dB
        assert p["value"] == pytest.approx(want, abs=0.6 if "offset" in key else 0.1), key
    h = rep["heldout"]["rssi_mae_db"]
    # before: the uncalibrated budget misses the planted offsets; after: near the noise's
    # own mean absolute value sqrt(2/pi) sigma_r = 0.80 dB
    assert h["after"]["estimate"] < 0.9 < h["before"]["estimate"]
    assert h["difference"]["verdict"] == "better"


def test_a_gain_common_to_all_antennas_is_a_sensitivity_and_rssi_offset():
    """delta_a + t, delta_s + t, r - 2t give the same reads: antenna 0 is the reference."""
    att = _attempts(np.random.default_rng(2), offsets=(2.0, 2.0), dsens=0.0, roff=0.0)
    fit = fit_calibration(att[att["split"] == "train"], BUDGET, 2)
    assert fit.antenna_offsets_db[0] == 0.0
    assert fit.antenna_offsets_db[1] == pytest.approx(0.0, abs=0.5)
    assert fit.tag_sensitivity_offset_db == pytest.approx(-2.0, abs=0.5)
    assert fit.rssi_offset_db == pytest.approx(4.0, abs=0.3)  # twice the common gain


def test_calibrated_overlay_is_a_study_with_the_fitted_reader():
    from pipeline.stages.calibration import calibrated_config

    cfg = StudyConfig()
    fit = CalibrationFit(np.array([0.0, -3.0]), -2.0, 1.5, 1.2, 1.5, 0.1)
    out = calibrated_config(cfg, fit)
    back = config_from_mapping(__import__("tomllib").loads(config_to_toml(out)))
    assert [a.cable_loss_db for a in back.robot.antennas] == [0.0, 3.0]
    assert back.reader.tag_sensitivity_dbm == cfg.reader.tag_sensitivity_dbm - 2.0
    assert back.reader.rssi_offset_db == 1.5
    # the fitted spread less the 0.5 dB quantisation's own (0.5^2 / 12)
    assert back.reader.rssi_noise_db == pytest.approx(np.sqrt(1.2 ** 2 - 0.25 / 12))
    assert not back.recording.enabled
