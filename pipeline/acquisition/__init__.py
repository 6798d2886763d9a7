"""Reader simulation and the datasets it writes (reads, poses, training sets).

A robot tours a ray-traced scene; at every read cycle the active antenna tries to
read every tag: the ray-traced one-way gain at the true antenna pose goes through the
backscatter link budget to a read or a miss, reads carry RSSI with the reader's noise
and quantisation, and d and alpha are recorded from both the true and the estimated
(MCL) antenna poses. The training sets of the fuzzy sensor model are built from that log.
"""

from pipeline.acquisition.config import ReaderConfig
from pipeline.acquisition.reader import (
    ReadAttempts,
    ReaderResponse,
    in_range_mask,
    read_attempts,
    reader_response,
    reads_from_gains,
    simulate_reads,
)
from pipeline.acquisition.readlog import (
    POSE_COLUMNS,
    READ_COLUMNS,
    ReadLog,
    read_table,
    write_table,
)
from pipeline.acquisition.track import PoseTrack, as_pose_track, interpolate_poses
from pipeline.acquisition.training import (
    TrainingSet,
    rssi_range_from_data,
    ssm_samples,
    tdm_samples,
)

__all__ = [
    "POSE_COLUMNS",
    "READ_COLUMNS",
    "PoseTrack",
    "ReadAttempts",
    "ReadLog",
    "ReaderConfig",
    "ReaderResponse",
    "TrainingSet",
    "as_pose_track",
    "in_range_mask",
    "interpolate_poses",
    "read_attempts",
    "read_table",
    "reader_response",
    "reads_from_gains",
    "rssi_range_from_data",
    "simulate_reads",
    "ssm_samples",
    "tdm_samples",
    "write_table",
]
