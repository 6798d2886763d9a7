"""Calibration: the fit finds the parameters of reads drawn from its own model, inside its
intervals; a gain common to all antennas moves into the sensitivity and RSSI offsets as
documented; the calibrated overlay is a valid study config with the fitted values."""

from __future__ import annotations

import dataclasses

import numpy as np
import pandas as pd
import pytest
from scipy.special import ndtr

from pipeline.config import StudyConfig, config_from_mapping, config_to_toml
from pipeline.evaluation.calibration import (
    CalibrationFit,
    MaterialModel,
    calibrate,
    fit_calibration,
)
from propagation.linkbudget import LinkBudget

BUDGET = LinkBudget()


def _attempts(rng, *, offsets=(0.0, -3.0), dsens=-2.0, roff=1.5, sigma_r=1.0, sigma_t=1.5, q=0.1,
              n_tags=60, per_tag=80, dof=np.inf, stray=0.0):
    """Attempts drawn from the calibration's own model: each tag's gains around the read
    threshold (the one-way gain at which the tag wakes), half the tags held out; the RSSI
    noise Student-t with ``dof`` degrees of freedom (inf: Gaussian), a share ``stray`` of
    attempts read whatever their margin."""
    g0 = BUDGET.min_gain_db()
    tag = np.repeat(np.arange(n_tags), per_tag)
    gain = g0 + rng.uniform(-8.0, 12.0, tag.size)
    ant = rng.integers(0, 2, tag.size)
    g = gain + np.asarray(offsets)[ant]
    m = np.minimum(BUDGET.tag_power_dbm(g) - (BUDGET.tag_sensitivity_dbm + dsens),
                   BUDGET.reader_rssi_dbm(g) - BUDGET.reader_sensitivity_dbm)
    read = rng.random(tag.size) < (1 - q) * (stray + (1 - stray) * ndtr(m / sigma_t))
    noise = rng.standard_normal(tag.size) if np.isinf(dof) else rng.standard_t(dof, tag.size)
    rssi = np.where(read, BUDGET.reader_rssi_dbm(g) + roff + sigma_r * noise, np.nan)
    return pd.DataFrame({"tag_id": [f"T{t}" for t in tag], "antenna": ant, "gain_db": gain,
                         "read": read, "rssi_dbm": rssi,
                         "split": np.where(tag % 2 == 0, "train", "eval"),
                         "p_sim": np.where(BUDGET.detected(gain), 0.95, 0.0),
                         "rssi_sim_dbm": np.where(BUDGET.detected(gain), BUDGET.reader_rssi_dbm(gain), np.nan)})


EPS_TRACED = 5.24  # P.2040 concrete, the traced wall


def wall_study(eps_true: float, seed: int = 5):
    """Attempts whose gain is a direct path plus a wall reflection (normal-incidence Fresnel
    amplitude of the wall's permittivity, random relative amplitude and phase), the reads
    drawn with the wall at ``eps_true``; the model's wall is traced at EPS_TRACED."""
    rng = np.random.default_rng(seed)
    att = _attempts(rng, offsets=(0.0, 0.0), dsens=0.0, roff=0.0, q=0.0)
    n = len(att)
    amp, phi = rng.uniform(0.5, 1.5, n), rng.uniform(0, 2 * np.pi, n)

    def gain_db(eps):
        r = (np.sqrt(eps) - 1) / (np.sqrt(eps) + 1)
        return 20 * np.log10(np.abs(1 + amp * r * np.exp(1j * phi)))

    g = att["gain_db"].to_numpy() + gain_db(eps_true) - gain_db(EPS_TRACED)
    m = np.minimum(BUDGET.tag_power_dbm(g) - BUDGET.tag_sensitivity_dbm,
                   BUDGET.reader_rssi_dbm(g) - BUDGET.reader_sensitivity_dbm)
    read = rng.random(n) < ndtr(m / 1.5)
    att["read"] = read
    att["rssi_dbm"] = np.where(read, BUDGET.reader_rssi_dbm(g) + rng.standard_normal(n), np.nan)
    model = MaterialModel(("wall.relative_permittivity",), np.array([EPS_TRACED]),
                          np.array([np.log(1 / EPS_TRACED)]), np.array([np.log(4.0)]),
                          lambda theta: gain_db(EPS_TRACED * np.exp(theta[0])) - gain_db(EPS_TRACED), {})
    return att, model


def test_fit_recovers_its_own_model_inside_the_intervals():
    # the model's interior: t-distributed RSSI noise (4 dof) and 3 % stray reads (Gaussian
    # noise and no stray reads are the edges of their ranges, DOF_RANGE and 1e-4)
    att = _attempts(np.random.default_rng(1), dof=4.0, stray=0.03)
    fit, rep = calibrate(att, BUDGET, 2, miss_probability=0.05, seed=3, n_boot=40)
    truth = {"antenna_offset_db[1]": -3.0, "tag_sensitivity_offset_db": -2.0, "rssi_offset_db": 1.5,
             "rssi_noise_db": 1.0, "detection_spread_db": 1.5, "miss_probability": 0.1,
             "rssi_dof": 4.0, "stray_read_probability": 0.03}
    for key, want in truth.items():
        p = rep["parameters"][key]
        assert p["low"] <= want <= p["high"], (key, p)
        # 30 training tags x 80 attempts: the RSSI terms to a few tenths of a dB; the stray
        # reads trade against the probit's tails, so the detection spread to 0.2 dB (its
        # interval is +-0.18 dB wide here)
        tol = {"rssi_dof": 1.5, "stray_read_probability": 0.02,
               "detection_spread_db": 0.2}.get(key, 0.6 if "offset" in key else 0.1)
        assert p["value"] == pytest.approx(want, abs=tol), key
    h = rep["heldout"]["rssi_mae_db"]
    # before: the uncalibrated budget misses the planted offsets; after: near the noise's
    # own mean absolute value E|T_4| sigma_r = 1.00 dB
    assert h["after"]["estimate"] < 1.1 < h["before"]["estimate"]
    assert h["difference"]["verdict"] == "better"


def test_outliers_of_pose_error_pull_the_gaussian_fit_not_the_robust_one():
    """What a recorded pose's error does (module doc of pipeline.evaluation.calibration):
    10 % of the reads' RSSI 15 dB above the model's, and 5 % of the misses read anyway with
    an RSSI 15 dB above their traced link's (a pose on the lit side of a shadow). The
    Gaussian likelihood's RSSI offset takes the outliers' mean shift (> 1 dB); the robust
    one (Student-t RSSI, stray reads) finds the planted offsets."""
    rng = np.random.default_rng(0)
    att = _attempts(rng)
    read, rssi = att["read"].to_numpy().copy(), att["rssi_dbm"].to_numpy().copy()
    g = att["gain_db"].to_numpy() + np.array([0.0, -3.0])[att["antenna"].to_numpy()]
    stray = ~read & (rng.random(len(att)) < 0.05)
    rssi[stray] = BUDGET.reader_rssi_dbm(g[stray]) + 1.5 + rng.standard_normal(stray.sum()) + 15.0
    off = read & (rng.random(len(att)) < 0.10)
    rssi[off] += 15.0
    train = att.assign(read=read | stray, rssi_dbm=rssi).query("split == 'train'")
    truth = {"antenna_offset_db[1]": -3.0, "tag_sensitivity_offset_db": -2.0, "rssi_offset_db": 1.5}
    # Tolerance 0.5 dB: on clean data of this size the 95 % intervals are +-0.1 dB wide for
    # the RSSI and antenna offsets and +-0.2 dB for the sensitivity (the test above); the
    # outliers keep a residual weight (nu + 1) / (nu + e^2) in the t's score, and six seeds
    # of this draw put the robust fit within 0.3 dB. 0.5 dB is a third of the 1.5 dB mean
    # shift the planted outliers give the reads' RSSI, which the Gaussian fit absorbs.
    gauss = fit_calibration(train, BUDGET, 2, robust=False).as_dict()
    robust = fit_calibration(train, BUDGET, 2).as_dict()
    assert "rssi_dof" not in gauss
    assert gauss["rssi_offset_db"] - truth["rssi_offset_db"] > 1.0, gauss
    assert gauss["rssi_noise_db"] > 4.0  # the outliers widen the Gaussian's spread
    for key, want in truth.items():
        assert robust[key] == pytest.approx(want, abs=0.5), (key, robust)
    assert robust["rssi_noise_db"] < 1.1  # the bulk's spread, not the outliers'
    assert 0.02 < robust["stray_read_probability"] < 0.1, robust  # ~ 0.05 / (1 - q) planted


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
    # the fitted spread less the 0.5 dB quantisation's own (0.5^2 / 12)
    assert back.reader.rssi_noise_db == pytest.approx(np.sqrt(1.2 ** 2 - 0.25 / 12))
    assert not back.recording.enabled


def test_calibrated_overlay_is_per_material_first_construction_first():
    """Constructions in order of power share: a material fitted in two thicknesses takes
    the first's values; a config naming the material by an ITU alias is the same material;
    a conductivity not fitted keeps the config's own."""
    from pipeline.sceneconfig import MaterialConfig
    from pipeline.stages.calibration import calibrated_config

    cfg = dataclasses.replace(StudyConfig(), materials=(
        MaterialConfig(name="itu_concrete", relative_permittivity=5.0, conductivity_s_per_m=0.05),
        MaterialConfig(name="brick", conductivity_s_per_m=0.03)))
    fit = CalibrationFit(np.array([0.0, 0.0]), 0.0, 0.0, 1.0, 1.0)
    out = calibrated_config(cfg, fit, {"uhf-concrete-t0p200": (6.0, 0.1),
                                       "uhf-concrete-t0p100": (3.0, None),
                                       "uhf-brick-t0p120": (4.5, None)})
    by = {m.name: m for m in out.materials}
    assert set(by) == {"concrete", "brick"}
    assert (by["concrete"].relative_permittivity, by["concrete"].conductivity_s_per_m) == (6.0, 0.1)
    assert (by["brick"].relative_permittivity, by["brick"].conductivity_s_per_m) == (4.5, 0.03)
    back = config_from_mapping(__import__("tomllib").loads(config_to_toml(out)))
    assert back.materials == out.materials


def test_untraced_attempts_are_left_out_and_counted():
    """A read on a link the tracer found no path for (gain -inf) would make the likelihood
    infinite and stall the fit at its start: such attempts are left out and counted."""
    att = _attempts(np.random.default_rng(4), n_tags=20, per_tag=60)
    bad = att.iloc[:3].assign(gain_db=-np.inf, read=True, rssi_dbm=-70.0)
    fit, rep = calibrate(pd.concat([att, bad], ignore_index=True), BUDGET, 2, seed=1, n_boot=20)
    assert rep["n_attempts_untraced"] == 3 and rep["n_reads_untraced"] == 3
    assert fit.antenna_offsets_db[1] == pytest.approx(-3.0, abs=0.7)  # not the start value 0
    with pytest.raises(ValueError, match="without a traced gain"):
        fit_calibration(bad, BUDGET, 2)


def test_a_fit_that_cannot_explain_the_reads_stops():
    """Reads where the budget says no tag can wake (40 dB below the threshold) drive the
    offsets to the edge of their range: a failed fit, stopped with a message."""
    att = _attempts(np.random.default_rng(5), n_tags=10, per_tag=40)
    att = att.assign(gain_db=att["gain_db"] - 60.0)
    with pytest.raises(ValueError, match="edge of its range"):
        fit_calibration(att, BUDGET, 2)


def test_cable_losses_are_refused_where_the_truth_would_not_see_them(tmp_path):
    import dataclasses

    from pipeline.apps.studyrun import run_full_study
    from pipeline.config import ConfigError

    cfg = StudyConfig()
    ants = list(cfg.robot.antennas)
    ants[1] = dataclasses.replace(ants[1], cable_loss_db=3.0)
    lossy = dataclasses.replace(cfg, robot=dataclasses.replace(cfg.robot, antennas=tuple(ants)))
    with pytest.raises(ConfigError, match=r"robot.antennas\[1\].cable_loss_db = 3.0"):
        run_full_study(lossy, tmp_path / "run")
    assert not (tmp_path / "run").exists()  # refused before the run directory is made


def test_calibrate_without_a_recording_stops_before_running(tmp_path):
    from typer.testing import CliRunner

    from pipeline.apps.cli import app

    res = CliRunner().invoke(app, ["calibrate", "configs/tiny.toml", "--out", str(tmp_path / "c")])
    assert res.exit_code == 2 and "no recording to calibrate to" in res.output
    assert not (tmp_path / "c").exists()


def test_a_log_from_another_region_stops():
    from pipeline.recording import Recording, RecordingError
    from pipeline.stages.recorded import _check_channels

    reads = pd.DataFrame({"t_s": [0.0], "antenna_port": [1], "rssi_dbm": [-60.0], "epc": ["AB"],
                          "phase_rad": [0.0], "frequency_hz": [915.25e6], "doppler_hz": [0.0],
                          "seen_count": [1]})
    rec = Recording(reads, None, pd.DataFrame(), "impinj", {})
    with pytest.raises(RecordingError, match=r"reader.region = 'ETSI'.*915.250 MHz"):
        _check_channels(rec, StudyConfig())
    _check_channels(rec, StudyConfig().__class__(reader=dataclasses_replace_region("FCC")))


def dataclasses_replace_region(region):
    import dataclasses

    return dataclasses.replace(StudyConfig().reader, region=region)


def test_a_planted_wall_permittivity_is_recovered_through_the_nonlinear_gains():
    """Each attempt: a direct path plus a wall reflection of relative amplitude a and phase
    phi (normal-incidence Fresnel |r| of the wall's permittivity); reads drawn with the wall
    at eps 8, the model traced at P.2040 concrete's 5.24. The gain change is nonlinear in
    the permittivity (interference), and the planted log ratio 0.42 is beyond one
    Gauss-Newton step (MATERIAL_TRUST, x1.5): found only by re-linearising."""
    from pipeline.evaluation.calibration import MATERIAL_TRUST

    eps_true = 8.0
    assert np.log(eps_true / EPS_TRACED) > MATERIAL_TRUST
    att, model = wall_study(eps_true)
    eps0 = EPS_TRACED
    fit, rep = calibrate(att, BUDGET, 2, seed=3, n_boot=40, materials=model)
    p = rep["parameters"]["wall.relative_permittivity"]
    assert p["traced"] == eps0 and p["unit"] == ""
    assert p["low"] <= eps_true <= p["high"], p
    assert p["value"] == pytest.approx(eps_true, rel=0.15)
    assert len(rep["constructions"]["gauss_newton_log_ratios"]) >= 3  # two steps at least
    assert rep["constructions"]["converged"] is True
    # the interval is the bootstrap's over the whole range, not the last step's trust region
    assert p["high"] / p["low"] < 1.5 ** 2
    # the reader's offsets alone cannot absorb an interference pattern: on the same held-out
    # tags the fit with the wall is better, by an interval
    vs = rep["constructions"]["heldout_against_reader_only"]["rssi_mae_db"]
    assert vs["difference"]["verdict"] == "better", vs


def test_a_calibration_worse_on_held_out_tags_is_named():
    from pipeline.stages.calibration import heldout_worse

    def sec(before, after, verdict):
        return {"label": "RSSI MAE [dB]", "before": {"estimate": before}, "after": {"estimate": after},
                "difference": {"verdict": verdict}}

    assert heldout_worse({"heldout": {"rssi_mae_db": sec(5.0, 1.0, "better")}}) is None
    msg = heldout_worse({"heldout": {"rssi_mae_db": sec(5.31, 7.08, "worse"), "n_tags": 58}})
    assert "RSSI MAE [dB] 5.31 -> 7.08" in msg and "calibrated.toml" not in msg
