"""One call from a true trajectory to what the robot records: odometry, scans, MCL poses."""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from pipeline.configschema import from_dict
from pipeline.robot.kinematics import Robot
from pipeline.robot.laser import LaserScanner
from pipeline.robot.mcl import LocalizationResult, MCLConfig, run_mcl
from pipeline.robot.occupancy import OccupancyMap
from pipeline.robot.odometry import OdometryNoise, simulate_odometry
from pipeline.robot.robotmap import draw_robot_map
from pipeline.robot.trajectory import Trajectory
from scenes import floor_plan_segments

__all__ = ["LocalizationConfig", "laser_map", "simulate_localisation"]


@dataclass(frozen=True)
class LocalizationConfig:
    """Sensors and filter of a localisation run.

    Attributes
    ----------
    odometry_noise : OdometryNoise
        The robot's true odometry error (what the simulated wheels report).
    scanner : LaserScanner
        The laser scanner (SICK LMS-like defaults).
    mcl : MCLConfig
        Particle filter settings.
    map_resolution_m : float
        Cell size of the laser map / likelihood field [m].
    map_error_m : float
        Standard deviation of the signed offset of each wall line of the robot's map
        along its normal [m] (:func:`pipeline.robot.robotmap.draw_robot_map`): a real
        robot localises in a map whose walls are a few centimetres off (survey or SLAM
        error, as-built tolerances), which biases its poses near them. 0 = every wall
        where it is.
    map_scale_error : float
        Standard deviation of the fractional scale error of the map [1] (the map is the
        building scaled by ``1 + s`` about its centre); 0 = none.
    map_noise_m : float
        Standard deviation of a smooth random displacement of the map's likelihood field
        added on top of the wall offsets [m] (:meth:`OccupancyMap.with_surface_error`:
        unsigned, no systematic offset); 0 = none.
    map_noise_correlation_m : float
        Correlation length of that smooth displacement along the surfaces [m].
    """

    odometry_noise: OdometryNoise = field(default_factory=OdometryNoise)
    scanner: LaserScanner = field(default_factory=LaserScanner)
    mcl: MCLConfig = field(default_factory=MCLConfig)
    map_resolution_m: float = 0.05
    map_error_m: float = 0.02
    map_scale_error: float = 0.0
    map_noise_m: float = 0.0
    map_noise_correlation_m: float = 1.0

    def __post_init__(self) -> None:
        for k in ("map_error_m", "map_scale_error", "map_noise_m"):
            if not getattr(self, k) >= 0:
                raise ValueError(f"LocalizationConfig: {k}={getattr(self, k)} must be >= 0")
        for k in ("map_resolution_m", "map_noise_correlation_m"):
            if not getattr(self, k) > 0:
                raise ValueError(f"LocalizationConfig: {k}={getattr(self, k)} must be > 0")

    @classmethod
    def from_dict(cls, data: Mapping[str, Any], where: str = "") -> LocalizationConfig:
        """Build from a (TOML-like) mapping; nested tables for the sub-configs.

        Unknown keys and wrong types raise :class:`pipeline.configschema.ConfigError`
        (a ValueError) naming ``where``, the dotted key and the value
        (:func:`pipeline.configschema.from_dict`).
        """
        return from_dict(cls, dict(data), source=where or "<dict>")


def laser_map(scene, scanner: LaserScanner, resolution_m: float = 0.05, route_m=None):
    """Occupancy map and likelihood field cut at the scanner's height."""
    h = scanner.height_m
    return OccupancyMap.from_scene(scene, resolution_m, (h, h), n_slices=1, route_m=route_m)


def simulate_localisation(
    scene,
    robot: Robot,
    trajectory: Trajectory,
    rng: np.random.Generator,
    config: LocalizationConfig | None = None,
    occupancy_map: OccupancyMap | None = None,
) -> LocalizationResult:
    """Simulate odometry and laser scans along a true trajectory, then localise with MCL.

    The robot starts at the trajectory's first pose, which it knows (tracking), unless
    ``config.mcl.global_init``. The laser is simulated in the true scene; the filter
    localises in the robot's map: ``occupancy_map`` when given (used as it is: draw it
    once per building with :func:`pipeline.robot.robotmap.draw_robot_map` and pass it
    to every tour), otherwise one drawn here from ``config`` (its wall offsets,
    scale error and smooth noise). Independent random streams (``rng.spawn(4)``) drive
    the odometry noise, the laser noise, the particle filter and the map (the last one
    unused when a map is given), so changing one does not reshuffle the others.

    Parameters
    ----------
    scene : scenes.Scene
    robot : Robot
        (Unused by the sensors today; kept so antenna-aware sensors can be added.)
    trajectory : Trajectory
        True path, poses (n, 3) [x_m, y_m, theta_rad].
    rng : numpy.random.Generator
    config : LocalizationConfig, optional
    occupancy_map : OccupancyMap, optional
        The map MCL localises in, cut at the scanner's height.

    Returns
    -------
    LocalizationResult
        True, odometry and MCL poses with per-step errors.

    Raises
    ------
    ValueError
        When ``occupancy_map`` was not cut at the scanner's height.
    """
    cfg = LocalizationConfig() if config is None else config
    rng_odo, rng_laser, rng_mcl, rng_map = rng.spawn(4)
    if occupancy_map is None:
        lmap = draw_robot_map(scene, cfg, rng_map).occupancy_map
    else:
        z0, z1 = occupancy_map.z_range_m
        h = cfg.scanner.height_m
        if not z0 - 1e-6 <= h <= z1 + 1e-6:
            raise ValueError(
                f"simulate_localisation: the map was cut at z in {occupancy_map.z_range_m} m, "
                f"the laser scans at {h} m"
            )
        lmap = occupancy_map
    truth = np.asarray(trajectory.poses, dtype=float)
    odo = simulate_odometry(truth, cfg.odometry_noise, rng_odo)
    segments = floor_plan_segments(scene, cfg.scanner.height_m)
    scans = cfg.scanner.scan(segments, truth, rng_laser)
    start = None if cfg.mcl.global_init else truth[0]
    return run_mcl(
        lmap,
        cfg.scanner,
        odo,
        scans,
        start,
        rng_mcl,
        config=cfg.mcl,
        true_poses=truth,
        t_s=trajectory.t_s,
    )
