"""Study stages that learn and judge: training sets, FCM + ANFIS models, truth, metrics.

Each ``stage_*`` function takes a :class:`pipeline.study.StageContext` and calls the
packages (``pipeline.acquisition``, ``fuzzymodel``, ``pipeline.evaluation``,
``propagation``). Orchestration only: no statistics are computed here.
"""

from __future__ import annotations

import json
import logging

import numpy as np

from pipeline.runstore import atomic_write_json
from pipeline.stages_data import (
    link_budget,
    load_scene,
    resolve_cache_dir,
    select_backend,
    stage_rng,
    trace_options,
)

__all__ = [
    "POSE_SOURCES",
    "field_coverage",
    "stage_evaluation",
    "stage_models",
    "stage_training_sets",
    "stage_truth",
]

log = logging.getLogger(__name__)

#: Training-pose variants: "est" (MCL, the study's model) and "true" (localisation split).
POSE_SOURCES = ("est", "true")


def _read_reads(ctx, prefix: str = ""):
    from pipeline.acquisition import read_table

    path = ctx.input(f"{prefix}reads.parquet")
    try:
        df, meta = read_table(path)
    except Exception as exc:
        raise ValueError(f"{path}: cannot read the read log ({type(exc).__name__}: {exc}); "
                         "delete it to re-run the reads stage") from None
    return df, meta


def stage_training_sets(ctx) -> dict:
    """SSM and TDM training sets from the tour's reads, for MCL and for true poses."""
    from pipeline.acquisition import rssi_range_from_data, ssm_samples, tdm_samples

    cfg = ctx.config.training
    reads, _ = _read_reads(ctx)
    rng_dbm = cfg.rssi_range_dbm
    if rng_dbm is None:
        # one range for every model (MCL and true poses), fixed by the reads themselves
        rssi = reads.loc[reads["read"].to_numpy(bool) & (reads["d_est_m"] < cfg.d_max_m), "rssi_dbm"]
        rng_dbm = rssi_range_from_data(rssi.to_numpy(float))
    info = {"rssi_range_dbm": [float(v) for v in rng_dbm]}
    for pose in POSE_SOURCES:
        ssm = ssm_samples(reads, d_max_m=cfg.d_max_m, rssi_range_dbm=rng_dbm, pose=pose)
        tdm = tdm_samples(reads, d_bin_m=cfg.d_bin_m, alpha_bin_deg=cfg.alpha_bin_deg,
                          d_max_m=cfg.d_max_m, pose=pose, min_attempts=cfg.min_attempts)
        if len(ssm) < cfg.n_clusters + 2 or len(tdm) < cfg.n_clusters + 2:
            raise ValueError(f"too few training samples for pose={pose!r}: SSM {len(ssm)}, TDM "
                             f"{len(tdm)} cells (need > n_clusters + 1 = {cfg.n_clusters + 1}); "
                             "lengthen the tour or lower training.min_attempts")
        ssm.to_parquet(ctx.out(f"training/ssm_{pose}.parquet"))
        tdm.to_parquet(ctx.out(f"training/tdm_{pose}.parquet"))
        info[pose] = {"ssm_samples": len(ssm), "tdm_cells": len(tdm)}
    return info


def _split(X, y, frac: float, rng):
    n = len(y)
    n_check = int(round(frac * n))
    if n_check < 1 or n - n_check < 2:
        return X, y, None, None
    perm = rng.permutation(n)
    c, t = perm[:n_check], perm[n_check:]
    return X[t], y[t], X[c], y[c]


def _fit(ts, cfg, rng, progress):
    """FCM-initialised ANFIS (fuzzymodel) on one training set; returns (model, history dict).

    A TDM set's samples are weighted by their read attempts n+ + n-
    (``TrainingSet.weights``): the FCM, the least squares and the gradient all weigh
    a cell that saw 200 attempts 100 times one that saw 2, and the RMSEs in the
    history are weighted. SSM samples (one per read) are unweighted.
    """
    from fuzzymodel import ANFIS

    X, y = ts.X, ts.y
    w = None if ts.weights is None else np.asarray(ts.weights, dtype=float)
    if ts.kind == "ssm" and cfg.max_samples and len(y) > cfg.max_samples:
        keep = np.sort(rng.choice(len(y), cfg.max_samples, replace=False))
        X, y = X[keep], y[keep]
        w = None if w is None else w[keep]
    if w is None:
        Xt, yt, Xc, yc = _split(X, y, cfg.check_fraction, rng)
        wt = wc = None
    else:  # the weights ride along as a third column, so they split with their cells
        XWt, yt, XWc, yc = _split(np.column_stack([X, w]), y, cfg.check_fraction, rng)
        Xt, wt = XWt[:, :-1], XWt[:, -1]
        Xc, wc = (None, None) if XWc is None else (XWc[:, :-1], XWc[:, -1])
    model = ANFIS.from_fcm(Xt, yt, n_clusters=cfg.n_clusters, m=cfg.fcm_exponent, rng=rng,
                           input_names=["d_m", "alpha_rad"], sample_weight=wt)
    hist = model.fit(Xt, yt, epochs=cfg.epochs, X_check=Xc, y_check=yc, step_size=cfg.step_size,
                     sample_weight=wt, check_sample_weight=wc)
    progress(advance=1)
    return model, {
        "n_train": int(len(yt)),
        "n_check": 0 if yc is None else int(len(yc)),
        "weighted": wt is not None,
        "train_weight_sum": None if wt is None else float(wt.sum()),
        "train_rmse": np.asarray(hist.train_rmse, float).tolist(),
        "check_rmse": [None if not np.isfinite(v) else float(v) for v in np.asarray(hist.check_rmse)],
        "step_size": np.asarray(hist.step_size, float).tolist(),
        "best_epoch": int(hist.best_epoch),
    }


def stage_models(ctx) -> dict:
    """FCM + ANFIS for SSM and TDM (MCL and true poses) and the baselines; write models/."""
    from fuzzymodel import SensorModel
    from pipeline.acquisition import TrainingSet
    from pipeline.evaluation.baselines import fit_baselines
    from pipeline.evaluation.cells import CellGrid

    cfg = ctx.config.training
    rng = stage_rng(ctx.config, "models")
    progress = ctx.progress("FCM + ANFIS", total=2 * len(POSE_SOURCES))
    histories, info = {}, {}
    rssi_range = None
    for pose in POSE_SOURCES:
        suffix = "" if pose == "est" else "_truepose"
        ssm_set = TrainingSet.from_parquet(ctx.input(f"training/ssm_{pose}.parquet"))
        tdm_set = TrainingSet.from_parquet(ctx.input(f"training/tdm_{pose}.parquet"))
        rssi_range = tuple(ssm_set.rssi_range_dbm)
        ssm, h_ssm = _fit(ssm_set, cfg, rng, progress)
        tdm, h_tdm = _fit(tdm_set, cfg, rng, progress)
        ssm.save(ctx.out(f"models/ssm{suffix}.json"))
        tdm.save(ctx.out(f"models/tdm{suffix}.json"))
        SensorModel(ssm, tdm, rssi_range_dbm=rssi_range).save(ctx.out(f"models/sensor{suffix}.json"))
        histories[f"ssm{suffix}"] = h_ssm
        histories[f"tdm{suffix}"] = h_tdm
        info[pose] = {"ssm_train_rmse": h_ssm["train_rmse"][h_ssm["best_epoch"]],
                      "tdm_train_rmse": h_tdm["train_rmse"][h_tdm["best_epoch"]]}
    atomic_write_json(ctx.out("models/training_history.json"), histories)
    reads, _ = _read_reads(ctx)
    grid = CellGrid(d_max_m=cfg.d_max_m, d_bin_m=cfg.d_bin_m, alpha_bin_deg=cfg.alpha_bin_deg)
    base = fit_baselines(reads, rssi_range, grid=grid, pose="est")
    base.save(ctx.out("models/baselines.json"))
    base_true = fit_baselines(reads, rssi_range, grid=grid, pose="true")
    base_true.save(ctx.out("models/baselines_truepose.json"))
    # the chapter's competitors and ablations (pipeline.sensormodels), each on its own stream
    # so the ANFIS fits above stay bit-identical
    from pipeline.sensormodels import ABLATIONS, fit_ablation, fit_competitors

    comps = fit_competitors(reads, rssi_range, d_max_m=cfg.d_max_m, grid=grid,
                            rng=stage_rng(ctx.config, "competitors"))
    for name, model in comps.items():
        model.save(ctx.out(f"models/{name}.json"))
    ssm_set = TrainingSet.from_parquet(ctx.input("training/ssm_est.parquet"))
    tdm_set = TrainingSet.from_parquet(ctx.input("training/tdm_est.parquet"))
    for kind in ABLATIONS:
        fit_ablation(kind, ssm_set, tdm_set, stage_rng(ctx.config, f"ablation_{kind}"),
                     epochs=cfg.epochs, n_clusters=cfg.n_clusters, fcm_exponent=cfg.fcm_exponent,
                     check_fraction=cfg.check_fraction, max_samples=cfg.max_samples,
                     step_size=cfg.step_size).save(ctx.out(f"models/{kind}.json"))
    info["competitors"] = sorted(comps) + list(ABLATIONS)
    return info


def _sample_poses(reads, n: int, tilt_rad: dict) -> np.ndarray:
    """``n`` true antenna poses (x, y, z, yaw, pitch, roll) spread evenly over the tour."""
    cols = ["true_ant_x_m", "true_ant_y_m", "true_ant_z_m", "true_ant_yaw_rad"]
    att = reads.drop_duplicates(["time_s", "antenna"])
    poses = att[cols].to_numpy(float)
    pitch = np.array([tilt_rad[int(a)] for a in att["antenna"]])
    poses = np.column_stack([poses, pitch, np.zeros(len(poses))])
    idx = np.linspace(0, len(poses) - 1, n + 2)[1:-1].round().astype(int)
    return poses[idx]


def _tilts(cfg) -> dict:
    """Antenna index (as in reads.parquet) -> tilt [rad]."""
    return {i: float(np.deg2rad(a.tilt_deg)) for i, a in enumerate(cfg.robot.antennas)}


def _polar_points(pose: np.ndarray, d_m: np.ndarray, alpha_rad: np.ndarray) -> np.ndarray:
    """Points at antenna height on a (d, alpha) grid around ``pose`` (row-major d, alpha)."""
    D, A = np.meshgrid(d_m, alpha_rad, indexing="ij")
    ang = pose[3] + A.ravel()
    return np.column_stack([pose[0] + D.ravel() * np.cos(ang), pose[1] + D.ravel() * np.sin(ang),
                            np.full(D.size, pose[2])])


def stage_truth(ctx) -> dict:
    """Propagation truth: detection grids of the training and of the held-out reads, the
    truth at tag sites along the evaluation tour, and the chapter's free-space Fig. 6
    points and RSSI fields around evaluation-tour antenna poses."""
    from pipeline.evaluation.cells import CellGrid
    from pipeline.evaluation.truth import detection_truth

    cfg = ctx.config
    select_backend(cfg)
    budget = link_budget(cfg)
    reads, _ = _read_reads(ctx)
    eval_reads, _ = _read_reads(ctx, "eval_")
    grid = CellGrid(d_max_m=cfg.training.d_max_m, d_bin_m=cfg.training.d_bin_m,
                    alpha_bin_deg=cfg.training.alpha_bin_deg)
    q = cfg.reader.anticollision_miss_probability
    # the training truth is what a floor may be fitted on; the held-out one is scored on
    truth = detection_truth(reads, budget, grid=grid, miss_probability=q)
    truth.save(ctx.out("truth/detection_grid.npz"))
    eval_truth = detection_truth(eval_reads, budget, grid=grid, miss_probability=q)
    eval_truth.save(ctx.out("truth/detection_grid_eval.npz"))
    info = {"cells_with_attempts": int((truth.n_attempts > 0).sum()),
            "eval_cells_with_attempts": int((eval_truth.n_attempts > 0).sum())}
    info.update(_trace_sites(ctx, eval_reads))
    info.update(_trace_free_space_view(ctx, eval_reads, budget))
    return info


def _trace_sites(ctx, eval_reads) -> dict:
    """Truth at every tag site within reach of evaluation-tour antenna poses
    (pipeline.evaluation.sites); writes truth/site_truth.npz."""
    import propagation
    from pipeline.evaluation.sites import SiteTruth, obstructed_pairs
    from scenes.tagsites import tag_sites

    cfg = ctx.config
    ev = cfg.evaluation
    sc = load_scene(ctx)
    poses = _sample_poses(eval_reads, ev.n_site_poses, _tilts(cfg))
    sites = tag_sites(sc, spacing_m=ev.site_spacing_m, z_range_m=tuple(ev.eval_tag_heights_m))
    if len(sites) == 0:
        raise ValueError(f"{sc.name}: no tag sites on the scene's surfaces at "
                         f"evaluation.eval_tag_heights_m = {list(ev.eval_tag_heights_m)}")
    reach = max(cfg.training.d_max_m, ev.grid_d_max_m)
    d = np.linalg.norm(poses[:, None, :3] - sites.positions_m[None], axis=2)
    pairs = d <= reach
    traced = np.zeros(pairs.shape, bool)
    gain = np.full(pairs.shape, -np.inf)
    update = ctx.progress("truth at tag sites", total=len(poses))
    # one call per pose: the solver's cost grows with the receivers of a call, and poses
    # batched together would each be traced against the union of their sites
    for i in range(len(poses)):
        cols = np.flatnonzero(pairs[i])
        if len(cols):
            links = propagation.trace_links(
                sc, poses[i:i + 1], sites.positions_m[cols], frequency_hz=cfg.frequency_hz,
                tag_normals=sites.normals[cols], cache_dir=resolve_cache_dir(cfg),
                **trace_options(cfg))
            traced[i, cols] = np.asarray(links.traced, bool)[0]
            gain[i, cols] = np.where(traced[i, cols], np.asarray(links.gain_db, float)[0], -np.inf)
        update(advance=1)
    SiteTruth(antenna_poses=poses, positions_m=sites.positions_m, normals=sites.normals,
              material=sites.material, gain_db=gain, traced=traced,
              obstructed=obstructed_pairs(sc, poses[:, :3], sites.positions_m)
              ).save(ctx.out("truth/site_truth.npz"))
    return {"n_site_poses": int(len(poses)), "n_sites": int(len(sites)),
            "n_site_links": int(traced.sum())}


def _trace_free_space_view(ctx, eval_reads, budget) -> dict:
    """The chapter's Fig. 6 view: (d, alpha) points at antenna height in free space around
    evaluation-tour poses, and RSSI fields; writes truth/rho_points_*.npz, fields/*.npz."""
    import propagation
    from pipeline.evaluation.comparison import rho_points_truth
    from scenes.geometry import is_free

    cfg = ctx.config
    ev = cfg.evaluation
    sc = load_scene(ctx)
    rssi_range = tuple(json.loads(ctx.input("models/sensor.json").read_text())["rssi_range_dbm"])
    poses = _sample_poses(eval_reads, ev.n_sample_poses, _tilts(cfg))
    d = np.linspace(ev.grid_d_max_m / ev.grid_n_d, ev.grid_d_max_m, ev.grid_n_d)
    a = np.deg2rad(np.linspace(-90.0, 90.0, ev.grid_n_alpha))
    cache = resolve_cache_dir(cfg)
    opts = trace_options(cfg)
    update = ctx.progress("Fig. 6 free-space view + fields", total=len(poses))
    lo, hi = sc.bounds_m
    bounds = [float(lo[0]), float(lo[1]), float(hi[0]), float(hi[1])]
    n_free = 0
    for i, pose in enumerate(poses):
        pts = _polar_points(pose, d, a)
        free = is_free(sc, pts)
        links = propagation.trace_links(sc, pose[None], pts[free], frequency_hz=cfg.frequency_hz,
                                        cache_dir=cache, **opts)
        gain = np.full(len(pts), -np.inf)
        gain[free] = np.asarray(links.gain_db, float)[0]
        n_free += int(free.sum())
        rp = rho_points_truth(pose, pts, gain, budget, rssi_range,
                              miss_probability=cfg.reader.anticollision_miss_probability,
                              grid_shape=(len(d), len(a)))
        rp.save(ctx.out(f"truth/rho_points_{i:02d}.npz"))
        if i < ev.n_field_poses:
            field = propagation.rssi_field(
                sc, pose, frequency_hz=cfg.frequency_hz, cell_size_m=cfg.tracing.field_cell_m,
                plane_height_m=ev.field_height_m, samples_per_tx=cfg.tracing.field_samples_per_tx,
                max_depth=cfg.tracing.max_depth, reader_pattern=cfg.tracing.reader_pattern,
                reader_polarization=cfg.tracing.reader_polarization,
                plane_bounds_m=bounds, cache_dir=cache)
            field.save(ctx.out(f"fields/field_{i:02d}.npz"))
        update(advance=1)
    return {"n_sample_poses": int(len(poses)), "n_points_traced": n_free}


def field_coverage(cfg, scene, field_paths) -> dict | None:
    """Corridor coverage of the saved RSSI fields (pipeline.evaluation.detection_coverage).

    Cells outside the scene's free space are left out. Returns None without fields, else
    ``{"corridor_fraction": mean over fields, "fields": [CoverageResult dicts]}``.
    """
    import propagation
    from pipeline.evaluation.coverage import detection_coverage
    from scenes.geometry import is_free

    if not field_paths:
        return None
    budget = link_budget(cfg)
    per_field = []
    for path in field_paths:
        field = propagation.RssiField.load(path)
        free = is_free(scene, field.plane_centers_m.reshape(-1, 3))
        per_field.append(detection_coverage(
            field.plane_gain_db, budget, free,
            miss_probability=cfg.reader.anticollision_miss_probability).to_dict())
    return {"corridor_fraction": float(np.mean([c["fraction"] for c in per_field])),
            "fields": per_field}


def stage_evaluation(ctx) -> dict:
    """Every model against the truth; write metrics.json and the Fig. 7 / tag-site tables.

    ``metrics.json`` sections: ``heldout`` (every model and the floor on the held-out tag
    layout read by the evaluation tour; the headline), ``fig7`` (chapter Sec. 5 on the
    evaluation tour, per model), ``tag_sites`` (truth where tags are, per model),
    ``error_budget``, ``localisation`` (MCL pose error and bias per tour), ``in_sample``
    (the same comparisons on the training tour's reads: labelled, not the headline),
    ``free_space_view`` (the chapter's Fig. 6 plane at antenna height), ``coverage``.
    """
    import pandas as pd

    from fuzzymodel import SensorModel
    from pipeline.evaluation.baselines import BaselineSensorModel
    from pipeline.evaluation.comparison import RhoPoints, rho_vs_truth
    from pipeline.evaluation.evaluate import EvaluationInputs, evaluate_all
    from pipeline.evaluation.fig7 import fig7_errors
    from pipeline.evaluation.heldout import error_budget, heldout_scores
    from pipeline.evaluation.metrics import nan_to_none
    from pipeline.evaluation.sites import SiteTruth, site_comparison
    from pipeline.evaluation.tables import read_tags, write_parquet_atomic
    from pipeline.evaluation.truth import TruthGrid

    cfg = ctx.config
    budget = link_budget(cfg)
    reads, meta = _read_reads(ctx)
    eval_reads, eval_meta = _read_reads(ctx, "eval_")
    tags = read_tags(ctx.input("scene/tags.parquet"))
    _check_split(tags, reads, eval_reads, ctx.store.path("scene/tags.parquet"))
    eval_poses = pd.read_parquet(ctx.input("eval_poses.parquet"))
    base = BaselineSensorModel.load(ctx.input("models/baselines.json"))
    sensors = {
        "anfis": SensorModel.load(ctx.input("models/sensor.json")),
        "anfis_truepose": SensorModel.load(ctx.input("models/sensor_truepose.json")),
        "log_distance": base,
        "grid_count": base,
    }
    from pipeline.sensormodels import ABLATIONS, COMPETITORS, load_competitor

    sensors.update({n: load_competitor(ctx.input(f"models/{n}.json")) for n in COMPETITORS})
    sensors.update({k: SensorModel.load(ctx.input(f"models/{k}.json")) for k in ABLATIONS})
    extra = (*COMPETITORS, *ABLATIONS)
    rssi_names = ("anfis", "anfis_truepose", "log_distance",
                  *(n for n in extra if getattr(sensors[n], "predicts_rssi", True)))
    train_truth = TruthGrid.load(ctx.input("truth/detection_grid.npz"))
    eval_truth = TruthGrid.load(ctx.input("truth/detection_grid_eval.npz"))
    tr = cfg.training
    heldout = heldout_scores(sensors, eval_reads, train_truth, eval_truth, budget,
                             d_max_m=tr.d_max_m, min_attempts=tr.min_attempts,
                             rssi_models=rssi_names,
                             detection_models=("anfis", "anfis_truepose", "grid_count", *extra))
    metrics = {"heldout": heldout, "error_budget": error_budget(heldout),
               "reads": {"range_margin": _range_margin(meta, eval_meta)}}
    fig7 = {}
    for name in rssi_names:
        f7 = fig7_errors(eval_reads, tags, sensors[name], radius_m=cfg.evaluation.fig7_radius_m,
                         pose_times_s=eval_poses["time_s"].to_numpy(float),
                         antenna_pitch_rad=_tilts(cfg), d_max_m=tr.d_max_m)
        fig7[name] = f7.to_dict()
        if name == "anfis":  # the Fig. 7 figure reads it instead of recomputing
            f7.write_table(ctx.out("truth/fig7_errors.parquet"))
    metrics["fig7"] = fig7
    site_truth = SiteTruth.load(ctx.input("truth/site_truth.npz"))
    q = cfg.reader.anticollision_miss_probability
    metrics["tag_sites"] = {}
    for name in rssi_names:
        sc_ = site_comparison(site_truth, sensors[name], budget, miss_probability=q,
                              d_max_m=tr.d_max_m)
        metrics["tag_sites"][name] = sc_.to_dict()
        if name == "anfis":
            write_parquet_atomic(sc_.per_site, ctx.out("truth/site_errors.parquet"))
    loc = ctx.store.path("tour/localisation.json")
    if loc.is_file():
        metrics["localisation"] = json.loads(loc.read_text())
    # in-sample: the training tour's own reads (labelled; not the headline)
    insample = evaluate_all(
        {"anfis": sensors["anfis"], "anfis_truepose": sensors["anfis_truepose"],
         "baselines": base,
         "baselines_truepose": BaselineSensorModel.load(ctx.input("models/baselines_truepose.json"))},
        EvaluationInputs(reads=reads, truth=train_truth, budget=budget,
                         d_max_m=tr.d_max_m, min_attempts=tr.min_attempts)).to_dict()
    insample["note"] = ("in_sample: scored on the training tour's reads of the training tags, "
                        "which the models were fitted on")
    metrics["in_sample"] = insample
    rho_points = [RhoPoints.load(p) for p in sorted(ctx.store.path("truth").glob("rho_points_*.npz"))]
    metrics["free_space_view"] = {
        name: rho_vs_truth(rho_points, sensors[name]).to_dict() for name in rssi_names
    } if rho_points else None
    fields = sorted(ctx.store.path("fields").glob("field_*.npz"))
    coverage = field_coverage(cfg, load_scene(ctx), fields)
    if coverage is not None:
        metrics["coverage"] = coverage
    atomic_write_json(ctx.out("metrics.json"), nan_to_none(metrics))
    return {"models": sorted(sensors)}


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
    for name, df, want in (("reads.parquet", reads, "train"), ("eval_reads.parquet", eval_reads, "eval")):
        ids = set(df["tag_id"].astype(str))
        wrong = sorted(t for t in ids if split.get(t) != want)
        if wrong:
            raise ValueError(f"{name} holds tags {wrong[:5]} whose split in {path} is not {want!r}: "
                             "training and held-out layouts mix; rerun the reads stage")
