"""Stage ``training_sets``: SSM and TDM samples from the training tour's reads, on the
MCL poses and on the true poses (``pipeline.acquisition``); writes ``training/``."""

from __future__ import annotations

from pipeline import runfiles
from pipeline.acquisition import rssi_range_from_data, ssm_samples, tdm_samples
from pipeline.engine.study import Stage
from pipeline.runfiles import STAGE_OUTPUTS
from pipeline.stages.common import pose_sources, read_reads

__all__ = ["STAGE", "stage_training_sets"]


def stage_training_sets(ctx) -> dict:
    """SSM and TDM training sets from the tour's reads, for MCL and for true poses."""
    cfg = ctx.config.training
    reads, _ = read_reads(ctx)
    rng_dbm = cfg.rssi_range_dbm
    if rng_dbm is None:
        # one range for every model (MCL and true poses), fixed by the reads themselves
        rssi = reads.loc[reads["read"].to_numpy(bool) & (reads["d_est_m"] < cfg.d_max_m), "rssi_dbm"]
        rng_dbm = rssi_range_from_data(rssi.to_numpy(float))
    info = {"rssi_range_dbm": [float(v) for v in rng_dbm]}
    for pose in pose_sources(ctx.config):
        ssm = ssm_samples(reads, d_max_m=cfg.d_max_m, rssi_range_dbm=rng_dbm, pose=pose)
        tdm = tdm_samples(reads, d_bin_m=cfg.d_bin_m, alpha_bin_deg=cfg.alpha_bin_deg,
                          d_max_m=cfg.d_max_m, pose=pose, min_attempts=cfg.min_attempts)
        if len(ssm) < cfg.n_clusters + 2 or len(tdm) < cfg.n_clusters + 2:
            raise ValueError(f"too few training samples for pose={pose!r}: SSM {len(ssm)}, TDM "
                             f"{len(tdm)} cells (need > n_clusters + 1 = {cfg.n_clusters + 1}); "
                             "lengthen the tour or lower training.min_attempts")
        ssm.to_parquet(ctx.out(runfiles.TRAINING_SET.format(kind="ssm", pose=pose)))
        tdm.to_parquet(ctx.out(runfiles.TRAINING_SET.format(kind="tdm", pose=pose)))
        info[pose] = {"ssm_samples": len(ssm), "tdm_cells": len(tdm)}
    return info


STAGE = Stage("training_sets", stage_training_sets,
              ("training.d_max_m", "training.rssi_range_dbm", "training.d_bin_m",
               "training.alpha_bin_deg", "training.min_attempts", "training.n_clusters"),
              ("reads",), description="training sets",
              outputs=STAGE_OUTPUTS["training_sets"])
