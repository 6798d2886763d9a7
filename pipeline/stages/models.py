"""Stage ``models``: FCM + ANFIS for the SSM and the TDM (MCL-pose and true-pose; TDM
weighted by read attempts), the baselines, the chapter's competitors and the ablations
(``fuzzymodel``, ``pipeline.evaluation``, ``pipeline.sensormodels``); writes ``models/``."""

from __future__ import annotations

import numpy as np

from fuzzymodel import ANFIS, SensorModel
from pipeline import runfiles
from pipeline.acquisition import TrainingSet
from pipeline.engine.runstore import atomic_write_json
from pipeline.engine.study import Stage
from pipeline.evaluation.baselines import fit_baselines
from pipeline.evaluation.cells import CellGrid
from pipeline.runfiles import STAGE_OUTPUTS
from pipeline.sensormodels import fit_competitors, model_info, model_names, tag_height_differences
from pipeline.sensormodels.ablations import train_check_split
from pipeline.sensormodels.registry import stage_version
from pipeline.stages.common import pose_sources, read_reads, split_tags
from pipeline.studyscene import stage_rng

__all__ = ["STAGE", "stage_models"]


def _split(X, y, frac: float, rng):
    return train_check_split(X, y, frac, rng)


def _fit(ts, cfg, rng, progress):
    """FCM-initialised ANFIS (fuzzymodel) on one training set; returns (model, history dict).

    A TDM set's samples are weighted by their read attempts n+ + n-
    (``TrainingSet.weights``): the FCM, the least squares and the gradient all weigh
    a cell that saw 200 attempts 100 times one that saw 2, and the RMSEs in the
    history are weighted. SSM samples (one per read) are unweighted.
    """
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
    cfg = ctx.config.training
    rng = stage_rng(ctx.config, "models")
    progress = ctx.progress("FCM + ANFIS", total=2 * len(pose_sources(ctx.config)))
    histories, info = {}, {}
    rssi_range = None
    for pose in pose_sources(ctx.config):
        suffix = "" if pose == "est" else "_truepose"
        ssm_set = TrainingSet.from_parquet(ctx.input(runfiles.TRAINING_SET.format(kind="ssm", pose=pose)))
        tdm_set = TrainingSet.from_parquet(ctx.input(runfiles.TRAINING_SET.format(kind="tdm", pose=pose)))
        rssi_range = tuple(ssm_set.rssi_range_dbm)
        ssm, h_ssm = _fit(ssm_set, cfg, rng, progress)
        tdm, h_tdm = _fit(tdm_set, cfg, rng, progress)
        ssm.save(ctx.out(runfiles.MODEL.format(name=f"ssm{suffix}")))
        tdm.save(ctx.out(runfiles.MODEL.format(name=f"tdm{suffix}")))
        SensorModel(ssm, tdm, rssi_range_dbm=rssi_range).save(ctx.out(runfiles.MODEL.format(name=f"sensor{suffix}")))
        histories[f"ssm{suffix}"] = h_ssm
        histories[f"tdm{suffix}"] = h_tdm
        info[pose] = {"ssm_train_rmse": h_ssm["train_rmse"][h_ssm["best_epoch"]],
                      "tdm_train_rmse": h_tdm["train_rmse"][h_tdm["best_epoch"]]}
    atomic_write_json(ctx.out(runfiles.TRAINING_HISTORY), histories)
    reads, _ = read_reads(ctx)
    grid = CellGrid(d_max_m=cfg.d_max_m, d_bin_m=cfg.d_bin_m, alpha_bin_deg=cfg.alpha_bin_deg)
    base = fit_baselines(reads, rssi_range, grid=grid, pose="est")
    base.save(ctx.out(runfiles.BASELINES))
    if "true" in pose_sources(ctx.config):
        base_true = fit_baselines(reads, rssi_range, grid=grid, pose="true")
        base_true.save(ctx.out(runfiles.BASELINES_TRUEPOSE))
    # the chapter's competitors and ablations (pipeline.sensormodels), each on its own stream
    # so the ANFIS fits above stay bit-identical

    # the training tags' heights above the antennas (Vorst & Zell's ground plane)
    dz = tag_height_differences(reads, split_tags(ctx, "train"), pose="est")
    comps = fit_competitors(reads, rssi_range, d_max_m=cfg.d_max_m, grid=grid,
                            rng=stage_rng(ctx.config, "competitors"), dz_m=dz)
    for name, model in comps.items():
        model.save(ctx.out(model_info(name).file))
    ssm_set = TrainingSet.from_parquet(ctx.input(runfiles.TRAINING_SET.format(kind="ssm", pose="est")))
    tdm_set = TrainingSet.from_parquet(ctx.input(runfiles.TRAINING_SET.format(kind="tdm", pose="est")))
    ablations = [model_info(k) for k in model_names(role="ablation")]  # the registry's
    for m in ablations:
        m.fit(ssm_set, tdm_set, stage_rng(ctx.config, f"ablation_{m.key}"),
              epochs=cfg.epochs, n_clusters=cfg.n_clusters, fcm_exponent=cfg.fcm_exponent,
              check_fraction=cfg.check_fraction, max_samples=cfg.max_samples,
              step_size=cfg.step_size, **m.fit_options).save(ctx.out(m.file))
    info["competitors"] = sorted(comps) + [m.key for m in ablations]
    return info


STAGE = Stage("models", stage_models, ("seed", "training"), ("training_sets", "reads"),
              version=stage_version(5),  # each version's change: CHANGELOG.md
              description="FCM + ANFIS",
              outputs=STAGE_OUTPUTS["models"])
