"""The recorded study: a simulated study exported as a recording and run as one gives back
the simulated attempts exactly (the attempts rule), fits its models, scores them on
held-out tags and compares the ray tracer with the log; the Impinj units by hand; bad
recordings stop with one line naming the file and nothing half-written."""

from __future__ import annotations

import json
import math

import numpy as np
import pandas as pd
import pytest
from typer.testing import CliRunner

from pipeline.acquisition import ReaderConfig
from pipeline.apps.cli import app
from pipeline.apps.export.csv_export import EPOCH_S, tag_id_of
from pipeline.apps.studyrun import run_full_study
from pipeline.apps.targets import resolve_target
from pipeline.recording import (
    Recording,
    RecordingError,
    read_impinj_csv,
    recorded_read_table,
)
from pipeline.recording.config import recording_overrides
from pipeline.recording.load import detect_format
from pipeline.robot.kinematics import AntennaMount
from scenes.scene import TagSet
from tests.conftest import ROOT


@pytest.fixture(scope="module")
def recording(tiny_study, tmp_path_factory):
    out = tmp_path_factory.mktemp("rec") / "rec"
    res = CliRunner().invoke(app, ["export", str(tiny_study.run), "--out", str(out)])
    assert res.exit_code == 0, res.output
    return out


def _run(tiny_study, out, *args):
    cache = tiny_study.config.tracing.cache_dir
    return CliRunner().invoke(app, ["run", "configs/tiny.toml", "--out", str(out), "--no-progress",
                                    "--set", f"tracing.cache_dir={json.dumps(cache)}", *args])


def _attempts(run):
    rec = pd.concat([pd.read_parquet(run / "reads.parquet"),
                     pd.read_parquet(run / "eval_reads.parquet")], ignore_index=True)
    rec["tag_id"] = [tag_id_of(e) for e in rec["tag_id"].astype(str)]
    return rec


#: The calibration's tag-bootstrap refits in these runs (200 by default): no test here asserts
#: more of an interval than that the value lies in it (test_calibration.py asserts coverage)
RESAMPLES = "recording.calibration_resamples=20"


@pytest.fixture(scope="module")
def recorded_run(tiny_study, recording, tmp_path_factory):
    out = tmp_path_factory.mktemp("recrun") / "run"
    # the reader's parameters calibrated alone: the constructions' fit is
    # test_calibrate_writes_the_calibration_and_a_calibrated_study's (on a copy of this run)
    res = _run(tiny_study, out, "--recording", str(recording),
               "--set", "recording.calibrate_constructions=0", "--set", RESAMPLES)
    assert res.exit_code == 0, res.output
    return out


def test_recorded_study_rebuilds_the_simulated_attempts(tiny_study, recorded_run):
    sim = pd.read_parquet(tiny_study.run / "reads.parquet").assign(
        tag_id=lambda d: d["tag_id"].astype(str))
    rec = _attempts(recorded_run)
    key = ["cycle", "antenna", "tag_id"]
    m = sim.merge(rec, on=key, how="outer", suffixes=("_sim", "_rec"), indicator=True)
    # the same attempts (cycle, antenna, tag), none more, none fewer
    assert (m["_merge"] == "both").all() and len(m) == len(sim)
    # the same outcome of every attempt: a read is a read, a miss (no row in the log) a miss
    assert (m["read_sim"] == m["read_rec"]).all() and m["read_rec"].sum() > 50
    got = m[m["read_rec"]]
    # sllurp's whole dBm
    np.testing.assert_array_equal(got["rssi_dbm_rec"], np.round(got["rssi_dbm_sim"]))
    # the MCL poses the log was written with: the simulated est geometry, to the CSV's um
    np.testing.assert_allclose(m["d_est_m_rec"], m["d_est_m_sim"], atol=1e-5)


def test_recorded_study_scores_models_and_the_ray_tracer(recorded_run):
    met = json.loads((recorded_run / "metrics.json").read_text())
    assert met["source"] == "recording" and met["heldout"]["against"] == "measured"
    imp = met["recording"]
    assert imp["n_reads_unknown_epc"] == 0 and imp["n_off_schedule"] == 0
    assert imp["n_reads"] == imp["n_reads_in_file"] == imp["n_reports_used"]
    # held-out tags only, every model scored with an interval over them
    brier = met["intervals"]["heldout.detection_brier"]
    assert brier["unit"] == "tag" and {"anfis", "grid_count"} <= set(brier["models"])
    # its units: exactly the held-out tags with attempts inside the models' grid (d < 3 m)
    ev = pd.read_parquet(recorded_run / "eval_reads.parquet")
    near = ev.loc[ev["d_est_m"] < 3.0, "tag_id"].astype(str).nunique()
    assert brier["n_units"] == near >= 1
    iv = brier["models"]["anfis"]
    assert (iv["low"] is not None) if near >= 5 else "needs at least 5" in iv["note"]
    assert "anfis" not in met["comparisons"]["metrics"]["heldout.detection_brier"]
    svr = met["sim_vs_real"]["heldout"]
    for key in ("brier", "read_rate_mae", "rssi_bias_db", "rssi_mae_db", "rssi_rmse_db"):
        assert {"ray_tracer", "baseline", "difference"} <= set(svr[key])
    # the log was simulated in this very building: the ray tracer predicts its read
    # outcomes better than the log-distance baseline fitted on the training tags
    assert svr["brier"]["ray_tracer"]["estimate"] < svr["brier"]["baseline"]["estimate"]
    assert svr["brier"]["ray_tracer"]["estimate"] < 0.1
    # every training read's attempt was traced on the channel the reader reported for it
    # (held-out reads do not set channels: their outcome would leak into their prediction)
    att = pd.read_parquet(recorded_run / "sim_vs_real" / "attempts.parquet")
    rec = pd.read_parquet(recorded_run / "reads.parquet")[["cycle", "antenna", "tag_id", "read", "frequency_hz"]]
    rec["tag_id"] = rec["tag_id"].astype(str)
    both = att[["cycle", "antenna", "tag_id", "frequency_hz"]].merge(
        rec[rec["read"]], on=["cycle", "antenna", "tag_id"], suffixes=("_traced", "_reported"))
    assert len(both) > 50
    np.testing.assert_allclose(both["frequency_hz_traced"], both["frequency_hz_reported"], atol=1.0)
    ch = json.loads((recorded_run / "sim_vs_real" / "summary.json").read_text())["channels"]
    assert ch["reported"] > 0 and ch["reported"] + ch["filled_within_dwell"] + ch["hop_sequence"] == ch["n_slots"]
    tags = pd.read_parquet(recorded_run / "scene" / "tags.parquet")
    held = set(tags.loc[tags["split"] == "eval", "tag_id"].astype(str))
    train = set(pd.read_parquet(recorded_run / "reads.parquet")["tag_id"].astype(str))
    assert held and not held & train  # no model saw a held-out tag's reads
    cal = met["calibration"]  # the calibration stage's calibration.json
    assert {"antenna_offset_db[1]", "tag_sensitivity_offset_db", "rssi_offset_db"} <= set(cal["parameters"])
    assert cal["parameters"]["antenna_offset_db[0]"]["value"] == 0.0  # the reference antenna
    assert {"before", "after", "difference"} <= set(cal["heldout"]["brier"])
    html = (recorded_run / "report.html").read_text()
    assert "Calibration" in html
    assert "Simulation against the recording" in html and "data:image/png;base64" in html
    assert not (recorded_run / "truth").exists()  # no simulated truth in a recorded run


def test_recorded_study_localises_the_held_out_tags(recorded_run):
    """The downstream stage on a recording: every fitted model localises the held-out tags
    from their recorded reads, scored against the recording's tag layout, with intervals
    over tags in metrics.json; no robot filter (the poses are the only track) and no phase
    (sllurp's log has none), each said so."""
    down = json.loads((recorded_run / "downstream" / "scores.json").read_text())
    assert down["robot_localisation"].startswith("not run: a recording's poses are the only track")
    met = json.loads((recorded_run / "metrics.json").read_text())
    tl = met["tag_localisation"]
    assert tl == down["tag_localisation"] and met["robot_localisation"] == down["robot_localisation"]
    assert {"anfis", "log_distance", "grid_count", "joho2009", "vorst2008", "fcm_only"} <= set(tl)
    assert "no backscatter phase" in tl["phase"]["not_run"] and "oracle" not in tl
    tags = pd.read_parquet(recorded_run / "scene" / "tags.parquet")
    held = tags[tags["split"] == "eval"]
    errs = pd.read_parquet(recorded_run / "downstream" / "tag_errors.parquet")
    e = errs[errs["model"] == "anfis"].set_index("tag_id")["error_m"]
    # every held-out tag of the layout, none of the training tags, a finite error each
    assert set(e.index) == set(held["tag_id"].astype(str)) and tl["anfis"]["n_tags"] == len(held)
    assert np.isfinite(e).all() and (e > 0).all()  # no candidate sits on a tag
    iv = met["intervals"]["tag_localisation.median_m"]
    assert iv["unit"] == "tag" and iv["n_units"] == len(held)
    a = iv["models"]["anfis"]
    assert a["estimate"] == pytest.approx(tl["anfis"]["median_m"]) == pytest.approx(np.median(e))
    assert a["low"] <= a["estimate"] <= a["high"]
    assert "log_distance" in met["comparisons"]["metrics"]["tag_localisation.median_m"]
    # corridor_lab is 25 m long: an error on that scale is no localisation at all
    assert e.mean() < 25.0
    # Measured (configs/tiny.toml, seed 7): 7 held-out tags, two of them read (0.9 and 2.1 m
    # from the 5 m route), placed 0.23 and 1.77 m off; the five never read (x = 13-19.5 m)
    # all land on the first candidate beyond the far rule's reach (11 m from the route:
    # (16.3, 0.0, 2.9)), 1.9-4.3 m from them, for every model alike. The median (2.86 m) is
    # such a tag's; 5 m is more than any of them and fails where the truth is not the
    # recording's layout or a never-read tag lands inside the route's reach.
    assert float(np.median(e)) < 5.0
    ev = pd.read_parquet(recorded_run / "eval_reads.parquet")
    read = set(ev.loc[ev["read"], "tag_id"].astype(str))
    assert read and set(e.index) - read  # both kinds, as measured
    # a tag that was read is placed by its reads and their RSSI, near the poses that read
    # it: 0.23 and 1.77 m (the latter read from 2.1 m away at the closest), 1.0 m on
    # average against the never-read tags' 3.4 m
    never = sorted(set(e.index) - read)
    assert (e[sorted(read)] < 2.0).all() and e[sorted(read)].mean() < e[never].mean()
    # the phase estimator would run on reads with phases: the stage's own check, here
    assert not np.isfinite(ev.loc[ev["read"], "phase_rad"]).any()
    html = (recorded_run / "report.html").read_text()
    assert "Held-out tags localised" in html and "robot localisation not run" in html


def test_impinj_export_reads_back_in_si(tiny_study, recording, tmp_path):
    got = read_impinj_csv(recording / "reads_impinj.csv", "ETSI")
    sim = pd.read_parquet(tiny_study.run / "reads.parquet")
    sim = sim[sim["read"]]
    assert len(got) == len(sim)
    np.testing.assert_allclose(got["t_s"] - EPOCH_S, sim["time_s"], atol=1e-6)
    np.testing.assert_allclose(got["rssi_dbm"], sim["rssi_dbm"], atol=0.005)  # 0.01 dBm steps
    np.testing.assert_allclose(got["frequency_hz"], sim["frequency_hz"])  # channel index, ETSI
    dphi = np.angle(np.exp(1j * (got["phase_rad"].to_numpy() - sim["phase_rad"].to_numpy())))
    assert np.max(np.abs(dphi)) <= math.pi / 4096 + 1e-6  # half a 12-bit step
    np.testing.assert_allclose(got["doppler_hz"], sim["doppler_hz"], atol=1 / 32 + 1e-6)
    assert detect_format(recording / "reads_impinj.csv") == "impinj"
    assert detect_format(recording / "reads.csv") == "sllurp"


def test_impinj_units_by_hand(tmp_path):
    p = tmp_path / "r.csv"
    p.write_text("EPC,AntennaPort,LastSeenTimestampUTC,ImpinjPeakRSSI,ImpinjRFPhaseAngle,"
                 "ChannelIndex,ImpinjRFDopplerFrequency,TagSeenCount\n"
                 "e2801160,2,1767225600123456,-6543,1024,3,-40,4\n")
    r = read_impinj_csv(p, "ETSI").iloc[0]
    assert r["t_s"] == pytest.approx(1767225600.123456, abs=1e-6)
    assert r["rssi_dbm"] == pytest.approx(-65.43)
    assert r["phase_rad"] == pytest.approx(math.pi / 2)  # 1024 / 4096 of a turn
    assert r["frequency_hz"] == 866.9e6  # ETSI EN 302 208's third high-power channel
    assert r["doppler_hz"] == pytest.approx(-2.5)  # -40 / 16
    assert r["antenna_port"] == 2 and r["seen_count"] == 4 and r["epc"] == "E2801160"
    assert read_impinj_csv(p, "FCC").iloc[0]["frequency_hz"] == 903.75e6  # 902.75 + 2 x 0.5
    q = tmp_path / "octane.csv"
    q.write_text("Epc,AntennaPortNumber,LastSeenTime,PeakRssiInDbm,PhaseAngleInRadians,ChannelInMhz\n"
                 "AB,1,1000000,-60.5,3.0,865.7\n")
    r = read_impinj_csv(q).iloc[0]
    assert (r["t_s"], r["rssi_dbm"], r["phase_rad"], r["frequency_hz"]) == (1.0, -60.5, 3.0, 865.7e6)
    assert np.isnan(r["doppler_hz"]) and r["seen_count"] == 1


def test_impinj_reports_out_of_time_order_are_sorted_and_counted(tmp_path):
    p = tmp_path / "r.csv"
    p.write_text("EPC,AntennaPort,LastSeenTimestampUTC,ImpinjPeakRSSI\n"
                 "AB,1,9000000,-6000\nCD,2,5000000,-6100\nAB,1,9500000,-6200\n")
    r = read_impinj_csv(p)
    assert r["t_s"].tolist() == [5.0, 9.0, 9.5] and r["epc"].tolist() == ["CD", "AB", "AB"]
    assert r.attrs["n_reordered"] == 1


@pytest.mark.parametrize("body, region, words", [
    ("EPC,AntennaPort,ImpinjPeakRSSI\nAB,1,-6000\n", "ETSI", r":1: no t_s column"),
    ("EPC,AntennaPort,LastSeenTimestampUTC,ImpinjPeakRSSI,ChannelIndex\nAB,1,5,-6000,5\n", "ETSI",
     r":2: column 'ChannelIndex': channel index 5 is outside ETSI's table of 4"),
    ("EPC,AntennaPort,LastSeenTimestampUTC,ImpinjPeakRSSI,ChannelIndex\nAB,1,5,-6000,1\n", "",
     r":2: column 'ChannelIndex': .*recording.region"),
    ("EPC,AntennaPort,LastSeenTimestampUTC,ImpinjPeakRSSI\nAB,1,5,loud\n", "ETSI",
     r":2: column 'ImpinjPeakRSSI': 'loud' is not a number"),
])
def test_bad_impinj_files(tmp_path, body, region, words):
    p = tmp_path / "r.csv"
    p.write_text(body)
    with pytest.raises(RecordingError, match=words) as exc:
        read_impinj_csv(p, region)
    assert str(p) in str(exc.value) and "\n" not in str(exc.value)


def _hand_recording(reads, poses_t=(0.0, 2.0)):
    poses = pd.DataFrame({"t_s": list(poses_t), "x_m": [0.0, 1.0], "y_m": 0.0, "yaw_rad": 0.0})
    tags = pd.DataFrame({"epc": ["A", "B"], "x_m": [1.0, 2.0], "y_m": 1.0, "z_m": 1.0,
                         "nx": 0.0, "ny": -1.0, "nz": 0.0})
    r = pd.DataFrame(reads, columns=["t_s", "antenna_port", "rssi_dbm", "epc"]).assign(
        phase_rad=np.nan, frequency_hz=np.nan, doppler_hz=np.nan, seen_count=1)
    return Recording(r, poses, tags, "sllurp", {"ports": [1, 2]})


_TAGS = TagSet(np.array(["A", "B"]), np.array([[1.0, 1.0, 1.0], [2.0, 1.0, 1.0]]),
               np.array([[0.0, -1.0, 0.0]] * 2))
_MOUNTS = [AntennaMount("l", 0.0, 0.1, 0.6, 0.5), AntennaMount("r", 0.0, -0.1, 0.6, -0.5)]


def test_attempts_rule_by_hand():
    """Round robin at 2 Hz over 2 s: cycles at 0, 0.5, ..., 2.0 s, antenna k mod 2. Two
    reports of A in cycle 0 are one read (the stronger RSSI, seen twice); a report of B on
    port 2 at 0.6 s is cycle 1's; a miss is every other (cycle, tag)."""
    rec = _hand_recording([(0.1, 1, -60.0, "A"), (0.3, 1, -55.0, "A"), (0.6, 2, -70.0, "B")])
    reader = ReaderConfig(read_rate_hz=2.0, antenna_mode="round_robin")
    t, _, info = recorded_read_table(rec, _TAGS, _MOUNTS, reader, frequency_hz=866e6)
    assert info["n_attempts"] == 5 * 2 and info["n_off_schedule"] == 0
    hit = t[t["read"]]
    assert hit[["cycle", "antenna", "tag_id"]].astype(str).values.tolist() == [["0", "0", "A"],
                                                                                ["1", "1", "B"]]
    assert hit["rssi_dbm"].tolist() == [-55.0, -70.0] and hit["seen_count"].tolist() == [2, 1]
    # the same report on port 1 at 0.6 s falls in antenna 2's slot: off schedule, refused
    # when more than 5 % of the reads are
    bad = _hand_recording([(0.1, 1, -60.0, "A"), (0.6, 1, -70.0, "B")])
    with pytest.raises(RecordingError, match=r"1 of 2 reads .*reader.read_rate_hz = 2.0"):
        recorded_read_table(bad, _TAGS, _MOUNTS, reader, frequency_hz=866e6)
    # with both antennas in every cycle ("all") port 1 at 0.6 s is cycle 1's antenna 0
    t2, _, _ = recorded_read_table(bad, _TAGS, _MOUNTS, ReaderConfig(read_rate_hz=2.0, antenna_mode="all"),
                                   frequency_hz=866e6)
    assert t2[t2["read"]][["cycle", "antenna"]].values.tolist() == [[0, 0], [1, 0]]


def test_bad_recordings_stop_before_anything_is_written(tiny_study, recording, tmp_path):
    rec = tmp_path / "rec"
    rec.mkdir()
    for name in ("tags.csv", "poses.csv"):
        (rec / name).write_bytes((recording / name).read_bytes())
    lines = (recording / "reads.csv").read_text().splitlines()
    # a read on port 3, where no mount is
    (rec / "reads.csv").write_text("\n".join([lines[0], lines[1].replace(",1,", ",3,", 1), *lines[2:]]))
    out = tmp_path / "run"
    res = _run(tiny_study, out, "--recording", str(rec))
    assert res.exit_code != 0 and "port(s) [3]" in res.output and "Traceback" not in res.output
    assert not (out / "reads.parquet").exists()
    # reads of EPCs absent from the layout are counted and listed, never merged: the study
    # run as far as the recording's import (what it counts; the stages after it read its
    # tables, as in recorded_run's)
    (rec / "reads.csv").write_text("\n".join([*lines, lines[-1].replace(lines[-1].split(",")[-1], "ABCDEF")]))
    cfg = resolve_target(str(ROOT / "configs" / "tiny.toml"), [
        f"tracing.cache_dir={json.dumps(tiny_study.config.tracing.cache_dir)}",
        *recording_overrides(rec)], None)
    run_full_study(cfg, out, upto="recording", command_line=["pytest"])
    imp = json.loads((out / "recording" / "import.json").read_text())
    assert imp["n_reads_unknown_epc"] == 1 and imp["unknown_epcs"] == {"ABCDEF": 1}
    for name in ("reads.parquet", "eval_reads.parquet"):
        assert "ABCDEF" not in set(pd.read_parquet(out / name)["tag_id"].astype(str)), name
    # no such folder; a folder without its files
    res = _run(tiny_study, out, "--recording", str(tmp_path / "nothing"))
    assert res.exit_code != 0 and "no such file or folder" in res.output
    (tmp_path / "empty").mkdir()
    res = _run(tiny_study, tmp_path / "run2", "--recording", str(tmp_path / "empty"))
    assert res.exit_code != 0 and "no reads.csv or tags.csv" in res.output


def test_figures_and_export_of_a_recorded_run(recorded_run, recording, tmp_path):
    run = tmp_path / "run"
    import shutil

    shutil.copytree(recorded_run, run)
    res = CliRunner().invoke(app, ["figures", str(run)])
    assert res.exit_code == 0, res.output
    assert {p.name for p in (run / "figures").glob("*.png")} == {"sim_vs_real_rssi.png",
                                                                 "sim_vs_real_residual.png"}
    res = CliRunner().invoke(app, ["export", str(run), "--out", str(tmp_path / "again")])
    assert res.exit_code == 0, res.output
    # a recorded run's tag ids are the EPCs: exported as they are, not encoded again
    again = pd.read_csv(tmp_path / "again" / "reads.csv", dtype={"epc": str})
    first = pd.read_csv(recording / "reads.csv", dtype={"epc": str})
    assert set(again["epc"]) < set(first["epc"])  # the training tags' reads
    imp = read_impinj_csv(tmp_path / "again" / "reads_impinj.csv", "ETSI")
    assert imp["phase_rad"].isna().all()  # sllurp's log had no phase: empty, not invented


def test_calibrate_writes_the_calibration_and_a_calibrated_study(tiny_study, recording, recorded_run,
                                                               tmp_path):
    import shutil

    from pipeline.config import load_config

    out = tmp_path / "cal"
    # into a copy of recorded_run's directory: the calibration's keys are its stage's alone,
    # so the calibration (now with the constructions) and what follows it run again, not
    # the import, the traces and the models
    shutil.copytree(recorded_run, out)
    cache = tiny_study.config.tracing.cache_dir
    res = CliRunner().invoke(app, ["calibrate", "configs/tiny.toml", "--recording", str(recording),
                                   "--out", str(out), "--no-progress",
                                   "--set", f"tracing.cache_dir={json.dumps(cache)}",
                                   "--set", RESAMPLES])
    assert res.exit_code == 0, res.output
    for stage in ("training_sets", "models", "sim_vs_real"):  # their records as they were
        before, after = (json.loads((run / "stages" / f"{stage}.json").read_text())
                         for run in (recorded_run, out))
        assert after == before, stage
    cal = json.loads((out / "calibration.json").read_text())
    study = load_config(out / "calibrated.toml")  # a valid study, without the recording
    assert not study.recording.enabled
    cons = cal["constructions"]
    # the reader in calibrated.toml: the joint fit's where the constructions are laid over,
    # else the reader's parameters fitted alone (the building as traced)
    d1 = (cal["parameters"]["antenna_offset_db[1]"]["value"] if cons["in_calibrated_toml"] is True
          else cons["reader_only_parameters"]["antenna_offset_db[1]"])
    assert study.robot.antennas[1].cable_loss_db == pytest.approx(-d1)
    # the constructions carrying most traced power were fitted (the corridor's concrete
    # floor first); their overlay is in calibrated.toml exactly when they won on held-out tags
    assert max(cons["power_share"], key=cons["power_share"].get) == "uhf-concrete-t0p200"
    eps = cal["parameters"]["uhf-concrete-t0p200.relative_permittivity"]
    assert eps["traced"] == pytest.approx(5.24, rel=1e-6) and eps["low"] <= eps["value"] <= eps["high"]
    laid = {m.name: m for m in study.materials}
    assert ("concrete" in laid) == (cons["in_calibrated_toml"] is True), cons["in_calibrated_toml"]


def test_a_pose_clock_offset_is_found(recording):
    """Poses logged 0.8 s late: the estimated lag moves by 0.8 s (within two 0.1 s steps)."""
    from pipeline.config import load_config
    from pipeline.recording import read_poses_csv, read_sllurp_csv, read_tags_csv
    from pipeline.recording.lag import pose_lag_profile
    from pipeline.recording.load import recorded_tagset
    from pipeline.studyscene import build_robot

    reads = read_sllurp_csv(recording / "reads.csv")
    poses = read_poses_csv(recording / "poses.csv")
    rec = Recording(reads, poses, read_tags_csv(recording / "tags.csv"), "sllurp", {})
    tags, mounts = recorded_tagset(rec), build_robot(load_config("configs/tiny.toml")).antennas
    base = pose_lag_profile(reads, poses, tags, mounts, [1, 2])
    late = pose_lag_profile(reads, poses.assign(t_s=poses["t_s"] + 0.8), tags, mounts, [1, 2])
    assert late["lag_s"] is not None
    assert late["lag_s"] - (base["lag_s"] or 0.0) == pytest.approx(0.8, abs=0.2)
    assert late["rmse_db"] < late["rmse_db_at_zero"]
