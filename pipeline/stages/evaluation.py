"""Stage ``evaluation``: every model against the truth on held-out data
(``pipeline.evaluation``); writes ``metrics.json``, ``truth/fig7_errors.parquet`` and
``truth/site_errors.parquet``."""

from __future__ import annotations

import json

import numpy as np

import propagation
from pipeline import runfiles
from pipeline.engine.runstore import atomic_write_json, run_files
from pipeline.engine.study import Stage
from pipeline.evaluation import units as u
from pipeline.evaluation.baselines import BaselineSensorModel
from pipeline.evaluation.comparison import RhoPoints, rho_vs_truth
from pipeline.evaluation.coverage import detection_coverage
from pipeline.evaluation.evaluate import EvaluationInputs, evaluate_all
from pipeline.evaluation.fig7 import fig7_errors
from pipeline.evaluation.headline import headline_intervals
from pipeline.evaluation.heldout import error_budget, heldout_scores
from pipeline.evaluation.metrics import nan_to_none
from pipeline.evaluation.sites import SiteTruth, site_comparison
from pipeline.evaluation.tables import read_tags, write_parquet_atomic
from pipeline.evaluation.truth import TruthGrid
from pipeline.runfiles import STAGE_OUTPUTS
from pipeline.sensormodels import tag_height_differences
from pipeline.sensormodels.registry import (
    load_models,
    merge_identical_detection,
    model_names,
    stage_version,
)
from pipeline.stages.common import load_scene, read_reads
from pipeline.stages.truth import attempt_miss_probability, pose_miss_probability
from pipeline.studyscene import antenna_tilts, link_budget
from scenes.geometry import is_free

__all__ = ["STAGE", "field_coverage", "model_fits", "stage_evaluation", "study_models"]


def model_fits(models: dict) -> dict:
    """What each competitor is and how its fit went (``metrics.json`` ``model_fits``).

    Per model: ``name`` (display name), ``reference``, ``predicts_rssi``; a model whose
    fit searches a grid (the ``liu2006`` sector) gives ``at_search_bound`` (the fitted
    parameters on the edge of their search, comma-separated, "" if none) and a ``note``
    when there is one; a cross-validated one (``vorst2008``) its ``bandwidth_m`` and
    ``cv_n_groups`` (the tags its folds were grouped by).
    """
    out = {}
    for name, m in models.items():
        d = {"name": getattr(m, "DISPLAY_NAME", name), "reference": getattr(m, "REFERENCE", ""),
             "predicts_rssi": bool(getattr(m, "predicts_rssi", True))}
        bound = getattr(m, "at_search_bound", None)
        if bound is not None:
            d["at_search_bound"] = ", ".join(bound)
            if bound:
                d["note"] = ("fit ended on the edge of its search grid (" + ", ".join(bound)
                             + "): the value is the bound, not an optimum")
        if hasattr(m, "bandwidth_m"):
            d["bandwidth_m"] = float(m.bandwidth_m)
            d["cv_n_groups"] = int(getattr(m, "cv_n_groups", 0))
        out[name] = d
    return out


def study_models(ctx, where: str) -> tuple[dict, tuple, tuple, tuple]:
    """The models a context scores (:data:`pipeline.sensormodels.registry.SENSOR_MODELS`,
    ``where`` one of its ``CONTEXTS``), loaded from the run: ``(models, rssi_names,
    detection_names, competitors)``, each in the registry's study order."""
    return (load_models(ctx.input, where), model_names(scored_in=where, predicts="rssi"),
            model_names(scored_in=where, predicts="detection"),
            model_names(role="competitor", scored_in=where))


def field_coverage(cfg, scene, field_paths, eval_reads=None) -> dict | None:
    """Corridor coverage of the saved RSSI fields (pipeline.evaluation.detection_coverage).

    Cells outside the scene's free space are left out. The miss probability is the
    ``"fixed"`` reader's constant, or for the Gen2 reader that of a tag joining the
    closing tags of the field pose's slot in ``eval_reads`` (required then). Returns None
    without fields, else ``{"corridor_fraction": mean over fields, "fields":
    [CoverageResult dicts]}``.
    """
    if not field_paths:
        return None
    budget = link_budget(cfg)
    per_field = []
    for path in field_paths:
        field = propagation.RssiField.load(path)
        free = is_free(scene, field.plane_centers_m.reshape(-1, 3))
        q = pose_miss_probability(cfg, eval_reads, np.asarray(field.antenna_pose)[None], budget)
        per_field.append(detection_coverage(
            field.plane_gain_db, budget, free,
            miss_probability=q if np.ndim(q) == 0 else float(q[0])).to_dict())
    return {"corridor_fraction": float(np.mean([c["fraction"] for c in per_field])),
            "fields": per_field}


def stage_evaluation(ctx) -> dict:
    """Every model against the truth; write metrics.json and the Fig. 7 / tag-site tables.

    ``metrics.json`` sections: ``heldout`` (every model and the floor on the held-out tag
    layout read by the evaluation tour; the headline), ``fig7`` (chapter Sec. 5 on the
    evaluation tour, per model), ``tag_sites`` (truth where tags are, per model),
    ``error_budget``, ``localisation`` (MCL pose error and bias per tour), ``in_sample``
    (the same comparisons on the training tour's reads: labelled, not the headline),
    ``free_space_view`` (the chapter's Fig. 6 plane at antenna height), ``coverage``,
    ``intervals`` and ``comparisons`` (:func:`pipeline.evaluation.headline.headline_intervals`
    on the per-unit tables ``evaluation/*.parquet``).
    """
    import pandas as pd


    cfg = ctx.config
    budget = link_budget(cfg)
    reads, meta = read_reads(ctx)
    eval_reads, eval_meta = read_reads(ctx, "eval_")
    tags = read_tags(ctx.input(runfiles.SCENE_TAGS))
    _check_split(tags, reads, eval_reads, ctx.store.path(runfiles.SCENE_TAGS))
    eval_poses = pd.read_parquet(ctx.input(runfiles.EVAL_POSES))
    base = BaselineSensorModel.load(ctx.input(runfiles.BASELINES))

    sensors, rssi_names, det_candidates, competitors = study_models(ctx, "heldout")
    train_truth = TruthGrid.load(ctx.input(runfiles.DETECTION_GRID))
    eval_truth = TruthGrid.load(ctx.input(runfiles.DETECTION_GRID_EVAL))
    tr = cfg.training
    # each held-out link's tag height above its true antenna: a model whose detection
    # depends on it (Vorst & Zell's ground-plane table) is scored with it
    eval_dz = tag_height_differences(eval_reads, tags, pose="true")
    det_names, merged = _detection_models(sensors, det_candidates, eval_reads, eval_truth)
    heldout = heldout_scores(sensors, eval_reads, train_truth, eval_truth, budget,
                             d_max_m=tr.d_max_m, min_attempts=tr.min_attempts,
                             rssi_models=rssi_names, detection_models=det_names, dz_m=eval_dz)
    metrics = {"heldout": heldout, "error_budget": error_budget(heldout),
               "reads": {"range_margin": _range_margin(meta, eval_meta)},
               "model_fits": model_fits({n: sensors[n] for n in competitors}),
               "detection_merged": merged}
    fig7, fig7_results = {}, {}
    for name in rssi_names:
        f7 = fig7_results[name] = fig7_errors(eval_reads, tags, sensors[name], radius_m=cfg.evaluation.fig7_radius_m,
                         pose_times_s=eval_poses["time_s"].to_numpy(float),
                         antenna_pitch_rad=antenna_tilts(cfg), d_max_m=tr.d_max_m)
        fig7[name] = f7.to_dict()
        if name == "anfis":  # the Fig. 7 figure reads it instead of recomputing
            f7.write_table(ctx.out(runfiles.FIG7_ERRORS))
    metrics["fig7"] = fig7
    site_truth = SiteTruth.load(ctx.input(runfiles.SITE_TRUTH))
    q = pose_miss_probability(cfg, eval_reads, site_truth.antenna_poses, budget)
    metrics["tag_sites"] = {}
    for name in rssi_names:
        sc_ = site_comparison(site_truth, sensors[name], budget, miss_probability=q,
                              d_max_m=tr.d_max_m)
        metrics["tag_sites"][name] = sc_.to_dict()
        if name == "anfis":
            write_parquet_atomic(sc_.per_site, ctx.out(runfiles.SITE_ERRORS))
    scores = ctx.store.path(runfiles.DOWNSTREAM_SCORES)
    if scores.is_file():  # the downstream stage's results (absent when it is disabled)
        down = json.loads(scores.read_text())
        metrics["tag_localisation"] = down["tag_localisation"]
        metrics["robot_localisation"] = down["robot_localisation"]
    loc = ctx.store.path(runfiles.LOCALISATION)
    if loc.is_file():
        metrics["localisation"] = json.loads(loc.read_text())
    # in-sample: the training tour's own reads (labelled; not the headline)
    insample = evaluate_all(
        {"anfis": sensors["anfis"], "anfis_truepose": sensors["anfis_truepose"],
         "baselines": base,
         "baselines_truepose": BaselineSensorModel.load(ctx.input(runfiles.BASELINES_TRUEPOSE))},
        EvaluationInputs(reads=reads, truth=train_truth, budget=budget,
                         d_max_m=tr.d_max_m, min_attempts=tr.min_attempts)).to_dict()
    insample["note"] = ("in_sample: scored on the training tour's reads of the training tags, "
                        "which the models were fitted on")
    metrics["in_sample"] = insample
    rho_points = [RhoPoints.load(p) for p in run_files(ctx.store.root, "truth", "rho_points_*.npz")]
    metrics["free_space_view"] = {
        name: rho_vs_truth(rho_points, sensors[name]).to_dict() for name in rssi_names
    } if rho_points else None
    fields = run_files(ctx.store.root, "fields", "field_*.npz")
    coverage = field_coverage(cfg, load_scene(ctx), fields, eval_reads)
    if coverage is not None:
        metrics["coverage"] = coverage
    units = write_unit_tables(ctx, eval_reads, sensors, eval_truth, budget, fig7_results,
                              rssi_names=rssi_names, detection_names=det_names, dz_m=eval_dz)
    metrics.update(headline_intervals(units, seed=cfg.seed, min_attempts=tr.min_attempts))
    atomic_write_json(ctx.out(runfiles.METRICS), nan_to_none(metrics))
    return {"models": sorted(sensors)}


def _detection_models(sensors, names, eval_reads, eval_truth):
    """The detection models to score, each distinct set of predictions once
    (:func:`pipeline.sensormodels.registry.merge_identical_detection`, probed at the
    held-out links' MCL and true geometry and the truth grid's cell centres), and the
    merged ones -> their twin."""
    dc, ac = eval_truth.grid.centre_mesh()
    d = np.concatenate([eval_reads["d_est_m"], eval_reads["d_true_m"], dc.ravel()])
    a = np.concatenate([eval_reads["alpha_est_rad"], eval_reads["alpha_true_rad"], ac.ravel()])
    return merge_identical_detection(sensors, names, d, a)


def write_unit_tables(ctx, eval_reads, sensors, eval_truth, budget, fig7_results, *,
                      rssi_names, detection_names, dz_m=None):
    """Write the per-unit tables of :mod:`pipeline.evaluation.units` under ``evaluation/``
    and return them with the downstream stage's tag and robot tables (the intervals'
    input); ``dz_m``: the held-out links' tag heights above their true antennas."""
    import pandas as pd


    cfg = ctx.config
    tables = u.UnitTables(
        rssi_links=u.rssi_link_errors(eval_reads, sensors, budget, d_max_m=cfg.training.d_max_m,
                                      names=rssi_names),
        detection_attempts=u.detection_outcomes(
            eval_reads, sensors, eval_truth, attempt_miss_probability(cfg, eval_reads, budget),
            budget, names=detection_names, dz_m=dz_m),
        detection_cells=u.detection_cells(sensors, eval_truth.grid, names=detection_names,
                                          eval_reads=eval_reads, dz_m=dz_m),
        fig7_groups=u.fig7_groups(fig7_results))
    for name in ("rssi_links", "detection_attempts", "detection_cells", "fig7_groups"):
        write_parquet_atomic(getattr(tables, name), ctx.out(u.TABLES[name]))
    for name in ("tag_errors", "robot_steps"):
        path = ctx.store.path(u.TABLES[name])
        if path.is_file():  # the downstream stage's (absent when it is disabled)
            df = pd.read_parquet(ctx.input(u.TABLES[name]))
            setattr(tables, name, df.rename(columns={"tag_id": "unit"}))
    return tables


def _range_margin(*metas) -> dict:
    """Did any traced link exceed free space by more than the range margin (the untraced
    links beyond it might then have been readable)? From the read logs' metadata."""
    vals = [m.get("max_excess_over_free_space_db") for m in metas if isinstance(m, dict)]
    vals = [float(v) for v in vals if v is not None]
    margin = next((m.get("range_margin_db") for m in metas if isinstance(m, dict)), None)
    worst = max(vals) if vals else None
    return {"range_margin_db": margin, "max_excess_over_free_space_db": worst,
            "margin_holds": None if worst is None or margin is None else bool(worst <= margin)}


def _check_split(tags, reads, eval_reads, path) -> None:
    """No tag read in training appears in evaluation, and each tour reads only its layout."""
    if "split" not in tags.columns:
        raise ValueError(f"{path}: no 'split' column; rerun the scene stage")
    split = dict(zip(tags["tag_id"].astype(str), tags["split"].astype(str), strict=True))
    for name, df, want in ((runfiles.TRAIN_READS, reads, "train"), (runfiles.EVAL_READS, eval_reads, "eval")):
        ids = set(df["tag_id"].astype(str))
        wrong = sorted(t for t in ids if split.get(t) != want)
        if wrong:
            raise ValueError(f"{name} holds tags {wrong[:5]} whose split in {path} is not {want!r}: "
                             "training and held-out layouts mix; rerun the reads stage")


STAGE = Stage("evaluation", stage_evaluation, ("seed", "reader", "evaluation", "training", "robot"),
              ("scene", "tour", "reads", "truth_traces", "models", "truth", "downstream"),
              version=stage_version(15),  # each version's change: CHANGELOG.md
              description="metrics",
              outputs=STAGE_OUTPUTS["evaluation"])
