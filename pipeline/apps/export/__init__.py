"""A finished study's training tour written as a recording (``rfidstudy export``).

The other direction of :mod:`pipeline.recording`: a run directory's reads, poses and tag
layout written in the layouts a recorded study reads, so that a simulated run can stand
in for a robot's logs (tests, benchmarks, the calibration twin).

- :mod:`.csv_export` - the sllurp-style CSV, the poses and the tag layout
  (:func:`export_csv`, and :func:`export_recording`, which picks the format);
- :mod:`.rosbag_export` - a ROS 2 bag, MCAP (:func:`export_mcap`);
- :mod:`.runtour` - what both read from the run directory and share.
"""

from pipeline.apps.export.csv_export import export_csv, export_recording
from pipeline.apps.export.rosbag_export import export_mcap

__all__ = ["export_csv", "export_mcap", "export_recording"]
