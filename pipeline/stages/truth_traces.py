"""Stage ``truth_traces``: the propagation truth's own ray traces, which need no reads: the
gains at every tag site within reach of evaluation-tour antenna poses, at the chapter's
Fig. 6 free-space points around some of those poses, and the RSSI fields; writes
``truth/site_truth.npz``, ``truth/free_space_points_*.npz`` and ``fields/*.npz``.

The antenna poses are those of the evaluation tour's read attempts, computed from the
evaluation path's true poses (:func:`pipeline.stages.common.attempt_poses` of
:func:`pipeline.stages.tour.eval_track`: the poses the read log holds), which need no MCL,
so the stage depends on the scene only and runs in a process of its own beside the tour
and the reads stage (``own_process``): it traces while the tour's MCL leaves a core idle
and while the reads stage traces. The ``truth``
stage turns the free-space gains into the Fig. 6 truth with the reads and the models.
"""

from __future__ import annotations

import numpy as np

import propagation
from pipeline import runfiles
from pipeline.engine.study import Stage
from pipeline.engine.tracetasks import trace_tasks
from pipeline.evaluation.sites import SiteTruth, obstructed_pairs
from pipeline.runfiles import STAGE_OUTPUTS
from pipeline.stages.common import TRACING_KEYS, attempt_poses, load_scene, spread_evenly
from pipeline.stages.tour import eval_track
from pipeline.studyscene import resolve_cache_dir, select_backend, trace_options
from scenes.fileio import atomic_save_npz
from scenes.geometry import is_free
from scenes.tagsites import tag_sites

__all__ = ["STAGE", "free_space_grid", "stage_truth_traces"]


def free_space_grid(cfg) -> tuple[np.ndarray, np.ndarray]:
    """The Fig. 6 view's polar grid: distances (n_d,) [m] and bearings (n_alpha,) [rad]."""
    ev = cfg.evaluation
    d = np.linspace(ev.grid_d_max_m / ev.grid_n_d, ev.grid_d_max_m, ev.grid_n_d)
    a = np.deg2rad(np.linspace(-90.0, 90.0, ev.grid_n_alpha))
    return d, a


def _polar_points(pose: np.ndarray, d_m: np.ndarray, alpha_rad: np.ndarray) -> np.ndarray:
    """Points at antenna height on a (d, alpha) grid around ``pose`` (row-major d, alpha)."""
    D, A = np.meshgrid(d_m, alpha_rad, indexing="ij")
    ang = pose[3] + A.ravel()
    return np.column_stack([pose[0] + D.ravel() * np.cos(ang), pose[1] + D.ravel() * np.sin(ang),
                            np.full(D.size, pose[2])])


def stage_truth_traces(ctx) -> dict:
    """Gains at tag sites and at free-space points, and RSSI fields, around
    evaluation-tour antenna poses."""
    select_backend(ctx.config)
    # the evaluation path's poses without the tour's MCL: this stage starts beside the tour
    poses = attempt_poses(ctx, "eval", eval_track(ctx))
    with trace_tasks(ctx.config) as tasks:  # tracing.scheduler: chunks as Dask tasks
        info = _trace_sites(ctx, poses)
        info.update(_trace_free_space_view(ctx, poses))
    if tasks is not None:
        info["trace_tasks"] = tasks.as_dict()
    return info


def _trace_sites(ctx, attempt_pose_rows: np.ndarray) -> dict:
    """Truth at every tag site within reach of evaluation-tour antenna poses
    (pipeline.evaluation.sites); writes truth/site_truth.npz."""
    cfg = ctx.config
    ev = cfg.evaluation
    sc = load_scene(ctx)
    poses = spread_evenly(attempt_pose_rows, ev.n_site_poses)
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
    fresh = 0
    # one call per pose: the solver's cost grows with the receivers of a call, and poses
    # batched together would each be traced against the union of their sites
    for i in range(len(poses)):
        cols = np.flatnonzero(pairs[i])
        if len(cols):
            links = propagation.trace_links(
                sc, poses[i:i + 1], sites.positions_m[cols], trace_options(cfg),
                frequency_hz=cfg.frequency_hz, tag_normals=sites.normals[cols],
                cache_dir=resolve_cache_dir(cfg))
            fresh += int(links.n_traced_sources)
            traced[i, cols] = np.asarray(links.traced, bool)[0]
            gain[i, cols] = np.where(traced[i, cols], np.asarray(links.gain_db, float)[0], -np.inf)
        update(advance=1)
    SiteTruth(antenna_poses=poses, positions_m=sites.positions_m, normals=sites.normals,
              material=sites.material, gain_db=gain, traced=traced,
              obstructed=obstructed_pairs(sc, poses[:, :3], sites.positions_m)
              ).save(ctx.out(runfiles.SITE_TRUTH))
    return {"n_site_poses": int(len(poses)), "n_sites": int(len(sites)),
            "n_site_links": int(traced.sum()), "n_site_sources_traced": fresh}


def _trace_free_space_view(ctx, attempt_pose_rows: np.ndarray) -> dict:
    """The chapter's Fig. 6 view: gains at (d, alpha) points at antenna height in free
    space around evaluation-tour poses, and RSSI fields; writes
    truth/free_space_points_*.npz (``pose``, ``points_m``, ``gain_db``; -inf where not
    free) and fields/*.npz."""
    cfg = ctx.config
    ev = cfg.evaluation
    sc = load_scene(ctx)
    poses = spread_evenly(attempt_pose_rows, ev.n_sample_poses)
    d, a = free_space_grid(cfg)
    cache = resolve_cache_dir(cfg)
    opts = trace_options(cfg)
    update = ctx.progress("Fig. 6 free-space view + fields", total=len(poses))
    lo, hi = sc.bounds_m
    bounds = [float(lo[0]), float(lo[1]), float(hi[0]), float(hi[1])]
    n_free = fresh = 0
    for i, pose in enumerate(poses):
        pts = _polar_points(pose, d, a)
        free = is_free(sc, pts)
        links = propagation.trace_links(sc, pose[None], pts[free], opts, frequency_hz=cfg.frequency_hz,
                                        cache_dir=cache)
        gain = np.full(len(pts), -np.inf)
        gain[free] = np.asarray(links.gain_db, float)[0]
        n_free += int(free.sum())
        fresh += int(links.n_traced_sources)
        atomic_save_npz(ctx.out(runfiles.FREE_SPACE_POINTS.format(i=i)), pose=pose, points_m=pts,
                        gain_db=gain)
        if i < ev.n_field_poses:
            field = propagation.rssi_field(
                sc, pose, frequency_hz=cfg.frequency_hz, cell_size_m=cfg.tracing.field_cell_m,
                plane_height_m=ev.field_height_m, samples_per_tx=cfg.tracing.field_samples_per_tx,
                max_depth=cfg.tracing.max_depth, reader_pattern=cfg.tracing.reader_pattern,
                reader_polarization=cfg.tracing.reader_polarization,
                include_walls=cfg.tracing.field_walls, plane_bounds_m=bounds, cache_dir=cache)
            field.save(ctx.out(runfiles.FIELD.format(i=i)))
        update(advance=1)
    return {"n_sample_poses": int(len(poses)), "n_points_traced": n_free,
            "n_view_sources_traced": fresh}


STAGE = Stage("truth_traces", stage_truth_traces,
              ("seed", "tour", "evaluation", "training.d_max_m", "robot", "reader.read_rate_hz",
               "reader.antenna_mode", "tracing.field_cell_m", "tracing.field_samples_per_tx",
               "tracing.field_walls") + TRACING_KEYS,
              ("scene",), version=3,  # each version's change: CHANGELOG.md
              description="propagation truth: traces at tag sites, Fig. 6 points, RSSI fields",
              # needs nothing of the tour's MCL or the reads: traces beside them
              # (pipeline.engine.stageproc)
              own_process=True,
              outputs=STAGE_OUTPUTS["truth_traces"])
