"""Comparison of the learned sensor model with the ray-traced truth, baselines, metrics.

Pure functions over DataFrames, arrays and SensorLike models returning
dataclasses; no plotting (see :mod:`pipeline.figures`) and no file layout
decisions beyond the few run-directory files documented in :mod:`.tables`,
:mod:`.truth`, :mod:`.comparison`, :mod:`.fig7` and :mod:`.baselines`.
"""

from pipeline.evaluation.baselines import (
    BASELINES_FORMAT,
    BaselineSensorModel,
    GridCountModel,
    LogDistanceModel,
    fit_baselines,
    fit_grid_count,
    fit_log_distance,
    tr38901_horizontal_db,
)
from pipeline.evaluation.cells import CellGrid, CellIndex
from pipeline.evaluation.comparison import (
    DetectionComparison,
    RhoComparison,
    RhoPoints,
    RssiComparison,
    detection_vs_truth,
    rho_points_truth,
    rho_vs_truth,
    rssi_cell_mean_floor,
    rssi_vs_truth,
)
from pipeline.evaluation.coverage import CoverageResult, detection_coverage
from pipeline.evaluation.evaluate import (
    EvaluationInputs,
    LocalisationSplit,
    ModelMetrics,
    StudyMetrics,
    evaluate_all,
    evaluate_model,
    localisation_split,
)
from pipeline.evaluation.fig7 import FIG7_COLUMNS, Fig7Result, fig7_errors, read_fig7_table
from pipeline.evaluation.geometry import antenna_frame_geometry, lattice_offsets
from pipeline.evaluation.interface import SensorLike, check_sensor
from pipeline.evaluation.localisation import LocalisationErrors, localisation_errors
from pipeline.evaluation.metrics import (
    ErrorStats,
    PercentileSummary,
    brier_score,
    error_stats,
    nan_to_none,
    pearson_correlation,
    percentile_summary,
)
from pipeline.evaluation.tables import (
    read_tags,
    require_columns,
    tag_position_lookup,
    tags_table,
    write_json_atomic,
    write_parquet_atomic,
    write_tags,
)
from pipeline.evaluation.truth import TruthGrid, detection_truth, true_detected, true_rssi_dbm

__all__ = [
    "CoverageResult",
    "detection_coverage",
    "BASELINES_FORMAT",
    "BaselineSensorModel",
    "CellGrid",
    "CellIndex",
    "DetectionComparison",
    "ErrorStats",
    "EvaluationInputs",
    "FIG7_COLUMNS",
    "Fig7Result",
    "GridCountModel",
    "LocalisationErrors",
    "LocalisationSplit",
    "LogDistanceModel",
    "ModelMetrics",
    "PercentileSummary",
    "RhoComparison",
    "RhoPoints",
    "RssiComparison",
    "SensorLike",
    "StudyMetrics",
    "TruthGrid",
    "antenna_frame_geometry",
    "brier_score",
    "check_sensor",
    "detection_truth",
    "detection_vs_truth",
    "error_stats",
    "evaluate_all",
    "evaluate_model",
    "fig7_errors",
    "fit_baselines",
    "fit_grid_count",
    "fit_log_distance",
    "lattice_offsets",
    "localisation_errors",
    "localisation_split",
    "nan_to_none",
    "pearson_correlation",
    "percentile_summary",
    "read_fig7_table",
    "read_tags",
    "require_columns",
    "rho_points_truth",
    "rho_vs_truth",
    "rssi_cell_mean_floor",
    "rssi_vs_truth",
    "tag_position_lookup",
    "tags_table",
    "tr38901_horizontal_db",
    "true_detected",
    "true_rssi_dbm",
    "write_json_atomic",
    "write_parquet_atomic",
    "write_tags",
]
