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
    "stage_reads",
    "stage_scene",
    "stage_tour",
    "stage_rng",
    "study_route",
    "trace_options",
]

log = logging.getLogger(__name__)


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


def load_scene(ctx):
    """The study's scene (loaded once per run, memoised in ``ctx.memo``)."""
    import scenes

    sc = ctx.memo.get("scene")
    if sc is None:
        sc = scenes.load(ctx.config.scene)
        ctx.memo["scene"] = sc
    return sc


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
        "route_m": None if route is None else np.round(route, 6).tolist(),
    }
    atomic_write_json(ctx.out("scene/scene.json"), summary)
    write_tags(ctx.out("scene/tags.parquet"), sc.tags.ids, sc.tags.positions_m, sc.tags.normals)
    heights = sorted({0.35, 1.0})
    segs = {f"segments_z{int(h * 100):03d}cm": floor_plan_segments(sc, h) for h in heights}
    save_npz(ctx.out("scene/floorplan.npz"), heights_m=np.asarray(heights),
             route_m=np.zeros((0, 2)) if route is None else route, **segs)
    return {"scene": sc.name, "n_tags": len(sc.tags), "content_hash": summary["content_hash"][:16]}


def _localise(scene, robot, traj, cfg: StudyConfig, rng, progress) -> dict:
    """Odometry, laser scans and MCL along a trajectory (pipeline.robot.simulate_localisation)."""
    from pipeline.robot import (
        LaserScanner,
        LocalizationConfig,
        MCLConfig,
        OdometryNoise,
        simulate_localisation,
    )

    loc = cfg.localisation
    true = np.asarray(traj.poses, dtype=float)
    t = np.asarray(traj.t_s, dtype=float)
    if not loc.enabled:
        return {"t_s": t, "true": true, "odom": true.copy(), "est": true.copy()}
    lcfg = LocalizationConfig(
        odometry_noise=OdometryNoise(*loc.odometry_noise),
        scanner=LaserScanner(n_beams=loc.laser_beams, fov_rad=float(np.deg2rad(loc.laser_fov_deg)),
                             max_range_m=loc.laser_max_range_m, range_noise_m=loc.laser_noise_m),
        mcl=MCLConfig(n_particles=loc.n_particles, n_beams_used=loc.n_beams_used,
                      sigma_hit_m=loc.sigma_hit_m),
        map_resolution_m=loc.map_resolution_m,
        map_error_m=loc.map_error_m,
        map_error_correlation_m=loc.map_error_correlation_m,
    )
    progress(completed=0.0, total=1.0)
    res = simulate_localisation(scene, robot, traj, rng, lcfg)
    progress(completed=1.0)
    return {"t_s": t, "true": true, "odom": np.asarray(res.odometry_poses),
            "est": np.asarray(res.estimated_poses),
            "position_error_m": np.asarray(res.position_error_m)}


def stage_tour(ctx) -> dict:
    """Drive the guided tour and the evaluation path, localise with MCL; write tour/*.npz."""
    from pipeline.robot import TourConfig, evaluation_path, guided_tour

    cfg = ctx.config
    sc = load_scene(ctx)
    robot = build_robot(cfg)
    route = study_route(sc, cfg)
    rng = stage_rng(cfg, "tour")
    t = cfg.tour
    tcfg = TourConfig(n_passes=t.n_passes, lane_fractions=tuple(t.lane_fractions),
                      lane_changes_per_pass=t.lane_changes_per_pass, stops_per_pass=t.stops_per_pass,
                      speed_m_per_s=t.speed_m_per_s, dt_s=t.dt_s)
    rng_eval = stage_rng(cfg, "eval_path")  # held out: its own seed stream
    info = {}
    rng_train = rng
    for name, rng_s, make in (
        ("train", rng_train, lambda: guided_tour(sc, robot, rng_train, tcfg, route_m=route)),
        ("eval", rng_eval, lambda: evaluation_path(sc, robot, rng_eval, n_poses=t.n_eval_poses,
                                                   config=tcfg, route_m=route)),
    ):
        traj = make()
        track = _localise(sc, robot, traj, cfg, rng_s, ctx.progress(f"{name} MCL", total=1.0))
        save_npz(ctx.out(f"tour/{name}_track.npz"), **track)
        err = track.get("position_error_m")
        info[name] = {
            "n_poses": int(len(track["t_s"])),
            "duration_s": float(track["t_s"][-1]),
            "mcl_position_error_m_median": None if err is None else float(np.median(err)),
        }
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
        readlog = simulate_reads(sc, robot, track, reader, rng, trace=opts, cache_dir=cache)
        readlog.write(ctx.staging_dir, prefix=prefix)
        info[name] = {"n_attempts": readlog.n_attempts, "n_reads": readlog.n_reads,
                      "n_pairs_traced": readlog.metadata.get("n_pairs_traced")}
    return info
