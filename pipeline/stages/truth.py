"""Stage ``truth``: the propagation truth: detection grids of the training and of the
held-out reads, the truth at tag sites along the evaluation tour, the chapter's Fig. 6
free-space points and RSSI fields (``propagation``); writes ``truth/`` and ``fields/``."""

from __future__ import annotations

import json

import numpy as np

from pipeline.stages.common import (
    TRACING_KEYS,
    antenna_tilts,
    link_budget,
    load_scene,
    read_reads,
    resolve_cache_dir,
    sample_poses,
    select_backend,
    trace_options,
)
from pipeline.study import Stage

__all__ = ["STAGE", "pose_miss_probability", "stage_truth"]


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
    reads, _ = read_reads(ctx)
    eval_reads, _ = read_reads(ctx, "eval_")
    grid = CellGrid(d_max_m=cfg.training.d_max_m, d_bin_m=cfg.training.d_bin_m,
                    alpha_bin_deg=cfg.training.alpha_bin_deg)
    # the training truth is what a floor may be fitted on; the held-out one is scored on
    truth = detection_truth(reads, budget, grid=grid,
                            miss_probability=_miss_probability(cfg, reads, budget))
    truth.save(ctx.out("truth/detection_grid.npz"))
    eval_truth = detection_truth(eval_reads, budget, grid=grid,
                                 miss_probability=_miss_probability(cfg, eval_reads, budget))
    eval_truth.save(ctx.out("truth/detection_grid_eval.npz"))
    info = {"cells_with_attempts": int((truth.n_attempts > 0).sum()),
            "eval_cells_with_attempts": int((eval_truth.n_attempts > 0).sum())}
    info.update(_trace_sites(ctx, eval_reads))
    info.update(_trace_free_space_view(ctx, eval_reads, budget))
    return info


def _miss_probability(cfg, reads, budget):
    """The truth's miss probability of a closing attempt of ``reads``: the constant of the
    ``"fixed"`` inventory (a float: the numbers of before), else one per row (Gen2,
    :func:`pipeline.acquisition.singulation.miss_probability_of_attempts`)."""
    from pipeline.acquisition.singulation import miss_probability_of_attempts

    if cfg.reader.inventory == "fixed":
        return cfg.reader.anticollision_miss_probability
    return miss_probability_of_attempts(reads, cfg.reader, budget,
                                        n_antennas=len(cfg.robot.antennas))


def pose_miss_probability(cfg, eval_reads, poses, budget):
    """Miss probability of a tag site or point (not in the log) at antenna ``poses`` taken
    from ``eval_reads``: the ``"fixed"`` constant (a float), or per pose (p,) for Gen2
    (:func:`pipeline.acquisition.singulation.miss_probability_at_poses`, the site joining
    the slot's closing tags)."""
    from pipeline.acquisition.singulation import miss_probability_at_poses

    if cfg.reader.inventory == "fixed":
        return cfg.reader.anticollision_miss_probability
    return miss_probability_at_poses(eval_reads, poses, cfg.reader, budget, extra_tags=1,
                                     n_antennas=len(cfg.robot.antennas))


def _trace_sites(ctx, eval_reads) -> dict:
    """Truth at every tag site within reach of evaluation-tour antenna poses
    (pipeline.evaluation.sites); writes truth/site_truth.npz."""
    import propagation
    from pipeline.evaluation.sites import SiteTruth, obstructed_pairs
    from scenes.tagsites import tag_sites

    cfg = ctx.config
    ev = cfg.evaluation
    sc = load_scene(ctx)
    poses = sample_poses(eval_reads, ev.n_site_poses, antenna_tilts(cfg))
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
    poses = sample_poses(eval_reads, ev.n_sample_poses, antenna_tilts(cfg))
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
        q = pose_miss_probability(cfg, eval_reads, pose[None], budget)
        rp = rho_points_truth(pose, pts, gain, budget, rssi_range,
                              miss_probability=q if np.ndim(q) == 0 else float(q[0]),
                              grid_shape=(len(d), len(a)))
        rp.save(ctx.out(f"truth/rho_points_{i:02d}.npz"))
        if i < ev.n_field_poses:
            field = propagation.rssi_field(
                sc, pose, frequency_hz=cfg.frequency_hz, cell_size_m=cfg.tracing.field_cell_m,
                plane_height_m=ev.field_height_m, samples_per_tx=cfg.tracing.field_samples_per_tx,
                max_depth=cfg.tracing.max_depth, reader_pattern=cfg.tracing.reader_pattern,
                reader_polarization=cfg.tracing.reader_polarization,
                include_walls=cfg.tracing.field_walls, plane_bounds_m=bounds, cache_dir=cache)
            field.save(ctx.out(f"fields/field_{i:02d}.npz"))
        update(advance=1)
    return {"n_sample_poses": int(len(poses)), "n_points_traced": n_free}


STAGE = Stage("truth", stage_truth,
              ("seed", "reader", "evaluation", "training.d_max_m", "training.d_bin_m",
               "training.alpha_bin_deg", "tracing.field_cell_m", "tracing.field_samples_per_tx",
               "tracing.field_walls")
              + TRACING_KEYS,
              ("scene", "reads", "models"), version=3,  # 2: held-out grid, tag sites, eval poses
              # 3: the Gen2 reader's miss probability from the tags in the field
              description="propagation truth")
