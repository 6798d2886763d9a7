"""Stage ``tour``: the guided tour and the held-out evaluation path, odometry, laser and
MCL in one biased robot map per building (``pipeline.robot``); writes ``tour/``."""

from __future__ import annotations

import numpy as np

from pipeline import runfiles
from pipeline.acquisition import PoseTrack
from pipeline.engine.runstore import atomic_write_json, save_npz
from pipeline.engine.study import Stage
from pipeline.evaluation.localisation import check_tracking, pose_error_summary
from pipeline.parallel import map_forked
from pipeline.robot import (
    DriveProfile,
    MapError,
    collision_map,
    draw_robot_map,
    evaluation_path,
    guided_tour,
    simulate_localisation,
)
from pipeline.runfiles import STAGE_OUTPUTS
from pipeline.stages.common import load_scene
from pipeline.studyscene import build_robot, stage_rng, study_route

__all__ = ["STAGE", "eval_track", "stage_tour"]


def _localise(scene, robot, traj, lcfg, rng, robot_map=None) -> dict:
    """Odometry, laser scans and MCL along a trajectory (pipeline.robot.simulate_localisation).

    ``lcfg`` is the study's :class:`pipeline.robot.LocalisationConfig` (None: MCL off, the
    estimated poses are the true ones); ``robot_map`` the ``OccupancyMap`` MCL localises
    in, drawn once per building by :func:`stage_tour` (None: ``simulate_localisation``
    draws one).
    """
    true = np.asarray(traj.poses, dtype=float)
    t = np.asarray(traj.t_s, dtype=float)
    # which pass along the route each pose belongs to (-1 while turning around): the
    # placement study's inventory completeness is counted per pass
    passes = np.asarray(traj.pass_index, dtype=np.int64)
    if lcfg is None:
        return {"t_s": t, "true": true, "odom": true.copy(), "est": true.copy(),
                "pass_index": passes}
    res = simulate_localisation(scene, robot, traj, rng, lcfg, occupancy_map=robot_map)
    return {"t_s": t, "true": true, "odom": np.asarray(res.odometry_poses),
            "est": np.asarray(res.estimated_poses),
            "position_error_m": np.asarray(res.position_error_m), "pass_index": passes}


def _eval_path(sc, robot, cfg, rng):
    return evaluation_path(sc, robot, rng, n_poses=cfg.tour.n_eval_poses, config=cfg.tour,
                           route_m=study_route(sc, cfg))


def eval_track(ctx):
    """The evaluation path's true poses as :func:`stage_tour` drives it, without its MCL.

    The path is the first thing drawn from its stream ``stage_rng(cfg, "eval_path")``
    (the MCL along it draws next), so a stage that needs only the path's true poses
    (``truth_traces``) computes them here and need not wait for the tour's MCL: the same
    poses and times as ``tour/eval_track.npz`` (a test), the estimated poses set to the
    true ones.

    Returns
    -------
    pipeline.acquisition.PoseTrack
    """
    cfg = ctx.config
    traj = _eval_path(load_scene(ctx), build_robot(cfg), cfg, stage_rng(cfg, "eval_path"))
    true = np.asarray(traj.poses, dtype=float)
    return PoseTrack(t_s=np.asarray(traj.t_s, dtype=float), true_poses=true,
                     est_poses=true.copy(), odom_poses=np.full_like(true, np.nan))


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

    The ``[tour]`` and ``[localisation]`` sections are the robot package's own
    :class:`pipeline.robot.TourConfig` and :class:`pipeline.robot.LocalisationConfig`.

    Raises
    ------
    ValueError
        When MCL lost track on either tour: position error median over
        ``localisation.max_position_error_median_m`` or p90 over
        ``localisation.max_position_error_p90_m``; the message names the measured
        error and the map-error and filter keys to change. Nothing is written then.
    """
    cfg = ctx.config
    loc = cfg.localisation
    sc = load_scene(ctx)
    robot = build_robot(cfg)
    route = study_route(sc, cfg)
    rng = stage_rng(cfg, "tour")
    tcfg = cfg.tour
    rng_eval = stage_rng(cfg, "eval_path")  # held out: its own seed stream
    if loc.enabled:  # one map of the building for both tours, from its own stream
        rmap = draw_robot_map(sc, loc, stage_rng(cfg, "map"))
        occ, map_error = rmap.occupancy_map, rmap.error
    else:
        occ = None
        map_error = MapError(np.zeros((0, 2, 2)), np.zeros((0, 2)), np.zeros(0), 0.0,
                             np.zeros(2), float(loc.scanner.height_m))
    causes = {f"localisation.{k}": getattr(loc, k) for k in
              ("map_error_m", "map_scale_error", "map_noise_m", "sigma_hit_m", "n_particles")}
    causes["largest drawn wall offset [m]"] = round(float(np.max(np.abs(map_error.offsets_m),
                                                                 initial=0.0)), 4)
    tours = (
        ("train", rng, lambda: guided_tour(sc, robot, rng, tcfg, route_m=route)),
        ("eval", rng_eval, lambda: _eval_path(sc, robot, cfg, rng_eval)),  # as eval_track
    )

    def drive(i: int) -> dict:
        """One tour: its trajectory and MCL along it, from its own stream only (so the
        two tours run side by side, in forked processes, with the same numbers)."""
        _, rng_s, make = tours[i]
        return _localise(sc, robot, make(), loc if loc.enabled else None, rng_s, robot_map=occ)

    # both tours use the robot's collision map (memoised in this process): built here,
    # before the fork, the children share it and it outlives them (the downstream stage
    # finds it where the route is the scene's whole route, tour.max_length_m = 0)
    collision_map(sc, robot, DriveProfile().resolution_m, route)
    update = ctx.progress("train and eval tours (MCL)", total=len(tours))
    tracks, info, summaries = {}, {}, {}
    for (name, _, _), track in zip(tours, map_forked(drive, len(tours)), strict=True):
        update(advance=1)
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
        save_npz(ctx.out(runfiles.TRACK.format(tour=name)), **track)
    save_npz(ctx.out(runfiles.MAP_ERROR), **map_error.to_arrays())
    atomic_write_json(ctx.out(runfiles.LOCALISATION), summaries)
    info["map"] = {"n_walls": int(len(map_error.offsets_m)),
                   "offset_std_m": float(np.std(map_error.offsets_m)) if len(map_error.offsets_m)
                   else None,
                   "scale": float(map_error.scale)}
    return info


STAGE = Stage("tour", stage_tour, ("seed", "robot", "tour", "localisation"), ("scene",),
              version=3,  # each version's change: CHANGELOG.md
              description="robot tours and MCL",
              outputs=STAGE_OUTPUTS["tour"])
