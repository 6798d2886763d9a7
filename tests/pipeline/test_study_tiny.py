"""A tiny real study (corridor_lab, 5 m of route, low ray counts, 3 epochs), end to end.

The session's one tiny study (``tiny_study``, tests/conftest.py) serves every test: real
MCL, real Sionna traces, real Parquet, real ANFIS, real figures. Then the cache on the
real stages: a second run skips every stage; a new run directory traces nothing; changing
the ANFIS epochs re-runs only the models and what follows. How the engine handles a
failing stage, a corrupt or missing output and a resume is tested on fake stages in
test_study_runner.py. The smoke study runs without the ray-traced oracle; one test here
runs it on a copy (its parts are unit-tested in tests/pipeline/localisation and
tests/propagation/test_anchored.py).

The tiny study is built once per session, whichever xdist worker asks first (the others
wait for it and read it: tests/conftest.py).
"""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from pipeline.apps.studyrun import run_full_study
from pipeline.config import load_config, replace_path
from pipeline.engine.study import run_study
from pipeline.stages import stage_names
from pipeline.stages.summary import run_summary
from tests.conftest import copy_run, draw_only, link_copy

ROOT = Path(__file__).resolve().parents[2]


@pytest.fixture
def tiny(tiny_study):
    """(config, base, console lines) of the session's tiny study (tests/conftest.py)."""
    return tiny_study.config, tiny_study.base, tiny_study.console


def test_first_run_produces_the_run_directory(tiny):
    cfg, base, console = tiny
    run = base / "run"
    # the command's summary: every stage ran, in the study's order, none from a record
    said = " ".join(ln.strip() for ln in console)
    assert f"stages run: {', '.join(stage_names())}; cached: none" in said, console
    for rel in ("config.toml", "manifest.json", "reads.parquet", "poses.parquet",
                "eval_reads.parquet", "eval_poses.parquet", "models/ssm.json", "models/tdm.json",
                "models/sensor_truepose.json", "models/baselines.json", "metrics.json",
                "truth/detection_grid.npz", "truth/fig7_errors.parquet", "fields/field_00.npz",
                "report.html"):
        assert (run / rel).is_file(), rel
    # every figure in the study's formats alone (configs/tiny.toml: PNG, no PDF)
    from pipeline.figures import FIGURES

    assert cfg.figures.formats == ("png",)
    assert sorted(p.name for p in (run / "figures").iterdir()) == sorted(
        f"{name}.png" for name in FIGURES)
    cov = json.loads((run / "metrics.json").read_text())["coverage"]
    assert 0 <= cov["corridor_fraction"] <= 1 and cov["fields"][0]["n_cells"] > 0
    # truth_traces took its antenna poses from the tour's track: those of the read log
    from pipeline.engine.runstore import RunStore
    from pipeline.engine.study import StageContext
    from pipeline.stages.common import attempt_poses
    from pipeline.studyscene import antenna_tilts

    eval_reads = pd.read_parquet(run / "eval_reads.parquet").drop_duplicates(["time_s", "antenna"])
    tilt = antenna_tilts(cfg)
    logged = np.column_stack([eval_reads[["true_ant_x_m", "true_ant_y_m", "true_ant_z_m",
                                          "true_ant_yaw_rad"]].to_numpy(float),
                              [tilt[int(a)] for a in eval_reads["antenna"]], np.zeros(len(eval_reads))])
    ctx = StageContext(cfg, RunStore(run), "check", run / "unused", None, {})
    np.testing.assert_array_equal(attempt_poses(ctx, "eval"), logged)
    # ... which it computes without the tour's MCL (it starts beside the tour): the same
    from pipeline.stages.tour import eval_track

    np.testing.assert_array_equal(attempt_poses(ctx, "eval", eval_track(ctx)), logged)
    # the plane only: the wall map (tracing.field_walls, off) is what no figure uses
    with np.load(run / "fields/field_00.npz") as z:
        assert z["plane_gain"].size > 0 and z["wall_gain"].size == 0
    reads = pd.read_parquet(run / "reads.parquet")
    assert reads["read"].any() and {"d_est_m", "alpha_est_rad", "rssi_dbm"} <= set(reads.columns)
    assert len(pd.read_parquet(run / "eval_poses.parquet")) == cfg.tour.n_eval_poses
    man = json.loads((run / "manifest.json").read_text())
    assert man["status"] == "complete" and man["seed"] == cfg.seed
    assert man["backend"]["variant"].endswith("_ad_mono_polarized")
    assert set(man["stages"]) == set(stage_names())
    assert man["versions"]["numpy"] and man["peak_rss_mib"] > 0
    assert list((run / "figures").glob("*.png"))
    html = (run / "report.html").read_text()
    assert "data:image/png;base64," in html and "anfis_truepose" in html
    assert load_config(run / "config.toml") == cfg  # resolved config reads back
    # the propagation cache was filled (shared across runs)
    assert any((base / "cache").rglob("*"))


def test_truth_refuses_traces_of_another_path(tiny, tmp_path):
    # truth_traces draws the evaluation path itself: traces whose poses are not the
    # tour's (a stale cached truth_traces) stop the truth stage with the file's name
    import dataclasses

    from pipeline.engine.runstore import RunStore
    from pipeline.engine.study import StageContext
    from pipeline.evaluation.sites import SiteTruth
    from pipeline.stages.truth import _check_trace_poses

    cfg, base, _ = tiny
    run = tmp_path / "run"
    shutil.copytree(base / "run", run)
    ctx = StageContext(cfg, RunStore(run), "check", tmp_path / "unused", None, {})
    _check_trace_poses(ctx)  # the run's own: fine
    site = SiteTruth.load(run / "truth/site_truth.npz")
    moved = dataclasses.replace(site, antenna_poses=site.antenna_poses + [0.01, 0, 0, 0, 0, 0])
    moved.save(run / "truth/site_truth.npz")
    with pytest.raises(ValueError, match=r"site_truth\.npz: its antenna poses are not the "
                                         r"evaluation tour's .* --force truth_traces"):
        _check_trace_poses(ctx)


def test_second_run_skips_every_stage(tiny_study, tmp_path):
    # on a copy: the session's run directory is read by other tests (and workers) meanwhile
    run = copy_run(tiny_study, tmp_path / "run")
    res = run_full_study(tiny_study.config, run, command_line=["pytest"])
    assert res.ran == [] and res.cached == stage_names()


def test_new_run_dir_traces_nothing(tiny, tmp_path):
    from pipeline.stages import STAGES

    cfg, base, _ = tiny
    # a copy of the session's cache, which other tests (and workers) add to meanwhile
    cache = link_copy(base / "cache", tmp_path / "cache")
    cache_before = sorted(p.relative_to(cache) for p in cache.rglob("*"))
    run_study(replace_path(cfg, "tracing.cache_dir", str(cache)), tmp_path / "run2",
              stages=STAGES[:3], manifest_extra=None)
    # the shared cache answers every link of the same tour: no new cache entry was made
    assert sorted(p.relative_to(cache) for p in cache.rglob("*")) == cache_before
    a = pd.read_parquet(tmp_path / "run2" / "reads.parquet")
    b = pd.read_parquet(base / "run" / "reads.parquet")
    pd.testing.assert_frame_equal(a, b)  # bit-reproducible from the seed


def test_run_summary_row(tiny):
    _, base, _ = tiny
    row = run_summary(base / "run")
    assert 0 < row["read_rate"] <= 1 and 0 < row["tag_coverage"] <= 1
    assert 0 <= row["completeness"] <= 1 and 0 < row["surface_coverage"] <= 1
    assert "corridor_coverage" not in row  # the plane metric left the sweeps (its artefact)
    assert row["ssm_rmse_db"] > 0


def test_cli_figures_on_a_run_dir(tiny, tmp_path, monkeypatch):
    """Redraw figures + report from a finished run directory (the tiny study's): two of
    the figures (:func:`draw_only`; drawn side by side in forked processes:
    tests/pipeline/figures/test_figures.py)."""
    _, base, _ = tiny
    run = tmp_path / "run"
    shutil.copytree(base / "run", run, ignore=shutil.ignore_patterns("figures", "report.html"))
    from typer.testing import CliRunner

    from pipeline.apps.cli import app

    drawn = ("scene_top_view", "mcl_error")
    draw_only(monkeypatch, *drawn)

    res = CliRunner().invoke(app, ["figures", str(run)])
    assert res.exit_code == 0, res.output
    for k in drawn:
        assert (run / "figures" / f"{k}.png").is_file(), k
    assert "data:image/png;base64," in (run / "report.html").read_text()
    # as the study's figures stage drew them: its [figures] formats (tiny: PNG alone)
    assert not list((run / "figures").glob("*.pdf"))


def test_heldout_layout_never_mixes_with_training(tiny):
    """No tag read in training appears in evaluation; each tour reads only its own layout."""
    _, base, _ = tiny
    run = base / "run"
    tags = pd.read_parquet(run / "scene" / "tags.parquet")
    assert set(tags["split"]) == {"train", "eval"}
    train_ids = set(tags.loc[tags["split"] == "train", "tag_id"])
    eval_ids = set(tags.loc[tags["split"] == "eval", "tag_id"])
    assert len(eval_ids) >= 8 and not train_ids & eval_ids
    seen_train = set(pd.read_parquet(run / "reads.parquet")["tag_id"].astype(str))
    seen_eval = set(pd.read_parquet(run / "eval_reads.parquet")["tag_id"].astype(str))
    assert seen_train <= train_ids and seen_eval <= eval_ids and not seen_train & seen_eval
    # held-out tags sit at positions the training tags do not (>= the configured separation)
    import numpy as np

    xyz = tags[["x_m", "y_m", "z_m"]].to_numpy(float)
    tr, ev = xyz[tags["split"] == "train"], xyz[tags["split"] == "eval"]
    assert np.min(np.linalg.norm(tr[:, None] - ev[None], axis=2)) >= 0.5 - 1e-9


def test_metrics_have_the_heldout_sections(tiny):
    _, base, _ = tiny
    m = json.loads((base / "run" / "metrics.json").read_text())
    for sec in ("heldout", "fig7", "error_budget", "in_sample", "tag_sites"):
        assert sec in m, sec
    models = m["heldout"]["models"]
    assert {"anfis", "anfis_truepose", "log_distance", "grid_count", "joho2009", "liu2006",
            "vorst2008", "fcm_only", "anfis_gridinit"} <= set(models)
    assert models["anfis"]["rssi_dbm"]["n"] > 0 and models["log_distance"]["detection"] is None
    assert models["grid_count"]["rssi_dbm"] is None
    assert m["heldout"]["bound"]["rssi_dbm"]["n"] > 0
    assert m["error_budget"]["total"]["rmse_db"] == models["anfis"]["rssi_dbm"]["rmse"]
    assert m["tag_sites"]["anfis"]["all"]["n_pairs"] > 0
    # the downstream benchmark: every model localises every held-out tag (the oracle is
    # off in the smoke study: test_changed_epochs_and_the_oracle_rerun_models_and_downstream_only)
    keys = {"median_m", "p90_m", "rmse_m", "within_0_5m", "within_1m", "n_tags"}
    assert "oracle" not in m["tag_localisation"]
    for name in ("anfis", "log_distance", "grid_count", "joho2009"):
        assert keys <= set(m["tag_localisation"][name]), name
        assert m["tag_localisation"][name]["n_tags"] == 16
    assert {"median_m", "p90_m", "converge_s"} <= set(m["robot_localisation"]["anfis"])
    assert "held-out" in (base / "run" / "report.html").read_text()


def test_identical_detection_models_are_scored_once(tiny):
    """Joho et al. 2009's detection part is the Hähnel grid count (reads / attempts per
    polar cell, nearest-cell fill): the two predict the same probability everywhere, so
    the detection scores hold one row for them, not one loser counted twice."""
    from pipeline.evaluation.baselines import BaselineSensorModel
    from pipeline.sensormodels import load_competitor

    _, base, _ = tiny
    run = base / "run"
    joho = load_competitor(run / "models" / "joho2009.json")
    grid = BaselineSensorModel.load(run / "models" / "baselines.json")
    d, a = np.meshgrid(np.linspace(0.05, 4.0, 60), np.linspace(-np.pi, np.pi, 73))
    assert np.array_equal(joho.fT(d, a), grid.fT(d, a))  # the premise, recomputed
    m = json.loads((run / "metrics.json").read_text())
    assert m["detection_merged"] == {"joho2009": "grid_count"}
    att = pd.read_parquet(run / "evaluation" / "detection_attempts.parquet")
    assert "grid_count" in set(att["model"]) and "joho2009" not in set(att["model"])
    brier = m["intervals"]["heldout.detection_brier"]["models"]
    assert "grid_count" in brier and "joho2009" not in brier
    # Joho's RSSI model is its own and is still scored
    assert "joho2009" in m["intervals"]["heldout.rssi_rmse_db"]["models"]


def test_intervals_are_the_headline_numbers_recomputed_from_the_saved_tables(tiny):
    """Each interval's estimate is the headline number of its section, recomputed here
    from the per-unit tables the run saved; the robot median is over every step of every
    filter run (recomputed from downstream/robot_steps.parquet)."""
    _, base, _ = tiny
    run = base / "run"
    m = json.loads((run / "metrics.json").read_text())
    iv, cmp_ = m["intervals"], m["comparisons"]
    for name in ("anfis", "joho2009", "log_distance"):
        h = m["heldout"]["models"][name]["rssi_dbm"]
        assert iv["heldout.rssi_rmse_db"]["models"][name]["estimate"] == pytest.approx(h["rmse"])
        assert iv["heldout.rssi_mae_db"]["models"][name]["estimate"] == pytest.approx(h["mae"])
        assert iv["fig7.median_pct"]["models"][name]["estimate"] == pytest.approx(
            m["fig7"][name]["median_pct"])
        assert iv["tag_localisation.median_m"]["models"][name]["estimate"] == pytest.approx(
            m["tag_localisation"][name]["median_m"])
    brier = m["heldout"]["models"]["anfis"]["detection"]["brier"]
    assert iv["heldout.detection_brier"]["models"]["anfis"]["estimate"] == pytest.approx(brier)
    mae = m["heldout"]["models"]["anfis"]["detection"]["mae"]
    assert iv["heldout.detection_mae"]["models"]["anfis"]["estimate"] == pytest.approx(mae)
    # 16 held-out tags resampled: a real interval around the estimate
    tag = iv["tag_localisation.median_m"]["models"]["anfis"]
    assert tag["n_units"] == 16 and tag["low"] <= tag["estimate"] <= tag["high"]
    steps = pd.read_parquet(run / "downstream" / "robot_steps.parquet")
    runs = m["robot_localisation"]["anfis"]["n_runs"]
    for name, rows in steps.groupby("model"):
        rob = m["robot_localisation"][name]
        assert rows["unit"].nunique() == runs
        assert rob["median_m"] == pytest.approx(np.median(rows["error_m"]), abs=1e-4)
        assert rob["median_after_kidnap_m"] == pytest.approx(
            np.median(rows.loc[rows["after_kidnap"], "error_m"]), abs=1e-4)
        assert iv["robot_localisation.median_m"]["models"][name]["estimate"] == pytest.approx(
            np.median(rows["error_m"]))
        conv = rows.groupby("unit")["converge_s"].first()
        assert rob["converged_runs"] == int(np.isfinite(conv).sum())
    # every interval holds its own estimate
    for key, sec in [*iv.items(), *((k, {"models": v}) for k, v in cmp_["metrics"].items())]:
        for name, x in sec["models"].items():
            if x["low"] is not None:
                assert x["low"] - 1e-9 <= x["estimate"] <= x["high"] + 1e-9, (key, name, x)
    # 3 filter runs: too few units for an interval, said so rather than invented
    assert iv["robot_localisation.median_m"]["models"]["anfis"]["low"] is None
    assert cmp_["reference"] == "anfis" and "anfis" not in cmp_["metrics"]["heldout.rssi_mae_db"]
    assert {c["verdict"] for c in cmp_["metrics"]["heldout.rssi_mae_db"].values()} <= {
        "better", "worse", "not distinguishable at 95 %"}


def test_a_downstream_change_reruns_downstream_and_what_reads_it_only():
    """What the re-run below cannot show (its epochs change re-runs the models too): a
    change of ``[downstream]`` alone (the oracle on) re-runs the downstream stage and the
    stages that read its outputs, never the models or the truth. A stage re-runs when one
    of its config keys changed or an upstream stage re-ran (pipeline.engine.study)."""
    from pipeline.stages import STAGES

    def reads_downstream(key: str) -> bool:
        return key == "downstream" or key.startswith("downstream.")

    rerun = set()
    for st in STAGES:  # in order: every upstream stage comes first
        if any(map(reads_downstream, st.config_keys)) or rerun & set(st.upstream):
            rerun.add(st.name)
    assert [s.name for s in STAGES if s.name in rerun] == [
        "downstream", "evaluation", "figures", "report"]


def test_changed_epochs_and_the_oracle_rerun_models_and_downstream_only(tiny_study, tmp_path,
                                                                         monkeypatch):
    """Two changes in one re-run of a copy of the tiny study (each re-run costs a
    downstream stage, the suite's time): the ANFIS epochs (re-run the models and what
    follows, never the reads) and ``downstream.oracle = true`` (the ray-traced oracle in
    the real study).

    The oracle's search narrowed to what the assertions need: the coarse pass only as far
    as the longest read, windows of 0.2 m (candidates 0.1 m apart: configs/tiny.toml; a broken search, e.g.
    the coarse modes taken from the worst anchors, lands metres away: within 1 m of none;
    that planted bug also fails tests/propagation/test_anchored.py); one robot run per
    model (the runs' pooling: the tiny study's three). One figure, of the models (the
    downstream figure with an oracle: tests/pipeline/figures/test_figures.py)."""
    run = copy_run(tiny_study, tmp_path / "run")
    before = (run / "reads.parquet").stat().st_mtime_ns
    draw_only(monkeypatch, "ssm_surface")
    cfg = replace_path(tiny_study.config, "training.epochs", 4)
    cfg = replace_path(cfg, "downstream.oracle", True)
    cfg = replace_path(cfg, "downstream.oracle_reach_m", 1.0)  # at least the longest read
    cfg = replace_path(cfg, "downstream.oracle_window_m", 0.2)
    cfg = replace_path(cfg, "downstream.robot_runs", 1)
    res = run_full_study(cfg, run, command_line=["pytest"])
    assert res.changed_keys == ["downstream.oracle",
                                "downstream.oracle_reach_m", "downstream.oracle_window_m",
                                "downstream.robot_runs", "training.epochs"]
    assert res.cached == ["scene", "tour", "reads", "truth_traces", "training_sets"]
    assert res.ran == ["models", "truth", "downstream", "evaluation", "figures", "report"]
    assert (run / "reads.parquet").stat().st_mtime_ns == before
    hist = json.loads((run / "models" / "training_history.json").read_text())
    assert len(hist["ssm"]["train_rmse"]) == 4
    assert (run / "figures" / "ssm_surface.png").is_file()

    m = json.loads((run / "metrics.json").read_text())
    n_eval = m["tag_localisation"]["anfis"]["n_tags"]
    tag = m["tag_localisation"]["oracle"]
    assert tag["n_tags"] == n_eval == 16
    assert 0 <= tag["within_0_5m"] <= tag["within_1m"] <= 1
    # the oracle knows the traced truth: it is at least as often within 1 m as the
    # crudest model (grid count) on the same tags; a broken oracle (wrong sign of a
    # log-likelihood, tags mixed up) lands far from them
    assert tag["within_1m"] >= m["tag_localisation"]["grid_count"]["within_1m"]
    robot = m["robot_localisation"]["oracle"]
    assert robot["n_runs"] == cfg.downstream.robot_runs and robot["median_m"] >= 0
    info = json.loads((run / "stages" / "downstream.json").read_text())["info"]["oracle"]
    assert info["traced_links"] > 0 and info["robot_field_links"] > 0
    assert "oracle" in (run / "report.html").read_text()
