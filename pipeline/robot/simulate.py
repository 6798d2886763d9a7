"""One call from a true trajectory to what the robot records: odometry, scans, MCL poses."""

from __future__ import annotations

import math

import numpy as np

from pipeline.configschema import ConfigError, option, section
from pipeline.robot.kinematics import Robot
from pipeline.robot.laser import LaserScanner
from pipeline.robot.mcl import LocalizationResult, MCLConfig, run_mcl
from pipeline.robot.occupancy import OccupancyMap
from pipeline.robot.odometry import OdometryNoise, simulate_odometry
from pipeline.robot.robotmap import draw_robot_map
from pipeline.robot.trajectory import Trajectory
from scenes import floor_plan_segments

__all__ = ["LocalisationConfig", "laser_map", "simulate_localisation"]


@section
class LocalisationConfig:
    """Odometry noise, the laser scanner and Monte Carlo Localization (pipeline.robot).

    The study's ``[localisation]`` section; what it configures is built from it:
    :attr:`odometry` (:class:`OdometryNoise`), :attr:`scanner` (:class:`LaserScanner`)
    and :attr:`mcl` (:class:`MCLConfig`). The defaults of the keys that configure those
    are theirs (one default per key); the rest of the filter and the scanner's mount keep
    their own defaults. The robot's map (:func:`pipeline.robot.robotmap.draw_robot_map`)
    is drawn from the ``map_*`` keys: a real robot localises in a map whose walls are a
    few centimetres off (survey or SLAM error, as-built tolerances), which biases its
    poses near them.
    """

    enabled: bool = option(True, "Run MCL; if false the estimated poses equal the true poses.")
    n_particles: int = option(MCLConfig.n_particles, "MCL particles.", max=1_000_000)
    n_beams_used: int = option(MCLConfig.n_beams_used, "Laser beams per scan used by the likelihood field.",
                               max=10_000)
    laser_beams: int = option(LaserScanner.n_beams, "Laser beams over the field of view (SICK LMS-200: 181).",
                              max=10_000)
    laser_fov_deg: float = option(math.degrees(LaserScanner.fov_rad), "Laser field of view [deg].")
    laser_max_range_m: float = option(LaserScanner.max_range_m, "Laser maximum range [m].")
    laser_noise_m: float = option(LaserScanner.range_noise_m, "Laser range noise standard deviation [m].")
    odometry_noise: tuple[float, ...] = option(
        (OdometryNoise.alpha1, OdometryNoise.alpha2, OdometryNoise.alpha3, OdometryNoise.alpha4),
        "Robot odometry noise alpha1..alpha4 (Thrun et al. 2005, Table 5.6).",
    )
    map_resolution_m: float = option(0.05, "Likelihood-field grid resolution [m].")
    map_error_m: float = option(
        0.05,
        "Std of the signed offset of each wall of the robot's map along its normal (one draw "
        "per wall line, once per building, shared by both tours; survey/SLAM error, as-built "
        "tolerances) [m]; 0 = every wall where it is.",
    )
    map_scale_error: float = option(
        0.0, "Std of the fractional scale error of the robot's map (scaled about the building's "
        "centre by 1 + s; 0.001 = 1 mm per metre) [1]; 0 = none.",
    )
    map_noise_m: float = option(
        0.0, "Std of a smooth, unsigned random displacement of the map's likelihood field on top "
        "of the wall offsets [m]; 0 = none.",
    )
    map_noise_correlation_m: float = option(
        1.0, "Correlation length of that smooth displacement along surfaces [m]."
    )
    sigma_hit_m: float = option(
        MCLConfig.sigma_hit_m,
        "Likelihood-field std of the MCL laser model [m]; keep it >= map_error_m (corridor_lab, "
        "per-wall offsets of 0.05 m std: MCL tracks at 0.05 and 0.10, position error median "
        "3-8 cm; at 0.2 m std the p90 reached 2-6 m on 2 of 3 maps).",
    )
    max_position_error_median_m: float = option(
        0.5, "The tour stage fails when the MCL position error median of either tour exceeds "
        "this (MCL lost track: lower the map error or widen sigma_hit_m) [m].",
    )
    max_position_error_p90_m: float = option(
        1.0, "The tour stage fails when the 90th percentile of the MCL position error of either "
        "tour exceeds this [m].",
    )

    def __post_init__(self):
        for k in ("n_particles", "n_beams_used", "laser_beams", "laser_fov_deg",
                  "laser_max_range_m", "map_resolution_m", "map_noise_correlation_m", "sigma_hit_m",
                  "max_position_error_median_m", "max_position_error_p90_m"):
            if not getattr(self, k) > 0:
                raise ConfigError(f"{k} must be > 0, got {getattr(self, k)!r}")
        for k in ("laser_noise_m", "map_error_m", "map_scale_error", "map_noise_m"):
            if not getattr(self, k) >= 0:
                raise ConfigError(f"{k} must be >= 0, got {getattr(self, k)!r}")
        if len(self.odometry_noise) != 4 or min(self.odometry_noise) < 0:
            raise ConfigError(f"odometry_noise must be 4 values >= 0, got {self.odometry_noise}")

    @property
    def odometry(self) -> OdometryNoise:
        """The robot's true odometry error (what the simulated wheels report)."""
        return OdometryNoise(*self.odometry_noise)

    @property
    def scanner(self) -> LaserScanner:
        """The laser scanner: ``laser_*`` keys, the SICK LMS mount of :class:`LaserScanner`."""
        return LaserScanner(n_beams=self.laser_beams, fov_rad=float(np.deg2rad(self.laser_fov_deg)),
                            max_range_m=self.laser_max_range_m, range_noise_m=self.laser_noise_m)

    @property
    def mcl(self) -> MCLConfig:
        """The particle filter: ``n_particles``, ``n_beams_used``, ``sigma_hit_m``; the rest
        :class:`MCLConfig`'s own settings."""
        return MCLConfig(n_particles=self.n_particles, n_beams_used=self.n_beams_used,
                         sigma_hit_m=self.sigma_hit_m)


def laser_map(scene, scanner: LaserScanner, resolution_m: float = 0.05, route_m=None):
    """Occupancy map and likelihood field cut at the scanner's height."""
    h = scanner.height_m
    return OccupancyMap.from_scene(scene, resolution_m, (h, h), n_slices=1, route_m=route_m)


def simulate_localisation(
    scene,
    robot: Robot,
    trajectory: Trajectory,
    rng: np.random.Generator,
    config: LocalisationConfig | None = None,
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
    config : LocalisationConfig, optional
        Odometry noise, scanner, filter and (without ``occupancy_map``) the map error;
        ``enabled`` and the tracking limits are the study stage's business.
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
    cfg = LocalisationConfig() if config is None else config
    scanner, mcl = cfg.scanner, cfg.mcl
    rng_odo, rng_laser, rng_mcl, rng_map = rng.spawn(4)
    if occupancy_map is None:
        lmap = draw_robot_map(scene, cfg, rng_map).occupancy_map
    else:
        z0, z1 = occupancy_map.z_range_m
        h = scanner.height_m
        if not z0 - 1e-6 <= h <= z1 + 1e-6:
            raise ValueError(
                f"simulate_localisation: the map was cut at z in {occupancy_map.z_range_m} m, "
                f"the laser scans at {h} m"
            )
        lmap = occupancy_map
    truth = np.asarray(trajectory.poses, dtype=float)
    odo = simulate_odometry(truth, cfg.odometry, rng_odo)
    segments = floor_plan_segments(scene, scanner.height_m)
    scans = scanner.scan(segments, truth, rng_laser)
    start = None if mcl.global_init else truth[0]
    return run_mcl(
        lmap,
        scanner,
        odo,
        scans,
        start,
        rng_mcl,
        config=mcl,
        true_poses=truth,
        t_s=trajectory.t_s,
    )
