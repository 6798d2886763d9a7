"""MCL localisation error over time, and its summary per track (error and bias).

:func:`localisation_errors` gives the error over time of a poses.parquet-format table;
:func:`pose_error_summary` (arrays) and :func:`localisation_summary` (a table) give the
numbers a study reports per tour: how large the MCL error is (median, p90) and how
*biased* it is (the mean signed offset of the estimate from the truth, in the robot
frame and in the world frame). A map whose walls are off shifts the estimate
systematically, which a mean absolute error cannot tell from noise.
:func:`check_tracking` fails a run whose filter lost track.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import asdict, dataclass
from typing import Any

import numpy as np
import pandas as pd

from fuzzymodel import wrap_angle
from pipeline.evaluation.metrics import PercentileSummary, nan_to_none, percentile_summary
from pipeline.evaluation.tables import require_columns

__all__ = [
    "LocalisationErrors",
    "LocalisationSummary",
    "check_tracking",
    "localisation_errors",
    "localisation_summary",
    "pose_error_summary",
    "pose_offsets",
]


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


def pose_offsets(true_poses: np.ndarray, est_poses: np.ndarray) -> dict[str, np.ndarray]:
    """Signed offset of estimated poses from true poses, in the world and robot frames.

    Parameters
    ----------
    true_poses, est_poses : numpy.ndarray
        Poses (n, 3) [x_m, y_m, theta_rad].

    Returns
    -------
    dict of numpy.ndarray, each (n,)
        ``x_m``, ``y_m``: ``est - true`` in the world frame [m]; ``along_m``,
        ``lateral_m``: the same rotated into the frame of the true pose (along = the
        robot's heading, lateral = to its left) [m]; ``heading_rad``:
        ``wrap(est_theta - true_theta)`` [rad].
    """
    t = np.asarray(true_poses, dtype=float).reshape(-1, 3)
    e = np.asarray(est_poses, dtype=float).reshape(-1, 3)
    if t.shape != e.shape:
        raise ValueError(f"pose_offsets: true poses {t.shape} and estimates {e.shape} differ")
    dx, dy = e[:, 0] - t[:, 0], e[:, 1] - t[:, 1]
    c, s = np.cos(t[:, 2]), np.sin(t[:, 2])
    return {"x_m": dx, "y_m": dy, "along_m": c * dx + s * dy, "lateral_m": -s * dx + c * dy,
            "heading_rad": wrap_angle(e[:, 2] - t[:, 2])}


@dataclass(frozen=True)
class LocalisationSummary:
    """MCL pose error and bias of one track.

    Attributes
    ----------
    n_poses : int
        Poses summarised.
    position_error_median_m, position_error_p90_m : float
        Median and 90th percentile of ``|est_xy - true_xy|`` [m].
    heading_error_median_deg : float
        Median of ``|wrap(est_theta - true_theta)|`` [deg].
    mean_offset_along_m, mean_offset_lateral_m : float
        Mean signed offset ``est - true`` in the frame of the true pose [m]: along the
        robot's heading and to its left. A map whose walls are off shows here.
    mean_offset_x_m, mean_offset_y_m : float
        Mean signed offset ``est - true`` in the world frame [m]. (A tour that drives
        up and back has opposite robot-frame signs on the two legs for the same
        world-frame shift; report both.)
    """

    n_poses: int
    position_error_median_m: float
    position_error_p90_m: float
    heading_error_median_deg: float
    mean_offset_along_m: float
    mean_offset_lateral_m: float
    mean_offset_x_m: float
    mean_offset_y_m: float

    def to_dict(self) -> dict:
        """JSON-able dict of the attributes (NaN becomes None)."""
        return nan_to_none(asdict(self))


def pose_error_summary(true_poses: np.ndarray, est_poses: np.ndarray) -> LocalisationSummary:
    """Error and bias of estimated poses against true poses (:class:`LocalisationSummary`).

    Parameters
    ----------
    true_poses, est_poses : numpy.ndarray
        Poses (n, 3) [x_m, y_m, theta_rad], one estimate per true pose. With n = 0 every
        statistic is NaN.

    Returns
    -------
    LocalisationSummary
    """
    off = pose_offsets(true_poses, est_poses)
    n = len(off["x_m"])
    if n == 0:
        nan = float("nan")
        return LocalisationSummary(0, nan, nan, nan, nan, nan, nan, nan)
    pos = np.hypot(off["x_m"], off["y_m"])
    return LocalisationSummary(
        n_poses=int(n),
        position_error_median_m=float(np.median(pos)),
        position_error_p90_m=float(np.percentile(pos, 90)),
        heading_error_median_deg=float(np.rad2deg(np.median(np.abs(off["heading_rad"])))),
        mean_offset_along_m=float(np.mean(off["along_m"])),
        mean_offset_lateral_m=float(np.mean(off["lateral_m"])),
        mean_offset_x_m=float(np.mean(off["x_m"])),
        mean_offset_y_m=float(np.mean(off["y_m"])),
    )


def localisation_summary(poses: pd.DataFrame, estimate: str = "est") -> LocalisationSummary:
    """:func:`pose_error_summary` of a poses.parquet-format table.

    Parameters
    ----------
    poses : pandas.DataFrame
        Columns true_x_m, true_y_m, true_theta_rad, <estimate>_x_m, <estimate>_y_m,
        <estimate>_theta_rad.
    estimate : {"est", "odom"}
        MCL estimate or raw odometry.

    Returns
    -------
    LocalisationSummary
    """
    if estimate not in ("est", "odom"):
        raise ValueError(f"estimate must be 'est' or 'odom', got {estimate!r}")
    cols = [f"{p}_{c}" for p in ("true", estimate) for c in ("x_m", "y_m", "theta_rad")]
    require_columns(poses, cols, "poses")
    a = poses[cols].to_numpy(float)
    return pose_error_summary(a[:, :3], a[:, 3:])


def check_tracking(
    summary: LocalisationSummary,
    max_median_m: float,
    max_p90_m: float,
    *,
    track: str = "track",
    median_key: str = "max_median_m",
    p90_key: str = "max_p90_m",
    causes: Mapping[str, Any] | None = None,
) -> None:
    """Raise when MCL lost track: position error median or p90 over its limit.

    Parameters
    ----------
    summary : LocalisationSummary
    max_median_m, max_p90_m : float
        Limits on the position error median and 90th percentile [m].
    track : str
        Name of the track, for the message.
    median_key, p90_key : str
        Names of the settings holding the limits (e.g. config keys), for the message.
    causes : mapping of str to value, optional
        Settings (name: value) that make MCL lose track, named in the message so that a
        user knows what to change.

    Raises
    ------
    ValueError
        Naming the track, the measured error, the limits exceeded and ``causes``.
    """
    bad = []
    med, p90 = summary.position_error_median_m, summary.position_error_p90_m
    if np.isfinite(med) and med > max_median_m:
        bad.append(f"position error median {med:.3f} m > {median_key} = {max_median_m:g} m")
    if np.isfinite(p90) and p90 > max_p90_m:
        bad.append(f"position error p90 {p90:.3f} m > {p90_key} = {max_p90_m:g} m")
    if not bad:
        return
    msg = f"MCL lost track on the {track} ({'; '.join(bad)})"
    if causes:
        msg += ("; the robot's map is too far from the building for the laser model, or "
                "the filter too weak: " + ", ".join(f"{k} = {v}" for k, v in causes.items()))
    raise ValueError(msg)
