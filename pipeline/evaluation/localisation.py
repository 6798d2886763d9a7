"""MCL localisation error over time, from a poses.parquet-format table."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import pandas as pd

from fuzzymodel import wrap_angle

from .metrics import PercentileSummary, nan_to_none, percentile_summary
from .tables import require_columns

__all__ = ["LocalisationErrors", "localisation_errors"]


@dataclass(frozen=True)
class LocalisationErrors:
    """Pose errors of an estimate against the truth.

    Attributes
    ----------
    time_s : numpy.ndarray, shape (n,)
        Pose times [s].
    position_m : numpy.ndarray, shape (n,)
        ``hypot(est_x - true_x, est_y - true_y)`` [m].
    heading_rad : numpy.ndarray, shape (n,)
        ``|wrap(est_theta - true_theta)|`` [rad].
    position_summary : PercentileSummary
        Of `position_m` [m].
    heading_summary : PercentileSummary
        Of `heading_rad` [rad].
    """

    time_s: np.ndarray
    position_m: np.ndarray
    heading_rad: np.ndarray
    position_summary: PercentileSummary
    heading_summary: PercentileSummary

    def to_dict(self) -> dict:
        """JSON-able summaries (no arrays)."""
        return nan_to_none({"position_m": self.position_summary.to_dict(),
                            "heading_rad": self.heading_summary.to_dict()})


def localisation_errors(poses: pd.DataFrame, estimate: str = "est") -> LocalisationErrors:
    """Position and heading error of the ``<estimate>_*`` columns against ``true_*``.

    Parameters
    ----------
    poses : pandas.DataFrame
        poses.parquet-format table (time_s, true_x_m, true_y_m, true_theta_rad,
        <estimate>_x_m, <estimate>_y_m, <estimate>_theta_rad).
    estimate : {"est", "odom"}
        MCL estimate or raw odometry.

    Returns
    -------
    LocalisationErrors
    """
    if estimate not in ("est", "odom"):
        raise ValueError(f"estimate must be 'est' or 'odom', got {estimate!r}")
    cols = ("time_s", "true_x_m", "true_y_m", "true_theta_rad",
            f"{estimate}_x_m", f"{estimate}_y_m", f"{estimate}_theta_rad")
    require_columns(poses, cols, "poses")
    dx = poses[f"{estimate}_x_m"].to_numpy(float) - poses["true_x_m"].to_numpy(float)
    dy = poses[f"{estimate}_y_m"].to_numpy(float) - poses["true_y_m"].to_numpy(float)
    dth = poses[f"{estimate}_theta_rad"].to_numpy(float) - poses["true_theta_rad"].to_numpy(float)
    dth = np.abs(wrap_angle(dth))
    pos = np.hypot(dx, dy)
    return LocalisationErrors(time_s=poses["time_s"].to_numpy(float), position_m=pos,
                              heading_rad=dth, position_summary=percentile_summary(pos),
                              heading_summary=percentile_summary(dth))
