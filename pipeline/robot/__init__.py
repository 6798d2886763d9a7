"""Robot, trajectories, odometry, laser and Monte Carlo Localization.

A Pioneer-like differential-drive robot with reader antennas drives guided tours up
and down a corridor; its wheel odometry drifts, a 2-D laser scanner is ray-cast
against the scene, and a particle filter (MCL) estimates the pose a real robot would
record, in a map of the building whose walls are off by a few centimetres
(:mod:`pipeline.robot.robotmap`) (Thrun, Burgard & Fox, *Probabilistic Robotics*, 2005).
"""

from pipeline.robot.coverage import (
    CoverageRoute,
    SkippedFace,
    TagFace,
    plan_coverage_route,
    tag_faces,
)
from pipeline.robot.kinematics import (
    AntennaMount,
    Robot,
    antenna_poses,
    compose_poses,
    default_antennas,
    footprint_points,
    wrap_angle,
)
from pipeline.robot.laser import LaserScanner, ray_cast
from pipeline.robot.mcl import (
    LocalizationResult,
    MCLConfig,
    MonteCarloLocalization,
    PoseEstimate,
    low_variance_resample,
    run_mcl,
)
from pipeline.robot.occupancy import OccupancyMap
from pipeline.robot.odometry import (
    OdometryNoise,
    sample_motion_model_odometry,
    simulate_odometry,
)
from pipeline.robot.robotmap import (
    MapError,
    RobotMap,
    displace_wall_lines,
    draw_map_error,
    draw_robot_map,
    robot_map,
    wall_lines,
)
from pipeline.robot.simulate import LocalisationConfig, laser_map, simulate_localisation
from pipeline.robot.trajectory import (
    DriveProfile,
    TourConfig,
    Trajectory,
    check_trajectory,
    collision_map,
    evaluation_path,
    guided_tour,
)

__all__ = [
    "CoverageRoute",
    "TagFace",
    "plan_coverage_route",
    "SkippedFace",
    "tag_faces",
    "AntennaMount",
    "DriveProfile",
    "LaserScanner",
    "LocalisationConfig",
    "LocalizationResult",
    "MCLConfig",
    "MapError",
    "MonteCarloLocalization",
    "OccupancyMap",
    "OdometryNoise",
    "PoseEstimate",
    "Robot",
    "RobotMap",
    "TourConfig",
    "Trajectory",
    "antenna_poses",
    "check_trajectory",
    "collision_map",
    "compose_poses",
    "default_antennas",
    "displace_wall_lines",
    "draw_map_error",
    "draw_robot_map",
    "evaluation_path",
    "footprint_points",
    "guided_tour",
    "laser_map",
    "low_variance_resample",
    "ray_cast",
    "robot_map",
    "run_mcl",
    "sample_motion_model_odometry",
    "simulate_localisation",
    "simulate_odometry",
    "wall_lines",
    "wrap_angle",
]
