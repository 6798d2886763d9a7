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
        Standard deviation of the displacement of the robot's map surfaces relative to
        the world [m] (:meth:`OccupancyMap.with_surface_error`). A real robot localises
        in a map that differs from the building by a few centimetres (mapping error,
        furniture moved, tolerances); the 2 cm default brings the simulated MCL error
        to the few-centimetre level of a real laser-MCL robot. 0 = perfect map.
    map_error_correlation_m : float
        Correlation length of that displacement along the walls [m].
    """

    odometry_noise: OdometryNoise = field(default_factory=OdometryNoise)
    scanner: LaserScanner = field(default_factory=LaserScanner)
    mcl: MCLConfig = field(default_factory=MCLConfig)
    map_resolution_m: float = 0.05
    map_error_m: float = 0.02
    map_error_correlation_m: float = 1.0

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
) -> LocalizationResult:
    """Simulate odometry and laser scans along a true trajectory, then localise with MCL.

    The robot starts at the trajectory's first pose, which it knows (tracking), unless
    ``config.mcl.global_init``. The laser is simulated in the true scene; the filter
    localises in the map cut from the same meshes, with ``config.map_error_m`` of surface
    displacement. Independent random streams (``rng.spawn``) drive the odometry noise,
    the laser noise, the particle filter and the map error, so changing one does not
    reshuffle the others.

    Parameters
    ----------
    scene : scenes.Scene
    robot : Robot
        (Unused by the sensors today; kept so antenna-aware sensors can be added.)
    trajectory : Trajectory
        True path.
    rng : numpy.random.Generator
    config : LocalizationConfig, optional

    Returns
    -------
    LocalizationResult
        True, odometry and MCL poses with per-step errors.
    """
    cfg = LocalizationConfig() if config is None else config
    rng_odo, rng_laser, rng_mcl, rng_map = rng.spawn(4)
    truth = np.asarray(trajectory.poses, dtype=float)
    odo = simulate_odometry(truth, cfg.odometry_noise, rng_odo)
    segments = floor_plan_segments(scene, cfg.scanner.height_m)
    scans = cfg.scanner.scan(segments, truth, rng_laser)
    lmap = laser_map(scene, cfg.scanner, cfg.map_resolution_m).with_surface_error(
        rng_map, cfg.map_error_m, cfg.map_error_correlation_m
    )
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
