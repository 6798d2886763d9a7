"""Stage ``truth``: the propagation truth: detection grids of the training and of the
held-out reads, and the chapter's Fig. 6 truth (rho at free-space points) from the gains
the ``truth_traces`` stage traced; writes ``truth/``."""

from __future__ import annotations

import json

import numpy as np

from pipeline import runfiles
from pipeline.acquisition.singulation import miss_probability_at_poses, miss_probability_of_attempts
from pipeline.engine.study import Stage
from pipeline.evaluation.cells import CellGrid
from pipeline.evaluation.comparison import rho_points_truth
from pipeline.evaluation.sites import SiteTruth
from pipeline.evaluation.truth import detection_truth
from pipeline.runfiles import STAGE_OUTPUTS
from pipeline.stages.common import attempt_poses, read_reads, spread_evenly
from pipeline.stages.truth_traces import free_space_grid
from pipeline.studyscene import link_budget
from scenes.fileio import read_npz

__all__ = ["STAGE", "attempt_miss_probability", "pose_miss_probability", "stage_truth"]


def stage_truth(ctx) -> dict:
    """Propagation truth: detection grids of the training and of the held-out reads, and
    the chapter's free-space Fig. 6 truth around evaluation-tour antenna poses."""
    cfg = ctx.config
    _check_trace_poses(ctx)
    budget = link_budget(cfg)
    reads, _ = read_reads(ctx)
    eval_reads, _ = read_reads(ctx, "eval_")
    grid = CellGrid(d_max_m=cfg.training.d_max_m, d_bin_m=cfg.training.d_bin_m,
                    alpha_bin_deg=cfg.training.alpha_bin_deg)
    # the training truth is what a floor may be fitted on; the held-out one is scored on
    truth = detection_truth(reads, budget, grid=grid,
                            miss_probability=attempt_miss_probability(cfg, reads, budget))
    truth.save(ctx.out(runfiles.DETECTION_GRID))
    eval_truth = detection_truth(eval_reads, budget, grid=grid,
                                 miss_probability=attempt_miss_probability(cfg, eval_reads, budget))
    eval_truth.save(ctx.out(runfiles.DETECTION_GRID_EVAL))
    info = {"cells_with_attempts": int((truth.n_attempts > 0).sum()),
            "eval_cells_with_attempts": int((eval_truth.n_attempts > 0).sum())}
    info.update(_free_space_view(ctx, eval_reads, budget))
    return info


def _check_trace_poses(ctx) -> None:
    """The truth_traces stage drew the evaluation path itself (``tour.eval_track``):
    its antenna poses must be those of the tour's track, the read log's, or its traces
    belong to another path (say, the tour's code changed and truth_traces stayed cached).

    Raises
    ------
    ValueError
        Naming the file whose poses differ and the way out.
    """
    ev = ctx.config.evaluation
    poses = attempt_poses(ctx, "eval")
    path = ctx.input(runfiles.SITE_TRUTH)
    checks = [(path, SiteTruth.load(path).antenna_poses, spread_evenly(poses, ev.n_site_poses))]
    for i, want in enumerate(spread_evenly(poses, ev.n_sample_poses)):
        p = ctx.input(runfiles.FREE_SPACE_POINTS.format(i=i))
        with read_npz(p) as z:
            checks.append((p, z["pose"], want))
    for p, got, want in checks:
        if np.shape(got) != np.shape(want) or not np.array_equal(got, want):
            raise ValueError(f"{p}: its antenna poses are not the evaluation tour's "
                             f"(tour/eval_track.npz): the truth's traces are of another path; "
                             "rerun with --force truth_traces")


def attempt_miss_probability(cfg, reads, budget):
    """The truth's miss probability of a closing attempt of ``reads``: the constant of the
    ``"fixed"`` inventory (a float), else one per row (Gen2,
    :func:`pipeline.acquisition.singulation.miss_probability_of_attempts`)."""
    if cfg.reader.inventory == "fixed":
        return cfg.reader.anticollision_miss_probability
    return miss_probability_of_attempts(reads, cfg.reader, budget,
                                        n_antennas=len(cfg.robot.antennas))


def pose_miss_probability(cfg, eval_reads, poses, budget):
    """Miss probability of a tag site or point (not in the log) at antenna ``poses`` taken
    from ``eval_reads``: the ``"fixed"`` constant (a float), or per pose (p,) for Gen2
    (:func:`pipeline.acquisition.singulation.miss_probability_at_poses`, the site joining
    the slot's closing tags)."""
    if cfg.reader.inventory == "fixed":
        return cfg.reader.anticollision_miss_probability
    return miss_probability_at_poses(eval_reads, poses, cfg.reader, budget, extra_tags=1,
                                     n_antennas=len(cfg.robot.antennas))


def _free_space_view(ctx, eval_reads, budget) -> dict:
    """The chapter's Fig. 6 truth from the traced free-space gains
    (truth/free_space_points_*.npz of the truth_traces stage): writes truth/rho_points_*.npz."""
    cfg = ctx.config
    rssi_range = tuple(json.loads(ctx.input(runfiles.SENSOR_MODEL).read_text())["rssi_range_dbm"])
    d, a = free_space_grid(cfg)
    for i in range(cfg.evaluation.n_sample_poses):
        path = ctx.input(runfiles.FREE_SPACE_POINTS.format(i=i))
        try:
            with read_npz(path) as z:
                pose, pts, gain = z["pose"], z["points_m"], z["gain_db"]
        except (OSError, KeyError, ValueError) as exc:
            raise ValueError(f"{path}: cannot read the traced free-space points ({exc}); "
                             "delete it to re-run the truth_traces stage") from None
        if len(pts) != len(d) * len(a) or np.isnan(gain).any():
            raise ValueError(f"{path}: {len(pts)} points (NaN gains: {int(np.isnan(gain).sum())}) "
                             f"where the grid has {len(d) * len(a)}; delete it to re-run the "
                             "truth_traces stage")
        q = pose_miss_probability(cfg, eval_reads, pose[None], budget)
        rp = rho_points_truth(pose, pts, gain, budget, rssi_range,
                              miss_probability=q if np.ndim(q) == 0 else float(q[0]),
                              grid_shape=(len(d), len(a)))
        rp.save(ctx.out(runfiles.RHO_POINTS.format(i=i)))
    return {"n_sample_poses": int(cfg.evaluation.n_sample_poses)}


STAGE = Stage("truth", stage_truth,
              ("seed", "frequency_hz", "reader", "robot", "evaluation", "training.d_max_m",
               "training.d_bin_m", "training.alpha_bin_deg"),
              ("scene", "tour", "reads", "models", "truth_traces"),
              version=5,  # each version's change: CHANGELOG.md
              description="propagation truth",
              outputs=STAGE_OUTPUTS["truth"])
