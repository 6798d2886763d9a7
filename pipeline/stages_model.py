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
    """FCM-initialised ANFIS (fuzzymodel) on one training set; returns (model, history dict)."""
    from fuzzymodel import ANFIS

    X, y = ts.X, ts.y
    if ts.kind == "ssm" and cfg.max_samples and len(y) > cfg.max_samples:
        keep = np.sort(rng.choice(len(y), cfg.max_samples, replace=False))
        X, y = X[keep], y[keep]
    Xt, yt, Xc, yc = _split(X, y, cfg.check_fraction, rng)
    model = ANFIS.from_fcm(Xt, yt, n_clusters=cfg.n_clusters, m=cfg.fcm_exponent, rng=rng,
                           input_names=["d_m", "alpha_rad"])
    hist = model.fit(Xt, yt, epochs=cfg.epochs, X_check=Xc, y_check=yc, step_size=cfg.step_size)
    progress(advance=1)
    return model, {
        "n_train": int(len(yt)),
        "n_check": 0 if yc is None else int(len(yc)),
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
    """Propagation truth: Fig. 6 (d, alpha) points traced around sample antenna poses,
    RSSI fields at those poses, and the detection truth grid over (d, alpha)."""
    import propagation
    from pipeline.evaluation.cells import CellGrid
    from pipeline.evaluation.comparison import rho_points_truth
    from pipeline.evaluation.truth import detection_truth
    from scenes.geometry import is_free

    cfg = ctx.config
    ev = cfg.evaluation
    select_backend(cfg)
    sc = load_scene(ctx)
    budget = link_budget(cfg)
    reads, _ = _read_reads(ctx)
    rssi_range = tuple(json.loads(ctx.input("models/sensor.json").read_text())["rssi_range_dbm"])
    grid = CellGrid(d_max_m=cfg.training.d_max_m, d_bin_m=cfg.training.d_bin_m,
                    alpha_bin_deg=cfg.training.alpha_bin_deg)
    truth = detection_truth(reads, budget, grid=grid,
                            miss_probability=cfg.reader.anticollision_miss_probability)
    truth.save(ctx.out("truth/detection_grid.npz"))
    poses = _sample_poses(reads, ev.n_sample_poses, _tilts(cfg))
    d = np.linspace(ev.grid_d_max_m / ev.grid_n_d, ev.grid_d_max_m, ev.grid_n_d)
    a = np.deg2rad(np.linspace(-90.0, 90.0, ev.grid_n_alpha))
    cache = resolve_cache_dir(cfg)
    opts = trace_options(cfg)
    update = ctx.progress("Fig. 6 truth + fields", total=len(poses))
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
                plane_bounds_m=bounds)
            field.save(ctx.out(f"fields/field_{i:02d}.npz"))
        update(advance=1)
    return {"n_sample_poses": int(len(poses)), "n_points_traced": n_free,
            "cells_with_attempts": int((truth.n_attempts > 0).sum())}


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
    """Every model against the truth (pipeline.evaluation.evaluate_all); write metrics.json
    (with the field coverage) and truth/fig7_errors.parquet."""
    from fuzzymodel import SensorModel
    from pipeline.evaluation.baselines import BaselineSensorModel
    from pipeline.evaluation.comparison import RhoPoints
    from pipeline.evaluation.evaluate import EvaluationInputs, evaluate_all
    from pipeline.evaluation.tables import read_tags
    from pipeline.evaluation.truth import TruthGrid

    cfg = ctx.config
    reads, _ = _read_reads(ctx)
    eval_reads, _ = _read_reads(ctx, "eval_")
    import pandas as pd

    eval_poses = pd.read_parquet(ctx.input("eval_poses.parquet"))
    rho_points = [RhoPoints.load(p) for p in sorted(ctx.store.path("truth").glob("rho_points_*.npz"))]
    sensors = {
        "anfis": SensorModel.load(ctx.input("models/sensor.json")),
        "anfis_truepose": SensorModel.load(ctx.input("models/sensor_truepose.json")),
        "baselines": BaselineSensorModel.load(ctx.input("models/baselines.json")),
        "baselines_truepose": BaselineSensorModel.load(ctx.input("models/baselines_truepose.json")),
    }
    inputs = EvaluationInputs(
        reads=reads, truth=TruthGrid.load(ctx.input("truth/detection_grid.npz")),
        budget=link_budget(cfg), eval_reads=eval_reads,
        tags=read_tags(ctx.input("scene/tags.parquet")), rho_points=rho_points,
        pose_times_s=eval_poses["time_s"].to_numpy(float), d_max_m=cfg.training.d_max_m,
        min_attempts=cfg.training.min_attempts, fig7_radius_m=cfg.evaluation.fig7_radius_m,
        antenna_pitch_rad=_tilts(cfg),
    )
    result = evaluate_all(sensors, inputs)
    fig7 = result.models["anfis"].fig7
    if fig7 is not None:  # the Fig. 7 figure reads it instead of recomputing
        fig7.write_table(ctx.out("truth/fig7_errors.parquet"))
    metrics = result.to_dict()
    fields = sorted(ctx.store.path("fields").glob("field_*.npz"))
    coverage = field_coverage(cfg, load_scene(ctx), fields)
    if coverage is not None:
        metrics["coverage"] = coverage
    atomic_write_json(ctx.out("metrics.json"), metrics)
    return {"models": sorted(sensors)}
