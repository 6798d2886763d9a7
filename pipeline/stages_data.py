"""Study stages that produce data: scene summary, robot tours with MCL, reader logs.

Each ``stage_*`` function takes a :class:`pipeline.study.StageContext`, calls the
packages that do the work (``scenes``, ``pipeline.robot``, ``pipeline.acquisition``,
``propagation``) and writes its outputs through ``ctx.out``. Orchestration only.
"""

from __future__ import annotations

import logging
import os
import zlib
from pathlib import Path

import numpy as np

from pipeline.config import StudyConfig
from pipeline.runstore import atomic_write_json, save_npz

__all__ = [
    "build_reader",
    "build_robot",
    "link_budget",
    "load_scene",
    "resolve_cache_dir",
    "split_tags",
    "study_scene",
    "stage_reads",
    "stage_scene",
    "stage_tour",
    "stage_rng",
    "study_route",
    "trace_options",
]

log = logging.getLogger(__name__)

#: Grid of candidate sites the held-out tags are drawn from [m]: fine, so their positions
#: and heights are not those of any lattice the training tags or truth sites use.
_EVAL_TAG_SPACING_M = 0.1


def stage_rng(cfg: StudyConfig, stage: str) -> np.random.Generator:
    """The random generator of one stage: seeded by (study seed, crc32 of the stage name).

    Every stage draws from its own stream, so re-running one stage reproduces it
    bit for bit whatever ran before it.
    """
    return np.random.default_rng([int(cfg.seed), zlib.crc32(stage.encode())])


def resolve_cache_dir(cfg: StudyConfig) -> Path:
    """The shared propagation cache: tracing.cache_dir, $RFIDSTUDY_CACHE or ~/.cache/rfidstudy."""
    if cfg.tracing.cache_dir:
        return Path(cfg.tracing.cache_dir).expanduser().resolve()
    env = os.environ.get("RFIDSTUDY_CACHE")
    if env:
        return Path(env).expanduser().resolve()
    return (Path.home() / ".cache" / "rfidstudy").resolve()


def study_scene(cfg: StudyConfig):
    """The scene with the study's two tag layouts, and which tag belongs to which.

    The scene's own tags are the training layout; ``evaluation.n_eval_tags`` held-out
    tags are drawn on its walls, boxes and cabinets (:func:`scenes.tagsites.draw_tags`,
    stream ``stage_rng(cfg, "eval_tags")``), at least ``eval_tag_min_separation_m`` from
    every other tag and at heights in ``eval_tag_heights_m``, so the evaluation tour
    reads tags at positions and heights the training tour never read.

    Returns
    -------
    scene : scenes.Scene
        A copy whose ``tags`` are the training tags followed by the held-out ones.
    split : numpy.ndarray, shape (n_tags,), str
        ``"train"`` or ``"eval"`` per tag, in ``scene.tags`` order.
    """
    import dataclasses

    import scenes
    from scenes.scene import TagSet
    from scenes.tagsites import draw_tags, tag_sites

    sc = scenes.load(cfg.scene)
    ev = cfg.evaluation
    train = sc.tags
    sites = tag_sites(sc, spacing_m=_EVAL_TAG_SPACING_M, z_range_m=tuple(ev.eval_tag_heights_m))
    route = study_route(sc, cfg)
    if route is not None:  # only where the evaluation tour passes within the models' domain
        sites = sites.subset(_route_distance_m(sites.positions_m[:, :2], route) <= cfg.training.d_max_m)
    held = draw_tags(sites, ev.n_eval_tags, stage_rng(cfg, "eval_tags"), avoid_m=train.positions_m,
                     min_separation_m=ev.eval_tag_min_separation_m, prefix="E",
                     where=f"{sc.name}: evaluation.n_eval_tags = {ev.n_eval_tags}")
    clash = sorted(set(train.ids.tolist()) & set(held.ids.tolist()))
    if clash:
        raise ValueError(f"{sc.name}: held-out tag ids {clash} are already used by the scene's tags")
    tags = TagSet(np.concatenate([train.ids, held.ids]),
                  np.vstack([train.positions_m, held.positions_m]),
                  np.vstack([train.normals, held.normals]))
    split = np.array(["train"] * len(train) + ["eval"] * len(held))
    return dataclasses.replace(sc, tags=tags), split


def _route_distance_m(xy: np.ndarray, route: np.ndarray) -> np.ndarray:
    """Horizontal distance of points (k, 2) to a polyline (n, 2) [m]."""
    a, b = route[:-1], route[1:]
    ab = b - a
    t = np.einsum("kij,ij->ki", xy[:, None, :] - a[None], ab) / np.maximum(
        np.einsum("ij,ij->i", ab, ab), 1e-12)
    proj = a[None] + np.clip(t, 0.0, 1.0)[..., None] * ab[None]
    return np.min(np.linalg.norm(xy[:, None, :] - proj, axis=2), axis=1)


def load_scene(ctx):
    """The study's scene with both tag layouts (:func:`study_scene`), memoised per run."""
    sc = ctx.memo.get("scene")
    if sc is None:
        sc, split = study_scene(ctx.config)
        ctx.memo["scene"] = sc
        ctx.memo["tag_split"] = split
    return sc


def split_tags(ctx, which: str):
    """The tags of one layout (``"train"`` or ``"eval"``) of the study scene (a TagSet)."""
    sc = load_scene(ctx)
    return sc.tags.subset(ctx.memo["tag_split"] == which)


def study_route(scene, cfg: StudyConfig) -> np.ndarray | None:
    """The scene's route, cut to its first ``tour.max_length_m`` metres when set.

    Returns
    -------
    numpy.ndarray or None
        Polyline (k, 2) [m].
    """
    route = None if scene.route_m is None else np.asarray(scene.route_m, dtype=float)
    L = cfg.tour.max_length_m
    if route is None or L <= 0:
        return route
    seg = np.linalg.norm(np.diff(route, axis=0), axis=1)
    s = np.concatenate([[0.0], np.cumsum(seg)])
    if L >= s[-1]:
        return route
    k = int(np.searchsorted(s, L))
    t = (L - s[k - 1]) / seg[k - 1]
    end = route[k - 1] + t * (route[k] - route[k - 1])
    return np.vstack([route[:k], end[None]])


def build_robot(cfg: StudyConfig):
    """``pipeline.robot.Robot`` with the config's antenna mounts (degrees -> radians)."""
    from pipeline.robot import AntennaMount, Robot

    mounts = [
        AntennaMount(a.name, x_m=a.x_m, y_m=a.y_m, z_m=a.z_m, yaw_rad=float(np.deg2rad(a.yaw_deg)),
                     tilt_rad=float(np.deg2rad(a.tilt_deg)))
        for a in cfg.robot.antennas
    ]
    return Robot(antennas=mounts)


def link_budget(cfg: StudyConfig):
    """``propagation.LinkBudget`` from the [reader] section."""
    from propagation import LinkBudget

    r = cfg.reader
    return LinkBudget(frequency_hz=cfg.frequency_hz, tx_power_dbm=r.tx_power_dbm,
                      tag_sensitivity_dbm=r.tag_sensitivity_dbm,
                      reader_sensitivity_dbm=r.reader_sensitivity_dbm,
                      polarization_loss_db=r.polarization_loss_db,
                      modulation_loss_db=r.modulation_loss_db)


def build_reader(cfg: StudyConfig):
    """``pipeline.acquisition.ReaderConfig`` from the [reader] section."""
    from pipeline.acquisition import ReaderConfig

    r = cfg.reader
    return ReaderConfig(read_rate_hz=r.read_rate_hz, antenna_mode=r.antenna_mode,
                        rssi_noise_db=r.rssi_noise_db, rssi_resolution_db=r.rssi_resolution_db,
                        anticollision_miss_probability=r.anticollision_miss_probability,
                        budget=link_budget(cfg), range_margin_db=r.range_margin_db)


def trace_options(cfg: StudyConfig) -> dict:
    """Keyword arguments for ``propagation.trace_links`` from the [tracing] section."""
    t = cfg.tracing
    return {
        "max_depth": t.max_depth,
        "samples_per_src": t.samples_per_src,
        "reader_pattern": t.reader_pattern,
        "tag_pattern": t.tag_pattern,
        "reader_polarization": t.reader_polarization,
        "memory_budget_bytes": int(t.memory_budget_mb * 2**20),
    }


def select_backend(cfg: StudyConfig) -> str:
    """Select the Dr.Jit variant (``propagation.select_variant``) before any tracing."""
    import propagation

    variant = propagation.select_variant(prefer=cfg.tracing.backend)
    propagation.set_deterministic(cfg.tracing.deterministic)
    return variant


# ---------------------------------------------------------------------------------- stages
def stage_scene(ctx) -> dict:
    """Load the scene; write ``scene/scene.json``, ``scene/tags.parquet``, floor plan."""
    from pipeline.evaluation.tables import write_tags
    from scenes.geometry import floor_plan_segments

    sc = load_scene(ctx)
    cfg = ctx.config
    lo, hi = sc.bounds_m
    route = study_route(sc, cfg)
    summary = {
        "name": sc.name,
        "source": str(sc.source),
        "content_hash": sc.content_hash(),
        "bounds_m": [lo.tolist(), hi.tolist()],
        "materials": sc.materials,
        "n_tags": len(sc.tags),
        "n_tags_train": int(np.sum(ctx.memo["tag_split"] == "train")),
        "n_tags_eval": int(np.sum(ctx.memo["tag_split"] == "eval")),
        "route_m": None if route is None else np.round(route, 6).tolist(),
    }
    atomic_write_json(ctx.out("scene/scene.json"), summary)
    write_tags(ctx.out("scene/tags.parquet"), sc.tags.ids, sc.tags.positions_m, sc.tags.normals,
               split=ctx.memo["tag_split"])
    heights = sorted({0.35, 1.0})
    segs = {f"segments_z{int(h * 100):03d}cm": floor_plan_segments(sc, h) for h in heights}
    save_npz(ctx.out("scene/floorplan.npz"), heights_m=np.asarray(heights),
             route_m=np.zeros((0, 2)) if route is None else route, **segs)
    return {"scene": sc.name, "n_tags": len(sc.tags), "content_hash": summary["content_hash"][:16]}


def _localise(scene, robot, traj, lcfg, rng, progress, robot_map=None) -> dict:
    """Odometry, laser scans and MCL along a trajectory (pipeline.robot.simulate_localisation).

    ``lcfg`` is the ``pipeline.robot.LocalizationConfig`` (None: MCL off, the estimated
    poses are the true ones); ``robot_map`` the ``OccupancyMap`` MCL localises in, drawn
    once per building by :func:`stage_tour` (None: ``simulate_localisation`` draws one).
    """
    from pipeline.robot import simulate_localisation

    true = np.asarray(traj.poses, dtype=float)
    t = np.asarray(traj.t_s, dtype=float)
    if lcfg is None:
        return {"t_s": t, "true": true, "odom": true.copy(), "est": true.copy()}
    progress(completed=0.0, total=1.0)
    res = simulate_localisation(scene, robot, traj, rng, lcfg, occupancy_map=robot_map)
    progress(completed=1.0)
    return {"t_s": t, "true": true, "odom": np.asarray(res.odometry_poses),
            "est": np.asarray(res.estimated_poses),
            "position_error_m": np.asarray(res.position_error_m)}


def stage_tour(ctx) -> dict:
    """Drive the guided tour and the evaluation path, localise with MCL; write tour/*.

    The robot's map (its walls off by ``localisation.map_error_m``, its scale by
    ``localisation.map_scale_error``: :func:`pipeline.robot.draw_robot_map`) is drawn
    once, from its own stream ``stage_rng(cfg, "map")``, and both tours localise in it,
    as one robot in one building would. Writes ``tour/train_track.npz``,
    ``tour/eval_track.npz``, ``tour/map_error.npz`` (the wall lines ``segments``
    (k, 2, 2) [m], their ``normals``, ``offsets_m`` (k,) [m], ``scale``, ``centre_m``,
    ``displaced_segments``; empty when MCL is off) and ``tour/localisation.json``
    (per tour: MCL position error median/p90, heading error median and the mean
    signed pose offset in the robot and world frames,
    :func:`pipeline.evaluation.localisation.pose_error_summary`).

    Raises
    ------
    ValueError
        When MCL lost track on either tour: position error median over
        ``localisation.max_position_error_median_m`` or p90 over
        ``localisation.max_position_error_p90_m``; the message names the measured
        error and the map-error and filter keys to change. Nothing is written then.
    """
    from pipeline.evaluation.localisation import check_tracking, pose_error_summary
    from pipeline.robot import (
        LaserScanner,
        LocalizationConfig,
        MapError,
        MCLConfig,
        OdometryNoise,
        TourConfig,
        draw_robot_map,
        evaluation_path,
        guided_tour,
    )

    cfg = ctx.config
    loc = cfg.localisation
    sc = load_scene(ctx)
    robot = build_robot(cfg)
    route = study_route(sc, cfg)
    rng = stage_rng(cfg, "tour")
    t = cfg.tour
    tcfg = TourConfig(n_passes=t.n_passes, lane_fractions=tuple(t.lane_fractions),
                      lane_changes_per_pass=t.lane_changes_per_pass, stops_per_pass=t.stops_per_pass,
                      speed_m_per_s=t.speed_m_per_s, dt_s=t.dt_s)
    rng_eval = stage_rng(cfg, "eval_path")  # held out: its own seed stream
    lcfg = LocalizationConfig(
        odometry_noise=OdometryNoise(*loc.odometry_noise),
        scanner=LaserScanner(n_beams=loc.laser_beams, fov_rad=float(np.deg2rad(loc.laser_fov_deg)),
                             max_range_m=loc.laser_max_range_m, range_noise_m=loc.laser_noise_m),
        mcl=MCLConfig(n_particles=loc.n_particles, n_beams_used=loc.n_beams_used,
                      sigma_hit_m=loc.sigma_hit_m),
        map_resolution_m=loc.map_resolution_m,
        map_error_m=loc.map_error_m,
        map_scale_error=loc.map_scale_error,
        map_noise_m=loc.map_noise_m,
        map_noise_correlation_m=loc.map_noise_correlation_m,
    )
    if loc.enabled:  # one map of the building for both tours, from its own stream
        rmap = draw_robot_map(sc, lcfg, stage_rng(cfg, "map"))
        occ, map_error = rmap.occupancy_map, rmap.error
    else:
        occ = None
        map_error = MapError(np.zeros((0, 2, 2)), np.zeros((0, 2)), np.zeros(0), 0.0,
                             np.zeros(2), float(lcfg.scanner.height_m))
    causes = {f"localisation.{k}": getattr(loc, k) for k in
              ("map_error_m", "map_scale_error", "map_noise_m", "sigma_hit_m", "n_particles")}
    causes["largest drawn wall offset [m]"] = round(float(np.max(np.abs(map_error.offsets_m),
                                                                 initial=0.0)), 4)
    tracks, info, summaries = {}, {}, {}
    rng_train = rng
    for name, rng_s, make in (
        ("train", rng_train, lambda: guided_tour(sc, robot, rng_train, tcfg, route_m=route)),
        ("eval", rng_eval, lambda: evaluation_path(sc, robot, rng_eval, n_poses=t.n_eval_poses,
                                                   config=tcfg, route_m=route)),
    ):
        traj = make()
        track = _localise(sc, robot, traj, lcfg if loc.enabled else None, rng_s,
                          ctx.progress(f"{name} MCL", total=1.0), robot_map=occ)
        summary = pose_error_summary(track["true"], track["est"])
        check_tracking(summary, loc.max_position_error_median_m, loc.max_position_error_p90_m,
                       track=f"{name} tour", causes=causes,
                       median_key="localisation.max_position_error_median_m",
                       p90_key="localisation.max_position_error_p90_m")
        tracks[name] = track
        summaries[name] = summary.to_dict()
        err = track.get("position_error_m")
        info[name] = {
            "n_poses": int(len(track["t_s"])),
            "duration_s": float(track["t_s"][-1]),
            "mcl_position_error_m_median": None if err is None else float(np.median(err)),
            **summaries[name],
        }
    for name, track in tracks.items():
        save_npz(ctx.out(f"tour/{name}_track.npz"), **track)
    save_npz(ctx.out("tour/map_error.npz"), **map_error.to_arrays())
    atomic_write_json(ctx.out("tour/localisation.json"), summaries)
    info["map"] = {"n_walls": int(len(map_error.offsets_m)),
                   "offset_std_m": float(np.std(map_error.offsets_m)) if len(map_error.offsets_m)
                   else None,
                   "scale": float(map_error.scale)}
    return info


def _read_track(ctx, name: str):
    from pipeline.acquisition import PoseTrack

    path = ctx.input(f"tour/{name}_track.npz")
    try:
        with np.load(path) as z:
            return PoseTrack(t_s=z["t_s"], true_poses=z["true"], est_poses=z["est"],
                             odom_poses=z["odom"])
    except (OSError, KeyError, ValueError) as exc:
        raise ValueError(f"{path}: cannot read pose track ({exc}); delete it to re-run the tour") from None


def stage_reads(ctx) -> dict:
    """Simulate the reader along both tracks (ray-traced); write reads/poses Parquet files."""
    from pipeline.acquisition import simulate_reads

    cfg = ctx.config
    variant = select_backend(cfg)
    sc = load_scene(ctx)
    robot = build_robot(cfg)
    reader = build_reader(cfg)
    cache = resolve_cache_dir(cfg)
    cache.mkdir(parents=True, exist_ok=True)
    rng = stage_rng(cfg, "reads")
    info = {"variant": variant, "cache_dir": str(cache)}
    for name, prefix in (("train", ""), ("eval", "eval_")):
        track = _read_track(ctx, name)
        opts = trace_options(cfg)
        opts["progress"] = ctx.progress(f"tracing {name} links")
        # held out: the training tour reads only the training tags, the evaluation tour
        # only the held-out ones
        tags = split_tags(ctx, name)
        readlog = simulate_reads(sc, robot, track, reader, rng, trace=opts, cache_dir=cache,
                                 tags=tags)
        readlog.write(ctx.staging_dir, prefix=prefix)
        info[name] = {"n_attempts": readlog.n_attempts, "n_reads": readlog.n_reads,
                      "n_pairs_traced": readlog.metadata.get("n_pairs_traced")}
    return info
