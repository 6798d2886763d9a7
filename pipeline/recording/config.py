"""The ``[recording]`` section: a real reader's log as the study's data source.

With ``reads`` set, ``rfidstudy run`` runs the recorded study
(:mod:`pipeline.recording.stages`): the tour and the reads come from the files named
here instead of the simulation; the building is the study's ``scene`` as always.
Relative paths resolve against the study TOML's folder.
"""

from __future__ import annotations

import dataclasses
from pathlib import Path

from pipeline.configschema import ConfigError, option, section

__all__ = ["CALIBRATION_FIELDS", "FORMATS", "RecordingConfig"]

#: Formats of a reads file (``"auto"``: a ROS 2 bag by its folder or suffix
#: (:func:`pipeline.recording.load.is_rosbag`), a CSV by its header).
FORMATS = ("auto", "sllurp", "impinj", "rosbag")
#: Fields only the calibration stage reads: the recording's import does not depend on them
#: (a changed one re-runs the calibration and what follows, not the import and the traces).
CALIBRATION_FIELDS = ("calibrate_constructions", "calibration_resamples")


@section
class RecordingConfig:
    """A recording: the reader's log, the robot's poses, the tag layout (docs/recordings.md).

    Empty ``reads``: no recording, the study simulates its reads. The antenna mounts are
    the study's ``[[robot.antennas]]``; without ``poses`` they are absolute positions
    and orientations in the scene frame (fixed antennas: a portal, a survey grid)."""

    reads: str = option(
        "", "The reader's log: a CSV file, or a ROS 2 bag (its folder, or one .mcap / .db3 "
        "file) ('' = no recording, the reads are simulated).")
    format: str = option(
        "auto", "Format of `reads`: 'sllurp' (the CSV `sllurp log` writes), 'impinj' (an Impinj "
        "ItemTest / Octane-style CSV), 'rosbag' (a ROS 2 bag: reads and poses from its topics) "
        "or 'auto' (a bag by its metadata.yaml or suffix, a CSV by its header).")
    tags: str = option("", "Tag layout CSV: header epc,x_m,y_m,z_m with optional nx,ny,nz [m].")
    poses: str = option(
        "", "Robot poses CSV: header t_s,x_m,y_m,yaw_rad, the localisation's estimate in the "
        "scene frame ('' = from the bag's pose_topic for a ROS 2 bag, else fixed antennas: "
        "the mounts are absolute). Set with a bag, it replaces the bag's poses.")
    reads_topic: str = option(
        "/rfid/reads", "A bag's topic of the reads: rfidstudy_msgs/msg/RfidRead, or "
        "std_msgs/msg/String with one JSON object per read (docs/recordings.md).")
    pose_topic: str = option(
        "/amcl_pose", "A bag's topic of the robot's pose in the map frame: "
        "geometry_msgs/msg/PoseWithCovarianceStamped, PoseStamped, nav_msgs/msg/Odometry, or "
        "'/tf' (the transforms map -> base_link, or map -> odom -> base_link); '' = no poses "
        "(fixed antennas).")
    region: str = option(
        "", "Channel plan the reader ran ('ETSI', 'FCC'): an Impinj channel index becomes its "
        "frequency by it ('' = reader.region).")
    antenna_ports: tuple[int, ...] = option(
        (), "Reader port (1-based) of each [[robot.antennas]] mount, in table order "
        "(empty = ports 1..N).", max=64)
    heldout_fraction: float = option(
        0.3, "Share of the recorded tags held out of training and scored on (drawn per tag "
        "from the study's seed).")
    time_offset_s: float = option(
        0.0, "Added to every read's time before it meets the poses [s]: a known offset "
        "between the reader's clock and the robot's (import.json's pose_lag estimates it).")
    max_tags: int = option(100_000, "Largest tag layout taken.", max=1_000_000)
    calibrate_constructions: int = option(
        2, "Constructions (radio materials) whose permittivity and conductivity the "
        "calibration fits: the N that carry most of the traced path power, metal left out "
        "(0: the reader's parameters only).", max=8)
    calibration_resamples: int = option(
        200, "Bootstrap resamples of the training tags behind each calibrated value's 95 % "
        "interval, each a whole refit: the calibration's time grows with them (0: no "
        "intervals).", max=100_000)

    def __post_init__(self):
        if self.format not in FORMATS:
            raise ConfigError(f"recording.format must be one of {', '.join(FORMATS)}; "
                              f"got {self.format[:40]!r}")
        if self.reads and not self.tags:
            raise ConfigError("recording.tags: a recording needs its tag layout (a CSV with "
                              "header epc,x_m,y_m,z_m)")
        if not abs(self.time_offset_s) <= 86_400.0:  # NaN fails too
            raise ConfigError(f"recording.time_offset_s must be within a day, got {self.time_offset_s!r}")
        if isinstance(self.calibrate_constructions, bool) or self.calibrate_constructions < 0:
            raise ConfigError(f"recording.calibrate_constructions must be 0 or more, got "
                              f"{self.calibrate_constructions!r}")
        if isinstance(self.calibration_resamples, bool) or self.calibration_resamples < 0:
            raise ConfigError(f"recording.calibration_resamples must be 0 or more, got "
                              f"{self.calibration_resamples!r}")
        if not 0.0 < self.heldout_fraction < 1.0:
            raise ConfigError(f"recording.heldout_fraction must be in (0, 1), got "
                              f"{self.heldout_fraction!r}")
        for key, topic in (("reads_topic", self.reads_topic), ("pose_topic", self.pose_topic)):
            if (topic or key == "reads_topic") and not topic.startswith("/"):
                raise ConfigError(f"recording.{key} must be a topic name with its leading '/' "
                                  f"(as a bag stores it), got {topic[:60]!r}")
        ports = list(self.antenna_ports)
        if any(isinstance(p, bool) or not 1 <= p <= 65535 for p in ports):
            raise ConfigError(f"recording.antenna_ports must be reader ports >= 1, got {ports}")
        if len(set(ports)) != len(ports):
            raise ConfigError(f"recording.antenna_ports lists a port twice: {ports}")

    @property
    def enabled(self) -> bool:
        """A recording is named: the study runs on it."""
        return bool(self.reads)

    def resolved(self, base_dir: Path) -> RecordingConfig:
        """This section with its relative paths made absolute against ``base_dir``."""
        def fix(p: str) -> str:
            return p if not p or Path(p).expanduser().is_absolute() else str((base_dir / p).resolve())

        return dataclasses.replace(self, reads=fix(self.reads), tags=fix(self.tags),
                                   poses=fix(self.poses))


def recording_overrides(path: str | Path) -> list[str]:
    """``--set`` overrides that make a study run on the recording at ``path``
    (``rfidstudy run STUDY --recording PATH``):

    - a folder with ``reads.csv`` and ``tags.csv`` (and, where present, ``poses.csv``),
      as ``rfidstudy export --format csv`` writes it;
    - a folder with a ROS 2 bag ``bag/`` and ``tags.csv``, as ``rfidstudy export --format
      mcap`` writes it; or a bag itself (a folder with ``metadata.yaml``), the tags then
      from a ``tags.csv`` next to it (in its parent folder) or the study's
      ``[recording]``. The reads and the poses then come from the bag's topics
      (``recording.reads_topic``, ``recording.pose_topic``);
    - a file: the reads file itself (a ``.mcap`` / ``.db3`` file is a bag); the tags and
      poses then come from the study's ``[recording]``.

    Raises
    ------
    ConfigError
        Nothing at ``path``, or a folder that is none of these.
    """
    import json

    def put(key: str, value) -> str:
        return f"recording.{key}={json.dumps(str(value))}"

    p = Path(path).expanduser().resolve()
    if p.is_file():
        return [put("reads", p)]
    if not p.is_dir():
        raise ConfigError(f"--recording {path}: no such file or folder")
    bag, tags = None, p / "tags.csv"
    if (p / "metadata.yaml").is_file():
        bag, tags = p, p.parent / "tags.csv"
    elif not (p / "reads.csv").is_file() and (p / "bag" / "metadata.yaml").is_file():
        bag = p / "bag"
    if bag is not None:  # the bag's poses, unless the study names a poses file
        return [put("reads", bag), put("format", "rosbag"),
                *([put("tags", tags)] if tags.is_file() else [])]
    missing = [n for n in ("reads.csv", "tags.csv") if not (p / n).is_file()]
    if missing:
        raise ConfigError(f"--recording {path}: the folder has no {' or '.join(missing)} "
                          "(a recording folder holds reads.csv, tags.csv and poses.csv, or a "
                          "ROS 2 bag folder bag/ and tags.csv)")
    sets = [put("reads", p / "reads.csv"), put("tags", p / "tags.csv")]
    if (p / "poses.csv").is_file():
        sets.append(put("poses", p / "poses.csv"))
    return sets
