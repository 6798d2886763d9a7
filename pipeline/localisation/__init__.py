"""Downstream localisation with each sensor model: tags from reads, the robot from tags.

* :mod:`.likelihood` - the read likelihood of a ``SensorLike`` model
  (:class:`ModelLikelihood`), vectorised over (slot, candidate) pairs, and
  :mod:`.oracle_likelihood` that of the propagation oracle given true gains
  (:class:`OracleLikelihood`);
* :mod:`.observations` - the read log as tags x attempt slots (:class:`Observations`);
* :mod:`.tags` - posteriors of tag positions over candidate sites, estimates and error
  summaries (:func:`localise_tags`, :func:`localisation_summary`);
* :mod:`.phase` - tag positions from the reads' backscatter phases, a synthetic-aperture
  estimator robust to the reader's pi ambiguity and unknown per-(antenna, channel, tag)
  offsets (:func:`localise_tags_phase`, :func:`phase_reads_from_table`);
* :mod:`.global_oracle` - the oracle over every candidate, a coarse-to-fine search that
  never looks at the truth (:func:`global_oracle`, the study's ``downstream.oracle``);
* :mod:`.oracle` - windows of candidates around given centres and the (slot, candidate)
  pairs to trace for them (:func:`oracle_plan`: a local oracle around known places);
* :mod:`.fading` - the reader's likelihood given a *local-mean* gain: Rician (Rayleigh by
  default) fading entering the RSSI twice (:class:`FadedLikelihood`, :class:`FadingModel`);
* :mod:`.robot_oracle` - the robot filter's oracle, a traced local-mean gain field over
  the free space (:func:`gain_field`, :class:`FieldLikelihood`);
* :mod:`.robot` - RFID-only robot localisation, a particle filter with global
  initialisation and random-particle injection (:func:`run_rfid_mcl`,
  :func:`filter_metrics`);
"""

from pipeline.localisation.fading import FadedLikelihood, FadingModel
from pipeline.localisation.global_oracle import GlobalOracle, OracleSearch, global_oracle
from pipeline.localisation.likelihood import (
    EPS,
    Z_CLIP,
    GaussianTerms,
    ModelLikelihood,
    OwnTerms,
    fit_far_detection,
    rssi_residual_std,
)
from pipeline.localisation.observations import (
    Observations,
    as_pose6,
    observations_from_reads,
    pair_geometry,
)
from pipeline.localisation.oracle import OraclePlan, oracle_plan
from pipeline.localisation.oracle_likelihood import OracleGains, OracleLikelihood
from pipeline.localisation.phase import (
    PhaseColumnsMissing,
    PhasePosteriors,
    PhaseReads,
    combine_posteriors,
    localise_tags_phase,
    phase_reads_from_table,
    simulate_phase_rad,
)
from pipeline.localisation.robot import (
    BoxFreeSpace,
    RfidMCLConfig,
    RfidMCLResult,
    RfidParticleFilter,
    as_free_space,
    filter_metrics,
    run_rfid_mcl,
)
from pipeline.localisation.robot_oracle import FieldLikelihood, GainField, gain_field
from pipeline.localisation.tags import (
    ESTIMATORS,
    TagPosteriors,
    as_tag_map,
    localisation_summary,
    localise_tags,
    read_region_mask,
    tag_position_errors,
)

__all__ = [
    "EPS",
    "ESTIMATORS",
    "Z_CLIP",
    "BoxFreeSpace",
    "FadedLikelihood",
    "FadingModel",
    "FieldLikelihood",
    "GainField",
    "GaussianTerms",
    "GlobalOracle",
    "ModelLikelihood",
    "Observations",
    "OracleGains",
    "OracleLikelihood",
    "OracleSearch",
    "OraclePlan",
    "OwnTerms",
    "PhaseColumnsMissing",
    "PhasePosteriors",
    "PhaseReads",
    "RfidMCLConfig",
    "RfidMCLResult",
    "RfidParticleFilter",
    "TagPosteriors",
    "as_free_space",
    "as_pose6",
    "as_tag_map",
    "combine_posteriors",
    "filter_metrics",
    "fit_far_detection",
    "gain_field",
    "global_oracle",
    "localisation_summary",
    "localise_tags",
    "localise_tags_phase",
    "observations_from_reads",
    "oracle_plan",
    "pair_geometry",
    "phase_reads_from_table",
    "read_region_mask",
    "rssi_residual_std",
    "run_rfid_mcl",
    "simulate_phase_rad",
    "tag_position_errors",
]
