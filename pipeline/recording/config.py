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

__all__ = ["FORMATS", "RecordingConfig"]

#: Formats of a reads file (``"auto"``: told apart by the file's header).
FORMATS = ("auto", "sllurp", "impinj")


@section
class RecordingConfig:
    """A recording: the reader's log, the robot's poses, the tag layout (docs/recordings.md).

    Empty ``reads``: no recording, the study simulates its reads. The antenna mounts are
    the study's ``[[robot.antennas]]``; without ``poses`` they are absolute positions
    and orientations in the scene frame (fixed antennas: a portal, a survey grid)."""

    reads: str = option("", "The reader's log: a CSV file ('' = no recording, the reads are simulated).")
    format: str = option(
        "auto", "Format of `reads`: 'sllurp' (the CSV `sllurp log` writes), 'impinj' (an Impinj "
        "ItemTest / Octane-style CSV) or 'auto' (told apart by the header).")
    tags: str = option("", "Tag layout CSV: header epc,x_m,y_m,z_m with optional nx,ny,nz [m].")
    poses: str = option(
        "", "Robot poses CSV: header t_s,x_m,y_m,yaw_rad, the localisation's estimate in the "
        "scene frame ('' = fixed antennas: the mounts are absolute).")
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

    def __post_init__(self):
        if self.format not in FORMATS:
            raise ConfigError(f"recording.format must be one of {', '.join(FORMATS)}; "
                              f"got {self.format[:40]!r}")
        if self.reads and not self.tags:
            raise ConfigError("recording.tags: a recording needs its tag layout (a CSV with "
                              "header epc,x_m,y_m,z_m)")
        if not abs(self.time_offset_s) <= 86_400.0:  # NaN fails too
            raise ConfigError(f"recording.time_offset_s must be within a day, got {self.time_offset_s!r}")
        if not 0.0 < self.heldout_fraction < 1.0:
            raise ConfigError(f"recording.heldout_fraction must be in (0, 1), got "
                              f"{self.heldout_fraction!r}")
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
    (``rfidstudy run STUDY --recording PATH``): a folder names its ``reads.csv``, ``tags.csv``
    and (where present) ``poses.csv``, as ``rfidstudy export`` writes them; a file is the
    reads file itself (the tags and poses then come from the study's ``[recording]``).

    Raises
    ------
    ConfigError
        Nothing at ``path``, or a folder without ``reads.csv`` and ``tags.csv``.
    """
    import json

    p = Path(path).expanduser().resolve()
    if p.is_file():
        return [f"recording.reads={json.dumps(str(p))}"]
    if not p.is_dir():
        raise ConfigError(f"--recording {path}: no such file or folder")
    missing = [n for n in ("reads.csv", "tags.csv") if not (p / n).is_file()]
    if missing:
        raise ConfigError(f"--recording {path}: the folder has no {' or '.join(missing)} "
                          "(a recording folder holds reads.csv, tags.csv and poses.csv)")
    sets = [f"recording.reads={json.dumps(str(p / 'reads.csv'))}",
            f"recording.tags={json.dumps(str(p / 'tags.csv'))}"]
    if (p / "poses.csv").is_file():
        sets.append(f"recording.poses={json.dumps(str(p / 'poses.csv'))}")
    return sets
