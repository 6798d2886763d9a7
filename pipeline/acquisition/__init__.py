"""Reader simulation and the datasets it writes (reads, poses, training sets).

A robot tours a ray-traced scene; at every read cycle the active antenna tries to
read every tag on the channel of its regional hop sequence: the ray-traced one-way
channel at the true antenna pose goes through the backscatter link budget (with each
tag's own sensitivity, backscatter and mounting loss) and the inventory (a fixed miss
probability or, by default, the EPC Gen2 Q algorithm, whose true miss probability
``singulation.py`` tabulates against the tags in the field) to a read or a miss; reads carry RSSI with the
reader's noise and quantisation, the backscatter phase and the Doppler shift, and d and
alpha are recorded from both the true and the estimated (MCL) antenna poses. The training sets of the fuzzy sensor model are built from that log.
"""

from pipeline.acquisition.channels import REGIONS, ChannelPlan, RegionProfile, channel_plan
from pipeline.acquisition.config import ReaderConfig
from pipeline.acquisition.gen2 import Gen2Config, ReadRateCurve, read_rate_curve
from pipeline.acquisition.population import TagPopulation, draw_population
from pipeline.acquisition.reader import (
    ReadAttempts,
    ReaderResponse,
    in_range_mask,
    read_attempts,
    reader_response,
    reads_from_gains,
)
from pipeline.acquisition.readlog import (
    POSE_COLUMNS,
    READ_COLUMNS,
    ReadLog,
    read_table,
    write_table,
)
from pipeline.acquisition.simulate import simulate_reads
from pipeline.acquisition.singulation import (
    SingulationCurve,
    miss_probability_at_poses,
    miss_probability_of_attempts,
    p_singulated,
    singulation_curve,
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
    "REGIONS",
    "ChannelPlan",
    "Gen2Config",
    "PoseTrack",
    "ReadAttempts",
    "ReadLog",
    "ReaderConfig",
    "ReadRateCurve",
    "ReaderResponse",
    "RegionProfile",
    "SingulationCurve",
    "TagPopulation",
    "TrainingSet",
    "as_pose_track",
    "channel_plan",
    "draw_population",
    "in_range_mask",
    "interpolate_poses",
    "miss_probability_at_poses",
    "miss_probability_of_attempts",
    "p_singulated",
    "read_attempts",
    "read_rate_curve",
    "read_table",
    "reader_response",
    "reads_from_gains",
    "rssi_range_from_data",
    "simulate_reads",
    "singulation_curve",
    "ssm_samples",
    "tdm_samples",
    "write_table",
]
