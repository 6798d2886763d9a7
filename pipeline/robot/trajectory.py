"""Guided tours up and down a corridor, and the held-out evaluation path.

A tour follows the scene's route (``scene.route_m``, the corridor centre line) in
passes of alternating direction. Lanes are defined relative to the *feasible band*:
at every station along the route, the interval of lateral offsets where the robot's
turning disc (circumscribed radius + clearance) is free in the occupancy map. A lane
fraction -1 is the right edge of that band (looking along the route), +1 the left
edge, 0 its middle, so lanes bend around cabinets by themselves. Within a pass the
robot changes lane with cosine ramps, stops, and drives with trapezoidal speed
profiles; at the end of a pass it turns around in place. Every pose's rectangular
footprint is checked against the map (:func:`check_trajectory`).
"""

from __future__ import annotations

import logging
import threading
from dataclasses import dataclass

import numpy as np
from scipy import ndimage

from pipeline.configschema import ConfigError, option, section
from pipeline.robot.kinematics import Robot, footprint_points, wrap_angle
from pipeline.robot.occupancy import OccupancyMap, _densify, map_boundary_segments
from scenes.sources import traits_of

logger = logging.getLogger(__name__)

__all__ = ["held_out_lane", "DriveProfile", "TourConfig", "Trajectory", "check_trajectory",
           "collision_map", "evaluation_path", "guided_tour"]


@dataclass(frozen=True)
class Trajectory:
    """A timed robot path.

    Attributes
    ----------
    t_s : numpy.ndarray
        Time stamps (n,) [s], increasing from 0.
    poses : numpy.ndarray
        True robot poses (n, 3) [x_m, y_m, theta_rad], heading wrapped to (-pi, pi].
    v_m_per_s : numpy.ndarray
        Forward speed (n,) [m/s] held over [t_i, t_{i+1}) (last entry 0).
    w_rad_per_s : numpy.ndarray
        Turn rate (n,) [rad/s] held over [t_i, t_{i+1}) (last entry 0).
    pass_index : numpy.ndarray
        (n,) int: which pass along the route the pose belongs to, -1 while turning around.
    """

    t_s: np.ndarray
    poses: np.ndarray
    v_m_per_s: np.ndarray
    w_rad_per_s: np.ndarray
    pass_index: np.ndarray

    def __len__(self) -> int:
        return len(self.t_s)

    @property
    def length_m(self) -> float:
        """Distance driven [m]."""
        return float(np.sum(np.linalg.norm(np.diff(self.poses[:, :2], axis=0), axis=1)))

    @classmethod
    def from_poses(cls, t_s: np.ndarray, poses: np.ndarray, pass_index=None) -> Trajectory:
        """Build a trajectory from times (n,) and poses (n, 3); v and w by finite differences."""
        t = np.asarray(t_s, dtype=float)
        p = np.asarray(poses, dtype=float).copy()
        p[:, 2] = wrap_angle(p[:, 2])
        dt = np.diff(t)
        if np.any(dt <= 0):
            raise ValueError("Trajectory: t_s must be strictly increasing")
        v = np.append(np.linalg.norm(np.diff(p[:, :2], axis=0), axis=1) / dt, 0.0)
        w = np.append(wrap_angle(np.diff(p[:, 2])) / dt, 0.0)
        pi = np.zeros(len(t), dtype=int) if pass_index is None else np.asarray(pass_index, int)
        return cls(t, p, v, w, pi)


@section
class TourConfig:
    """The guided training tour and the held-out evaluation path (pipeline.robot).

    The study's ``[tour]`` section, as :func:`guided_tour` and :func:`evaluation_path`
    take it. How the robot drives (ramps, accelerations, turn-arounds, stop length,
    clearance) is its :class:`DriveProfile`, not a study key.
    """

    n_passes: int = option(
        2, "Passes along the corridor route, alternating direction (2 = up and back; paper_scale: 9).", max=1_000)
    lane_fractions: tuple[float, ...] = option(
        (-0.6, 0.0, 0.6), "Lateral lanes as fractions of the free band, in [-1, 1] (0 = middle)."
    )
    lane_changes_per_pass: int = option(1, "Lane changes inside each pass.", max=1_000)
    stops_per_pass: int = option(1, "Stops inside each pass.", max=1_000)
    speed_m_per_s: float = option(0.3, "Cruise speed [m/s] (the chapter's robot: about 0.3 m/s).")
    dt_s: float = option(0.1, "Pose sampling period (one laser scan / MCL update per pose) [s].")
    max_length_m: float = option(
        0.0, "Drive only the first max_length_m metres of the scene's route (0 = whole route) [m]."
    )
    n_eval_poses: int = option(200, "Robot poses on the held-out evaluation path (chapter Fig. 7: 200).", max=100_000)
    eval_max_spacing_m: float = option(
        0.3, "Largest distance between evaluation poses [m]: a longer path gets more than n_eval_poses "
        "(MCL tracks between poses; on a 30 x 50 m map 200 poses are over 1 m apart and it loses "
        "track). 0 = n_eval_poses exactly.")

    def __post_init__(self):
        for k in ("n_passes", "speed_m_per_s", "dt_s", "n_eval_poses"):
            if not getattr(self, k) > 0:
                raise ConfigError(f"{k} must be > 0, got {getattr(self, k)!r}")
        for k in ("max_length_m", "lane_changes_per_pass", "stops_per_pass", "eval_max_spacing_m"):
            if not getattr(self, k) >= 0:
                raise ConfigError(f"{k} must be >= 0, got {getattr(self, k)!r}")
        if not self.lane_fractions or any(abs(f) > 1 for f in self.lane_fractions):
            raise ConfigError(f"lane_fractions must be non-empty and in [-1, 1], got {self.lane_fractions}")
        if self.n_eval_poses < 2:
            raise ConfigError(f"n_eval_poses must be >= 2, got {self.n_eval_poses}")

    def check_robot(self, robot: Robot, profile: DriveProfile | None = None) -> None:
        """Raise ValueError naming the key if the tour exceeds the robot's limits."""
        prof = DriveProfile() if profile is None else profile
        limits = {
            "speed_m_per_s": (self.speed_m_per_s, robot.max_speed_m_per_s),
            "accel_m_per_s2": (prof.accel_m_per_s2, robot.max_accel_m_per_s2),
            "turn_rate_rad_per_s": (prof.turn_rate_rad_per_s, robot.max_turn_rate_rad_per_s),
            "turn_accel_rad_per_s2": (prof.turn_accel_rad_per_s2, robot.max_turn_accel_rad_per_s2),
        }
        for k, (v, lim) in limits.items():
            if v > lim:
                raise ValueError(f"TourConfig: {k}={v} exceeds robot {robot.name!r} limit {lim}")


@dataclass(frozen=True)
class DriveProfile:
    """How the robot drives a tour (not study keys: the Pioneer's habits).

    Attributes
    ----------
    lane_change_length_m : float
        Length of the cosine ramp of a lane change [m]; also the smoothing length of the band.
    lane_jitter : float
        Uniform random jitter added to each lane fraction visit (fraction units).
    accel_m_per_s2 : float
        Acceleration and deceleration of the trapezoidal speed profile [m/s^2].
    turn_rate_rad_per_s : float
        Peak turn rate of the turn-arounds [rad/s].
    turn_accel_rad_per_s2 : float
        Angular acceleration of the turn-arounds [rad/s^2].
    stop_duration_s : float
        Duration of a stop [s].
    clearance_m : float
        Minimum clearance between the robot's turning disc and obstacles [m].
    resolution_m : float
        Cell size of the collision map [m].
    map_band_half_width_m : float
        On a map scene (``scenes.sources.SceneTraits.plans_route``) the route is where the robot
        drives: its lanes lie within this of it [m] (a corridor's centre line: up to 6 m).
    """

    lane_change_length_m: float = 2.0
    lane_jitter: float = 0.1
    accel_m_per_s2: float = 0.3
    turn_rate_rad_per_s: float = 0.6
    turn_accel_rad_per_s2: float = 1.0
    stop_duration_s: float = 2.0
    clearance_m: float = 0.10
    resolution_m: float = 0.05
    map_band_half_width_m: float = 0.3

    def __post_init__(self) -> None:
        for k in ("lane_change_length_m", "accel_m_per_s2", "turn_rate_rad_per_s",
                  "turn_accel_rad_per_s2", "resolution_m", "map_band_half_width_m"):
            if not getattr(self, k) > 0:
                raise ValueError(f"DriveProfile: {k}={getattr(self, k)} must be > 0")
        for k in ("stop_duration_s", "clearance_m", "lane_jitter"):
            if not getattr(self, k) >= 0:
                raise ValueError(f"DriveProfile: {k}={getattr(self, k)} must be >= 0")


#: The last few collision maps built, by (scene content, resolution, height, route): a
#: study asks for the same one for the tour and the evaluation path (~1.8 s each).
_COLLISION_MAPS: dict = {}
_COLLISION_MAPS_KEPT = 4
_COLLISION_MAPS_LOCK = threading.Lock()  # a Dask worker runs studies in threads


def collision_map(scene, robot: Robot, resolution_m: float = 0.05, route_m=None) -> OccupancyMap:
    """Occupancy map of everything the robot (body and antenna mast) could hit.

    For a map scene the building's edge (:func:`map_boundary_segments`) is an obstacle too.

    Slices from 5 cm above the floor up to 10 cm above the highest antenna or body top.
    The map is shared between calls with the same scene content and settings (its
    arrays are read-only).
    """
    top = max([robot.body_height_m] + [a.z_m for a in robot.antennas]) + 0.10
    # the content hash covers meshes, surfaces and tags; the route and name are added
    route = scene.route_m if route_m is None else route_m
    route = None if route is None else np.ascontiguousarray(route, dtype=np.float64)
    key = (scene.content_hash(), str(scene.name), np.asarray(scene.bounds_m, float).tobytes(),
           float(resolution_m), float(top), None if route is None else (route.shape, route.tobytes()))
    with _COLLISION_MAPS_LOCK:
        occ = _COLLISION_MAPS.get(key)
    if occ is None:
        occ = OccupancyMap.from_scene(scene, resolution_m, (0.05, top), n_slices=6, route_m=route_m,
                                      extra_segments=map_boundary_segments(scene))
        for arr in (occ.origin_m, occ.occupied, occ.distance_m, occ.boundary_distance_m):
            arr.flags.writeable = False
        with _COLLISION_MAPS_LOCK:
            while len(_COLLISION_MAPS) >= _COLLISION_MAPS_KEPT:
                _COLLISION_MAPS.pop(next(iter(_COLLISION_MAPS)), None)
            _COLLISION_MAPS[key] = occ
    return occ


def check_trajectory(
    scene_map: OccupancyMap, traj: Trajectory, robot: Robot, clearance_m: float = 0.0
) -> None:
    """Raise if any pose's footprint leaves free space.

    Parameters
    ----------
    scene_map : OccupancyMap
        Collision map (:func:`collision_map`).
    traj : Trajectory
    robot : Robot
        Its rectangular footprint is sampled at the map resolution.
    clearance_m : float
        Required clearance of every footprint point [m] (grid-accurate, about one cell).

    Raises
    ------
    ValueError
        Naming the first offending pose: index, time, x, y, theta and its clearance.
    """
    poses = np.asarray(traj.poses, dtype=float)
    bad_val = ~np.all(np.isfinite(poses), axis=1)
    if bad_val.any():
        i = int(np.argmax(bad_val))
        raise ValueError(f"trajectory pose {i} is not finite: {poses[i].tolist()}")
    pts = footprint_points(robot, poses, spacing_m=scene_map.resolution_m)
    c = scene_map.clearance_m(pts).min(axis=1)
    bad = c < clearance_m
    if bad.any():
        i = int(np.argmax(bad))
        x, y, th = poses[i]
        raise ValueError(
            f"trajectory leaves free space at pose {i} (t = {traj.t_s[i]:.2f} s): "
            f"x = {x:.3f} m, y = {y:.3f} m, theta = {th:.3f} rad; footprint clearance "
            f"{c[i]:.3f} m < required {clearance_m:.3f} m"
        )


# ----------------------------------------------------------------------------- geometry


@dataclass(frozen=True)
class _Band:
    """Route stations and the feasible lateral band at each."""

    s: np.ndarray  # (S,) station arc length [m]
    points: np.ndarray  # (S, 2)
    normals: np.ndarray  # (S, 2) unit, to the left of the route
    lo: np.ndarray  # (S,) smallest feasible offset [m]
    hi: np.ndarray  # (S,) largest feasible offset [m]
    i0: int  # first feasible station of the usable stretch
    i1: int  # last feasible station (inclusive)


def _route_band(scene, robot: Robot, cfg: DriveProfile, cmap: OccupancyMap, route_m) -> _Band:
    route = scene.route_m if route_m is None else route_m
    if route is None or len(route) < 2:
        raise ValueError(
            f"scene {scene.name!r} has no route_m (corridor centre line); pass route_m explicitly"
        )
    ds = cfg.resolution_m
    pts = _densify(np.asarray(route, dtype=float), ds / 2)
    # resample uniformly by arc length, round the corners (sigma 0.5 m), resample again
    for smooth in (True, False):
        seg = np.linalg.norm(np.diff(pts, axis=0), axis=1)
        keep = np.concatenate([[True], seg > 1e-12])
        pts = pts[keep]
        s = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(pts, axis=0), axis=1))])
        su = np.arange(0.0, s[-1] + 1e-9, ds)
        pts = np.stack([np.interp(su, s, pts[:, 0]), np.interp(su, s, pts[:, 1])], 1)
        if smooth and len(pts) > 3:
            pts = ndimage.gaussian_filter1d(pts, 0.5 / ds, axis=0, mode="nearest")
    s = np.arange(len(pts)) * ds
    tan = np.gradient(pts, axis=0)
    tan /= np.linalg.norm(tan, axis=1, keepdims=True)
    normals = np.stack([-tan[:, 1], tan[:, 0]], 1)
    half = cfg.map_band_half_width_m if traits_of(scene).plans_route else 6.0
    q = np.arange(-half, half + 1e-9, ds)
    cand = pts[:, None, :] + q[None, :, None] * normals[:, None, :]
    ok = cmap.clearance_m(cand) >= robot.radius_m + cfg.clearance_m
    lo = np.full(len(s), np.nan)
    hi = np.full(len(s), np.nan)
    for i in np.nonzero(ok.any(axis=1))[0]:
        lab, _ = ndimage.label(ok[i])
        j = int(np.argmin(np.where(ok[i], np.abs(q), np.inf)))  # feasible offset nearest 0
        idx = np.nonzero(lab == lab[j])[0]
        lo[i], hi[i] = q[idx[0]], q[idx[-1]]
    feas = np.isfinite(lo)
    if not feas.any():
        raise ValueError(
            f"scene {scene.name!r}: robot {robot.name!r} (radius {robot.radius_m:.3f} m + "
            f"clearance {cfg.clearance_m} m) fits nowhere along the route"
        )
    lab, n = ndimage.label(feas)
    sizes = ndimage.sum_labels(feas, lab, np.arange(1, n + 1))
    run = np.nonzero(lab == int(np.argmax(sizes)) + 1)[0]
    i0, i1 = int(run[0]), int(run[-1])
    if s[i1] - s[i0] < 0.5:
        raise ValueError(
            f"scene {scene.name!r}: usable stretch of the route is only {s[i1] - s[i0]:.2f} m "
            "(need >= 0.5 m where the robot's turning disc fits)"
        )
    # conservative smooth band: erode (max of lo / min of hi over a window), then smooth
    w = max(3, int(round(cfg.lane_change_length_m / ds)))
    lo_c, hi_c = lo.copy(), hi.copy()
    lo_c[~feas], hi_c[~feas] = np.nanmax(lo), np.nanmin(hi)
    lo_s = ndimage.maximum_filter1d(lo_c, w, mode="nearest")
    hi_s = ndimage.minimum_filter1d(hi_c, w, mode="nearest")
    lo_s = ndimage.maximum_filter1d(ndimage.gaussian_filter1d(lo_s, w / 6), w // 2)
    hi_s = ndimage.minimum_filter1d(ndimage.gaussian_filter1d(hi_s, w / 6), w // 2)
    lo_s, hi_s = np.maximum(lo_s, lo_c), np.minimum(hi_s, hi_c)
    mid = (lo_s + hi_s) / 2
    lo_s, hi_s = np.minimum(lo_s, mid), np.maximum(hi_s, mid)
    return _Band(s, pts, normals, lo_s, hi_s, i0, i1)


def _lane_profile(n_st: int, changes, lanes, ramp: int) -> np.ndarray:
    """Lane fraction per station: piecewise constant with cosine ramps at ``changes``."""
    f = np.full(n_st, lanes[0], dtype=float)
    k = np.arange(n_st)
    for c, a, b in zip(changes, lanes[:-1], lanes[1:], strict=True):
        x = np.clip((k - (c - ramp / 2)) / ramp, 0.0, 1.0)
        blend = 0.5 - 0.5 * np.cos(np.pi * x)
        f = np.where(k >= c - ramp / 2, a + (b - a) * blend, f)
    return f


def _change_stations(n_changes: int, n_st: int, ramp: int, rng) -> np.ndarray:
    """Stations (travel order) of lane changes, a ramp away from the ends and each other."""
    lo, hi = ramp, n_st - 1 - ramp
    if n_changes == 0 or hi - lo < n_changes * ramp:
        return np.zeros(0)
    edges = np.linspace(lo, hi, n_changes + 1)
    a, b = edges[:-1] + ramp / 2, edges[1:] - ramp / 2
    return np.where(b > a, rng.uniform(a, np.maximum(b, a)), (edges[:-1] + edges[1:]) / 2)


# ----------------------------------------------------------------------------- timing


def _trapezoid(distance: float, vmax: float, amax: float):
    """Duration and position function of a rest-to-rest trapezoidal profile."""
    distance = max(float(distance), 0.0)
    if distance <= vmax**2 / amax:
        ta = np.sqrt(distance / amax)
        tc = 0.0
        vp = amax * ta
    else:
        ta, vp = vmax / amax, vmax
        tc = (distance - vp * ta) / vmax
    total = 2 * ta + tc

    def pos(tau):
        tau = np.clip(tau, 0.0, total)
        return np.where(
            tau < ta,
            0.5 * amax * tau**2,
            np.where(
                tau < ta + tc,
                0.5 * amax * ta**2 + vp * (tau - ta),
                distance - 0.5 * amax * (total - tau) ** 2,
            ),
        )

    return total, pos


def _drive(path: np.ndarray, cfg: TourConfig, prof: DriveProfile):
    """Primitive: drive along path (k, 2) with heading from its tangent."""
    sig = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(path, axis=0), axis=1))])
    tan = np.gradient(path, axis=0)
    th = np.unwrap(np.arctan2(tan[:, 1], tan[:, 0]))
    total, pos = _trapezoid(sig[-1], cfg.speed_m_per_s, prof.accel_m_per_s2)

    def at(tau):
        p = pos(tau)
        return np.stack(
            [np.interp(p, sig, path[:, 0]), np.interp(p, sig, path[:, 1]), np.interp(p, sig, th)], 1
        )

    return total, at


def _turn(pose: np.ndarray, dtheta: float, prof: DriveProfile):
    total, pos = _trapezoid(abs(dtheta), prof.turn_rate_rad_per_s, prof.turn_accel_rad_per_s2)

    def at(tau):
        a = pose[2] + np.sign(dtheta) * pos(tau)
        return np.stack([np.full_like(a, pose[0]), np.full_like(a, pose[1]), a], 1)

    return total, at


def _wait(pose: np.ndarray, duration: float):
    return duration, lambda tau: np.repeat(pose[None, :], len(np.atleast_1d(tau)), axis=0)


def _sample(prims, times: np.ndarray) -> Trajectory:
    """Evaluate the primitive list (duration, at, pass) at ``times``."""
    starts = np.concatenate([[0.0], np.cumsum([p[0] for p in prims])])
    idx = np.clip(np.searchsorted(starts, times, side="right") - 1, 0, len(prims) - 1)
    poses = np.empty((len(times), 3))
    pidx = np.empty(len(times), dtype=int)
    for k, (_dur, at, pas) in enumerate(prims):
        sel = idx == k
        if sel.any():
            poses[sel] = at(times[sel] - starts[k])
            pidx[sel] = pas
    return Trajectory.from_poses(times, poses, pidx)


def _pass_path(band: _Band, frac: np.ndarray, forward: bool) -> np.ndarray:
    i0, i1 = band.i0, band.i1
    sl = slice(i0, i1 + 1)
    mid = (band.lo[sl] + band.hi[sl]) / 2
    half = (band.hi[sl] - band.lo[sl]) / 2
    path = band.points[sl] + (mid + frac * half)[:, None] * band.normals[sl]
    return path if forward else path[::-1]


def guided_tour(
    scene,
    robot: Robot,
    rng: np.random.Generator,
    config: TourConfig | None = None,
    route_m: np.ndarray | None = None,
    profile: DriveProfile | None = None,
) -> Trajectory:
    """A guided tour up and down the corridor along the scene's route.

    Parameters
    ----------
    scene : scenes.Scene
        Scene with ``route_m`` (or pass ``route_m``).
    robot : Robot
    rng : numpy.random.Generator
        Draws lane order, lane-change and stop places, lane jitter.
    config : TourConfig, optional
        Passes, lanes, lane changes, stops, speed and sampling period (the study's
        ``[tour]``; ``max_length_m`` and ``n_eval_poses`` are not used here).
    route_m : numpy.ndarray, optional
        Route polyline (k, 2) overriding ``scene.route_m``.
    profile : DriveProfile, optional
        How the robot drives (default :class:`DriveProfile`).

    Returns
    -------
    Trajectory
        Sampled every ``config.dt_s``; starts at rest at the route's start, facing along it.

    Raises
    ------
    ValueError
        Tour faster than the robot allows, no route, no room for the robot, or (should
        the construction fail) a pose leaving free space.
    """
    cfg = TourConfig() if config is None else config
    prof = DriveProfile() if profile is None else profile
    cfg.check_robot(robot, prof)
    cmap = collision_map(scene, robot, prof.resolution_m, route_m)
    band = _route_band(scene, robot, prof, cmap, route_m)
    n_st = band.i1 - band.i0 + 1
    ramp = max(2, int(round(prof.lane_change_length_m / prof.resolution_m)))
    lanes = np.asarray(cfg.lane_fractions, dtype=float)
    lane = int(rng.integers(len(lanes)))
    last_val = None
    prims = []
    for k in range(cfg.n_passes):
        forward = k % 2 == 0
        seq = [lane]
        for _ in range(cfg.lane_changes_per_pass):
            choices = [i for i in range(len(lanes)) if i != seq[-1]] or [seq[-1]]
            seq.append(int(rng.choice(choices)))
        lane = seq[-1]
        jitter = rng.uniform(-prof.lane_jitter, prof.lane_jitter, len(seq))
        vals = np.clip(lanes[seq] + jitter, -1, 1)
        if last_val is not None:
            vals[0] = last_val  # continuity with where the previous pass ended
        ch = _change_stations(len(seq) - 1, n_st, ramp, rng)
        vals = vals[: len(ch) + 1]
        last_val = vals[-1]
        frac_travel = _lane_profile(n_st, ch, vals, ramp)
        frac = frac_travel if forward else frac_travel[::-1]
        path = _pass_path(band, frac, forward)
        sig = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(path, axis=0), axis=1))])
        stops = np.sort(rng.uniform(0.2, 0.8, cfg.stops_per_pass)) * sig[-1]
        cuts = [0] + [int(np.searchsorted(sig, st)) for st in stops] + [len(path) - 1]
        for j, (a, b) in enumerate(zip(cuts[:-1], cuts[1:], strict=True)):
            if b - a < 2:
                continue
            dur, at = _drive(path[a : b + 1], cfg, prof)
            prims.append((dur, at, k))
            if j < len(cuts) - 2:
                prims.append((*_wait(at(np.array([dur]))[0], prof.stop_duration_s), k))
        if k < cfg.n_passes - 1:
            end = prims[-1][1](np.array([prims[-1][0]]))[0]
            prims.append((*_turn(end, np.pi if k % 2 == 0 else -np.pi, prof), -1))
    total = sum(p[0] for p in prims)
    times = np.arange(0.0, total + 1e-9, cfg.dt_s)
    traj = _sample(prims, times)
    check_trajectory(cmap, traj, robot, clearance_m=prof.clearance_m - cmap.resolution_m)
    return traj


def held_out_lane(lane_fractions, rng: np.random.Generator) -> float:
    """A lane fraction no tour lane uses: the middle of the widest gap between lanes.

    The band edges -1 and +1 count as lanes (the robot cannot drive beyond them);
    ties (e.g. -0.3 and +0.3 for lanes -0.6, 0, 0.6) are broken with ``rng``.
    """
    lanes = np.unique(np.concatenate([[-1.0, 1.0], np.asarray(lane_fractions, float)]))
    gaps = np.diff(lanes)
    best = np.flatnonzero(np.isclose(gaps, gaps.max()))
    i = int(best[rng.integers(len(best))])
    return float(0.5 * (lanes[i] + lanes[i + 1]))


def evaluation_path(
    scene,
    robot: Robot,
    rng: np.random.Generator,
    n_poses: int | None = None,
    lane_fraction: float | None = None,
    config: TourConfig | None = None,
    route_m: np.ndarray | None = None,
    profile: DriveProfile | None = None,
) -> Trajectory:
    """The held-out evaluation path: one pass in a lane the tour does not use (chapter Fig. 7).

    Parameters
    ----------
    scene, robot, rng : see :func:`guided_tour`
    n_poses : int, optional
        Number of poses, equally spaced in time over the pass; default
        ``config.n_eval_poses`` (chapter: 200).
    lane_fraction : float, optional
        Lane fraction in [-1, 1]; default :func:`held_out_lane` of the tour's
        ``config.lane_fractions`` (+-0.3 for the default lanes -0.6, 0, 0.6).
    config : TourConfig, optional
        Speed, the tour's lanes (for the held-out lane) and ``n_eval_poses``; passes,
        lane changes and stops are ignored.
    route_m : numpy.ndarray, optional
        Route polyline (k, 2) overriding ``scene.route_m``.
    profile : DriveProfile, optional
        How the robot drives (default :class:`DriveProfile`).

    Returns
    -------
    Trajectory
        ``n_poses`` poses of one forward pass without stops or lane changes, or more where
        they would be over ``config.eval_max_spacing_m`` apart.
    """
    cfg = TourConfig() if config is None else config
    prof = DriveProfile() if profile is None else profile
    n_poses = cfg.n_eval_poses if n_poses is None else n_poses
    if int(n_poses) < 2:
        raise ValueError(f"evaluation_path: n_poses={n_poses} must be >= 2")
    cfg.check_robot(robot, prof)
    if lane_fraction is None:
        lane_fraction = held_out_lane(cfg.lane_fractions, rng)
    if abs(lane_fraction) > 1:
        raise ValueError(f"evaluation_path: lane_fraction={lane_fraction} outside [-1, 1]")
    cmap = collision_map(scene, robot, prof.resolution_m, route_m)
    band = _route_band(scene, robot, prof, cmap, route_m)
    n_st = band.i1 - band.i0 + 1
    path = _pass_path(band, np.full(n_st, lane_fraction), True)
    dur, at = _drive(path, cfg, prof)
    length = float(np.linalg.norm(np.diff(path, axis=0), axis=1).sum())
    need = int(np.ceil(length / cfg.eval_max_spacing_m)) + 1 if cfg.eval_max_spacing_m > 0 else 0
    if need > int(n_poses):  # a long path: poses no farther apart than the bound
        logger.info("evaluation path of %.0f m: %d poses, not n_eval_poses = %d (tour.eval_max_spacing_m "
                    "= %.2f m)", length, need, int(n_poses), cfg.eval_max_spacing_m)
        n_poses = min(need, 100_000)
    times = np.linspace(0.0, dur, int(n_poses))
    traj = _sample([(dur, at, 0)], times)
    check_trajectory(cmap, traj, robot, clearance_m=prof.clearance_m - cmap.resolution_m)
    return traj
