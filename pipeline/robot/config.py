"""The robot's configuration sections: its reader antennas' mounts (``[robot]``,
``[[robot.antennas]]``), beside the tour's (:mod:`.trajectory`) and localisation's
(:mod:`.simulate`)."""

from __future__ import annotations

import numpy as np

from pipeline.configschema import ConfigError, option, section
from pipeline.robot.kinematics import default_antennas

__all__ = ["AntennaMountConfig", "RobotConfig"]


@section
class AntennaMountConfig:
    """One reader antenna mounted on the robot (robot frame: x forward, y left, z up)."""

    name: str = option("antenna", "Antenna name (unique), used in tables and figures.")
    x_m: float = option(0.0, "Mount position along the robot's forward axis [m].")
    y_m: float = option(0.0, "Mount position along the robot's left axis [m].")
    z_m: float = option(0.6, "Mount height above the floor [m].")
    yaw_deg: float = option(0.0, "Boresight yaw relative to the robot heading, counter-clockwise [deg].")
    tilt_deg: float = option(0.0, "Boresight tilt (pitch), positive up [deg].")
    cable_loss_db: float = option(0.0, "Loss between the reader port and this antenna (cable, "
                                  "connectors) [dB]: one way, so twice in the backscatter RSSI.")

    def __post_init__(self):
        if not self.name:
            raise ConfigError("name must not be empty")
        if not self.z_m > 0:
            raise ConfigError(f"z_m must be > 0, got {self.z_m!r}")


def _default_antennas() -> tuple[AntennaMountConfig, ...]:
    # pipeline.robot.default_antennas(): the chapter's two panels at the front corners of
    # a mast 0.70 m above the floor, yawed +-45 deg (see that function for why)
    return tuple(
        AntennaMountConfig(name=m.name, x_m=m.x_m, y_m=m.y_m, z_m=m.z_m,
                           yaw_deg=float(np.rad2deg(m.yaw_rad)), tilt_deg=float(np.rad2deg(m.tilt_rad)))
        for m in default_antennas()
    )


@section
class RobotConfig:
    """The mobile robot (a Pioneer P3-AT, pipeline.robot.Robot) and its reader antennas."""

    antennas: tuple[AntennaMountConfig, ...] = option(
        doc="Reader antennas mounted on the robot ([[robot.antennas]] tables).",
        factory=_default_antennas, max=16)

    def __post_init__(self):
        if not self.antennas:
            raise ConfigError("robot.antennas must list at least one antenna")
        names = [a.name for a in self.antennas]
        if len(set(names)) != len(names):
            raise ConfigError(f"antenna names must be unique, got {names}")
