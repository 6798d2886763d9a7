"""Recordings: a real reader's log and a robot's poses read from files.

- :mod:`.csvformats` - the reads in the CSV layout ``sllurp log`` writes, the poses and
  the tag layout as plain CSV: readers that stop at the first bad row naming
  ``file:line`` and the column, writers, and the time alignment of reads with poses;
- :mod:`.impinj` - an Impinj reader's tag reports (raw LLRP / Impinj units or the Octane
  SDK's), converted to SI;
- :mod:`.load` - a ``[recording]``'s files read, checked and joined (:func:`load_recording`);
- :mod:`.attempts` - the read attempts rebuilt from a log of reads (the rule the
  detection model's counts rest on);
- :mod:`.config` - the ``[recording]`` section;
- :mod:`.rosbag` - a ROS 2 bag's reads and poses (:func:`read_rosbag`, with ``rosbags``:
  MCAP and sqlite3, no ROS install); the message type ``rfidstudy_msgs/msg/RfidRead``
  is ``rfidmsg/RfidRead.msg``.

The recorded study's stages are :mod:`pipeline.stages.recorded`,
:mod:`pipeline.stages.sim_vs_real`, :mod:`pipeline.stages.calibration` (:mod:`pipeline.evaluation.calibration`) and
:mod:`pipeline.stages.recorded_eval`. The other direction, a finished study's training
tour written as a recording (``rfidstudy export RUN --format csv|mcap --out DIR``), reads
a run directory, so it is an application: :mod:`pipeline.apps.export`.
"""

from pipeline.recording.attempts import recorded_read_table
from pipeline.recording.config import RecordingConfig, recording_overrides
from pipeline.recording.csvformats import (
    RecordingError,
    align_reads,
    read_poses_csv,
    read_sllurp_csv,
    read_tags_csv,
    write_poses_csv,
    write_sllurp_csv,
    write_tags_csv,
)
from pipeline.recording.impinj import read_impinj_csv, write_impinj_csv
from pipeline.recording.load import Recording, load_recording, recorded_tagset
from pipeline.recording.rosbag import read_rosbag

__all__ = [
    "Recording",
    "RecordingConfig",
    "RecordingError",
    "align_reads",
    "load_recording",
    "read_impinj_csv",
    "read_poses_csv",
    "read_rosbag",
    "read_sllurp_csv",
    "read_tags_csv",
    "recorded_read_table",
    "recorded_tagset",
    "recording_overrides",
    "write_impinj_csv",
    "write_poses_csv",
    "write_sllurp_csv",
    "write_tags_csv",
]
