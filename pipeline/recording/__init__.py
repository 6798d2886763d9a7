"""Recordings: a real reader's log and a robot's poses as files, in and out (issue 53).

- :mod:`.csvformats` - the reads in the CSV layout ``sllurp log`` writes, the poses and
  the tag layout as plain CSV: readers that stop at the first bad row naming
  ``file:line`` and the column, writers, and the time alignment of reads with poses;
- :mod:`.export` - a finished study's training tour written as such a recording
  (``rfidstudy export RUN --format csv --out DIR``).

What is not here yet (issue 53): the Impinj and ROS 2 bag formats, a ``[recording]``
section that runs the study on recorded reads, simulation against reality, calibration.
"""

from .csvformats import (
    RecordingError,
    align_reads,
    read_poses_csv,
    read_sllurp_csv,
    read_tags_csv,
    write_poses_csv,
    write_sllurp_csv,
    write_tags_csv,
)
from .export import export_csv

__all__ = [
    "RecordingError",
    "align_reads",
    "export_csv",
    "read_poses_csv",
    "read_sllurp_csv",
    "read_tags_csv",
    "write_poses_csv",
    "write_sllurp_csv",
    "write_tags_csv",
]
