"""The robot: a Pioneer-like differential drive with reader antennas mounted on it.

Frames: the robot frame has its origin at the centre of rotation (the body centre,
on the floor), +x forward, +y to the left, z up. A robot pose is (x_m, y_m, theta_rad)
in the world frame. An antenna pose is (x, y, z, yaw, pitch, roll) in the world frame,
its boresight the antenna's local +x axis; pitch is the tilt (positive points the
boresight up), roll is always 0 here (see ``contracts.md``).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from fuzzymodel import wrap_angle  # re-exported: the one (-pi, pi] wrap

__all__ = [
    "AntennaMount",
    "Robot",
    "antenna_poses",
    "compose_poses",
    "default_antennas",
    "footprint_points",
    "mounts_to_array",
    "wrap_angle",
]


def compose_poses(base: np.ndarray, local: np.ndarray) -> np.ndarray:
    """Compose 2-D poses, ``base (+) local`` (SE(2) product).

    Parameters
    ----------
    base : numpy.ndarray
        Poses (..., 3) [x_m, y_m, theta_rad] in the world frame.
    local : numpy.ndarray
        Poses (..., 3) expressed in the ``base`` frame; broadcasts against ``base``.

    Returns
    -------
    numpy.ndarray
        World poses (..., 3), heading wrapped to (-pi, pi].
    """
    base = np.asarray(base, dtype=float)
    local = np.asarray(local, dtype=float)
    c, s = np.cos(base[..., 2]), np.sin(base[..., 2])
    x = base[..., 0] + c * local[..., 0] - s * local[..., 1]
    y = base[..., 1] + s * local[..., 0] + c * local[..., 1]
    return np.stack([x, y, wrap_angle(base[..., 2] + local[..., 2])], axis=-1)


@dataclass(frozen=True)
class AntennaMount:
    """Mounting pose of one reader antenna on the robot (robot frame).

    Attributes
    ----------
    name : str
        Antenna name (unique on a robot), e.g. ``"left"``; becomes the antenna id in the data.
    x_m, y_m : float
        Position of the antenna's phase centre in the robot frame [m] (+x forward, +y left).
    z_m : float
        Height of the phase centre above the floor [m].
    yaw_rad : float
        Boresight azimuth relative to the robot heading [rad] (positive = to the left).
    tilt_rad : float
        Boresight elevation [rad], positive up; becomes the antenna's pitch.
    cable_loss_db : float
        Loss between the reader port and the antenna [dB]: every link of this antenna is
        this much weaker one way (:func:`pipeline.acquisition.simulate_reads`).
    """

    name: str
    x_m: float
    y_m: float
    z_m: float
    yaw_rad: float
    tilt_rad: float = 0.0
    cable_loss_db: float = 0.0

    def __post_init__(self) -> None:
        vals = [self.x_m, self.y_m, self.z_m, self.yaw_rad, self.tilt_rad, self.cable_loss_db]
        if not np.all(np.isfinite(vals)):
            raise ValueError(f"AntennaMount {self.name!r}: non-finite value in {vals}")
        if abs(self.tilt_rad) > np.pi / 2:
            raise ValueError(
                f"AntennaMount {self.name!r}: tilt_rad={self.tilt_rad} outside [-pi/2, pi/2]"
            )


def default_antennas() -> list[AntennaMount]:
    """The two antennas of the chapter's robot, as modelled here.

    Both panels sit at the front corners of a mast above the P3AT deck, 0.70 m above
    the floor, one yawed +45 deg (front-left) and one -45 deg (front-right), no tilt.
    Why +-45 deg rather than +-90 deg: a robot touring a corridor with tags on both walls
    then sees every tag first ahead-sideways and keeps it in the main lobe while it passes,
    so one pass sweeps the bearing alpha over a wide range (the chapter's sensor model
    spans negative and positive alpha); this is also the classic two-antenna layout of
    Haehnel et al. (ICRA 2004, Pioneer with antennas at +-45 deg). Side-looking antennas
    (+-90 deg) would see each tag mostly at one bearing sign only. Change the mounts to
    study other layouts.
    """
    return [
        AntennaMount("left", x_m=0.20, y_m=0.15, z_m=0.70, yaw_rad=np.pi / 4),
        AntennaMount("right", x_m=0.20, y_m=-0.15, z_m=0.70, yaw_rad=-np.pi / 4),
    ]


@dataclass(frozen=True)
class Robot:
    """A skid-steer/differential-drive robot (defaults: Pioneer P3-AT) with reader antennas.

    The body is the box [-length/2, length/2] x [-width/2, width/2] x [0, body_height]
    in the robot frame. An antenna is "inside the body" when its phase centre lies
    strictly inside that box (inside the footprint and below the top of the body):
    a real antenna there would be shielded by the metal chassis, so it is rejected.
    Antennas above the deck (on a mast) or outside the footprint (on a bracket) are fine.

    Attributes
    ----------
    name : str
        Robot name.
    length_m, width_m : float
        Footprint along and across the heading [m] (P3-AT: 0.626 x 0.505 m).
    body_height_m : float
        Height of the top of the body above the floor [m] (P3-AT: 0.277 m).
    max_speed_m_per_s : float
        Translational speed limit [m/s] (P3-AT: 0.7 m/s).
    max_turn_rate_rad_per_s : float
        Turn-rate limit [rad/s] (P3-AT: 140 deg/s).
    max_accel_m_per_s2 : float
        Translational acceleration limit [m/s^2].
    max_turn_accel_rad_per_s2 : float
        Angular acceleration limit [rad/s^2].
    antennas : list[AntennaMount]
        Reader antennas; default :func:`default_antennas`.
    """

    name: str = "p3at"
    length_m: float = 0.626
    width_m: float = 0.505
    body_height_m: float = 0.277
    max_speed_m_per_s: float = 0.7
    max_turn_rate_rad_per_s: float = np.deg2rad(140.0)
    max_accel_m_per_s2: float = 0.5
    max_turn_accel_rad_per_s2: float = 1.5
    antennas: list[AntennaMount] = field(default_factory=default_antennas)

    def __post_init__(self) -> None:
        for key in (
            "length_m",
            "width_m",
            "body_height_m",
            "max_speed_m_per_s",
            "max_turn_rate_rad_per_s",
            "max_accel_m_per_s2",
            "max_turn_accel_rad_per_s2",
        ):
            v = getattr(self, key)
            if not (np.isfinite(v) and v > 0):
                raise ValueError(f"Robot {self.name!r}: {key}={v} must be finite and > 0")
        names = [a.name for a in self.antennas]
        if len(set(names)) != len(names):
            raise ValueError(f"Robot {self.name!r}: duplicate antenna names {names}")
        for a in self.antennas:
            if a.z_m <= 0.0:
                raise ValueError(
                    f"Robot {self.name!r}: antenna {a.name!r} at z_m={a.z_m} is not above the floor"
                )
            inside = (
                abs(a.x_m) < self.length_m / 2
                and abs(a.y_m) < self.width_m / 2
                and a.z_m < self.body_height_m
            )
            if inside:
                raise ValueError(
                    f"Robot {self.name!r}: antenna {a.name!r} at (x={a.x_m}, y={a.y_m}, "
                    f"z={a.z_m}) m is inside the body (footprint {self.length_m} x "
                    f"{self.width_m} m, top at {self.body_height_m} m); mount it above the "
                    "body top or outside the footprint"
                )

    @property
    def radius_m(self) -> float:
        """Circumscribed radius of the footprint [m]: the disc swept when turning in place."""
        return float(np.hypot(self.length_m / 2, self.width_m / 2))

    def mount_array(self) -> np.ndarray:
        """Antenna mounts as an array (n_antennas, 5) [x_m, y_m, z_m, yaw_rad, tilt_rad]."""
        return mounts_to_array(self.antennas)


def mounts_to_array(mounts: list[AntennaMount] | np.ndarray) -> np.ndarray:
    """Mounts as an array (n_antennas, 5) [x_m, y_m, z_m, yaw_rad, tilt_rad]."""
    if isinstance(mounts, np.ndarray):
        arr = np.asarray(mounts, dtype=float)
        if arr.ndim != 2 or arr.shape[1] not in (4, 5):
            raise ValueError(f"mounts array must be (n, 4) or (n, 5), got shape {arr.shape}")
        if arr.shape[1] == 4:
            arr = np.concatenate([arr, np.zeros((len(arr), 1))], axis=1)
        return arr
    return np.array([[m.x_m, m.y_m, m.z_m, m.yaw_rad, m.tilt_rad] for m in mounts], dtype=float)


def antenna_poses(robot_poses: np.ndarray, mounts: list[AntennaMount] | np.ndarray) -> np.ndarray:
    """World poses of every antenna at every robot pose.

    The antenna position is the robot pose composed with the mount position,
    ``p = (x, y) + R(theta) (x_m, y_m)``, ``z = z_m``; yaw = theta + yaw_mount (wrapped),
    pitch = tilt_mount, roll = 0.

    Parameters
    ----------
    robot_poses : numpy.ndarray
        Robot poses (n, 3) [x_m, y_m, theta_rad] (a single (3,) pose is accepted).
    mounts : list[AntennaMount] or numpy.ndarray
        Antenna mounts, or an array (n_antennas, 4|5) [x, y, z, yaw, (tilt)].

    Returns
    -------
    numpy.ndarray
        Antenna poses (n, n_antennas, 6) [x_m, y_m, z_m, yaw_rad, pitch_rad, roll_rad], float64.
    """
    poses = np.atleast_2d(np.asarray(robot_poses, dtype=float))
    if poses.shape[-1] != 3:
        raise ValueError(f"robot_poses must be (n, 3) [x, y, theta], got shape {poses.shape}")
    m = mounts_to_array(mounts)
    local = np.stack([m[:, 0], m[:, 1], m[:, 3]], axis=-1)  # (a, 3)
    planar = compose_poses(poses[:, None, :], local[None, :, :])  # (n, a, 3)
    n, a = planar.shape[:2]
    out = np.empty((n, a, 6))
    out[..., 0:2] = planar[..., 0:2]
    out[..., 2] = m[None, :, 2]
    out[..., 3] = planar[..., 2]
    out[..., 4] = m[None, :, 4]
    out[..., 5] = 0.0
    return out


def footprint_points(robot: Robot, poses: np.ndarray, spacing_m: float = 0.05) -> np.ndarray:
    """Points on the boundary and centre of the robot's footprint rectangle, in the world.

    Parameters
    ----------
    robot : Robot
    poses : numpy.ndarray
        Robot poses (n, 3).
    spacing_m : float
        Maximum spacing of the boundary samples [m].

    Returns
    -------
    numpy.ndarray
        World points (n, k, 2) [m].
    """
    hl, hw = robot.length_m / 2, robot.width_m / 2
    nx = max(2, int(np.ceil(robot.length_m / spacing_m)) + 1)
    ny = max(2, int(np.ceil(robot.width_m / spacing_m)) + 1)
    xs, ys = np.linspace(-hl, hl, nx), np.linspace(-hw, hw, ny)
    local = np.concatenate(
        [
            np.stack([xs, np.full(nx, hw)], 1),
            np.stack([xs, np.full(nx, -hw)], 1),
            np.stack([np.full(ny, hl), ys], 1),
            np.stack([np.full(ny, -hl), ys], 1),
            np.zeros((1, 2)),
        ]
    )
    poses = np.atleast_2d(np.asarray(poses, dtype=float))
    c, s = np.cos(poses[:, 2])[:, None], np.sin(poses[:, 2])[:, None]
    x = poses[:, 0:1] + c * local[None, :, 0] - s * local[None, :, 1]
    y = poses[:, 1:2] + s * local[None, :, 0] + c * local[None, :, 1]
    return np.stack([x, y], axis=-1)
