"""Chapter Fig. 7: percentage RSSI error of the model along the evaluation path.

Cicirelli, Milella & Di Paola (2011), Sec. 5: on a held-out path the robot
reads the tags; at each pose the model output is averaged over the points
within 10 cm of the tag (the tag position is known only to that accuracy) and
compared with the normalised RSSI measured there,

    e = |fs_model - fs_meas| / fs_meas * 100  [%],

the chapter reporting e below 20 %. Here, per read (pose, antenna, tag):

- ``fs_meas`` = normalise_rssi(rssi_dbm, sensor.rssi_range_dbm), averaged over
  the reads of the same pose, antenna and tag;
- ``fs_model`` = mean of ``sensor.fs(d, alpha)`` over a deterministic lattice of
  points within `radius_m` of the tag (:func:`~.geometry.lattice_offsets`),
  (d, alpha) taken in the ESTIMATED antenna frame (``est_ant_*`` columns), as
  the robot would.

Groups whose fs_meas is below `min_fs_meas` are excluded from the percentages
(the ratio explodes as fs_meas -> 0) and counted in ``n_excluded``.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import pandas as pd

from fuzzymodel import normalise_rssi

from .geometry import antenna_frame_geometry, lattice_offsets
from .interface import check_sensor
from .metrics import PercentileSummary, nan_to_none, percentile_summary
from .tables import require_columns, tag_position_lookup, write_parquet_atomic

__all__ = ["FIG7_COLUMNS", "Fig7Result", "fig7_errors", "read_fig7_table"]

_EST_POSE = ("est_ant_x_m", "est_ant_y_m", "est_ant_z_m", "est_ant_yaw_rad")
#: Columns of :attr:`Fig7Result.table` (and of ``truth/fig7_errors.parquet``).
FIG7_COLUMNS = ("pose", "antenna", "tag_id", "time_s", "n_reads", "d_est_m", "alpha_est_rad",
                "fs_meas", "fs_model", "pct_error", "excluded")


@dataclass(frozen=True)
class Fig7Result:
    """Percentage error of the RSSI model along the evaluation path.

    Attributes
    ----------
    table : pandas.DataFrame
        One row per (pose, antenna, tag) with reads, columns :data:`FIG7_COLUMNS`:
        pose (int, evaluation-pose index), antenna, tag_id, time_s (first read),
        n_reads, d_est_m / alpha_est_rad (tag centre in the estimated antenna
        frame, mean), fs_meas, fs_model (both in [0, 1]), pct_error [%] (NaN
        where excluded), excluded (bool).
    per_pose : pandas.DataFrame
        One row per (pose, antenna): pose, antenna, time_s, n_tags,
        pct_error (mean over the pose's tags) [%].
    summary : PercentileSummary
        Of ``table.pct_error`` over non-excluded rows [%].
    per_antenna : dict
        ``{antenna: PercentileSummary}`` of the same, per antenna.
    radius_m : float
        Neighbourhood radius used [m].
    n_excluded : int
        Groups dropped because fs_meas < min_fs_meas.
    """

    table: pd.DataFrame
    per_pose: pd.DataFrame
    summary: PercentileSummary
    per_antenna: dict
    radius_m: float
    n_excluded: int

    def to_dict(self) -> dict:
        """JSON-able summary (no per-pose arrays); NaN -> None."""
        return nan_to_none({
            "pct_error": self.summary.to_dict(),
            "pct_error_per_antenna": {str(k): v.to_dict() for k, v in self.per_antenna.items()},
            "radius_m": self.radius_m,
            "n_groups": int(len(self.table)),
            "n_excluded": self.n_excluded,
            "fraction_below_20pct": _fraction_below(self.table, 20.0),
        })

    def write_table(self, path):
        """Write :attr:`table` to Parquet (``truth/fig7_errors.parquet``), atomically."""
        return write_parquet_atomic(self.table, path)


def _fraction_below(table: pd.DataFrame, pct: float) -> float:
    v = table.loc[~table["excluded"], "pct_error"].to_numpy(float)
    v = v[np.isfinite(v)]
    return float(np.mean(v < pct)) if v.size else float("nan")


def _pitch_roll(df: pd.DataFrame, antenna_pitch_rad) -> tuple[np.ndarray, np.ndarray]:
    n = len(df)
    if "est_ant_pitch_rad" in df.columns:
        pitch = df["est_ant_pitch_rad"].to_numpy(np.float64)
    elif isinstance(antenna_pitch_rad, dict):
        try:
            pitch = np.array([float(antenna_pitch_rad[a]) for a in df["antenna"]])
        except KeyError as exc:
            raise ValueError(
                f"antenna_pitch_rad has no entry for antenna {exc.args[0]!r}; "
                f"has {sorted(antenna_pitch_rad)}"
            ) from None
    else:
        pitch = np.full(n, float(antenna_pitch_rad))
    roll = (df["est_ant_roll_rad"].to_numpy(np.float64) if "est_ant_roll_rad" in df.columns
            else np.zeros(n))
    return pitch, roll


def _pose_index(df: pd.DataFrame, pose_times_s) -> np.ndarray:
    if pose_times_s is None:
        require_columns(df, ("cycle",), "eval reads (no pose_times_s given)")
        return df["cycle"].to_numpy().astype(np.int64)
    t = np.asarray(pose_times_s, dtype=np.float64).ravel()
    if t.size == 0 or np.any(np.diff(t) < 0):
        raise ValueError("pose_times_s must be non-empty and non-decreasing")
    idx = np.searchsorted(t, df["time_s"].to_numpy(np.float64), side="right") - 1
    return np.clip(idx, 0, t.size - 1)


def fig7_errors(
    eval_reads: pd.DataFrame,
    tags,
    sensor,
    *,
    radius_m: float = 0.1,
    shape: str = "disc",
    n_per_radius: int = 4,
    pose_times_s=None,
    antenna_pitch_rad=0.0,
    min_fs_meas: float = 0.02,
) -> Fig7Result:
    """Fig. 7 percentage error of `sensor` on the evaluation reads.

    Parameters
    ----------
    eval_reads : pandas.DataFrame
        reads.parquet-format table of the evaluation path; uses the rows with
        ``read`` True and finite ``rssi_dbm``; needs time_s, antenna, tag_id,
        read, rssi_dbm, est_ant_x_m, est_ant_y_m, est_ant_z_m, est_ant_yaw_rad
        (optional est_ant_pitch_rad, est_ant_roll_rad) and ``cycle`` when
        `pose_times_s` is None.
    tags : pandas.DataFrame or mapping or scenes.TagSet
        Tag positions (see :func:`~.tables.tag_position_lookup`).
    sensor : SensorLike
        Model to evaluate (fs and rssi_range_dbm are used).
    radius_m : float
        Neighbourhood radius [m]; the chapter uses 0.1 m.
    shape : {"disc", "ball"}
        Horizontal disc (chapter, 2-D) or 3-D ball.
    n_per_radius : int
        Lattice density (points per radius); 4 gives 49 disc / 257 ball points.
    pose_times_s : array_like, optional
        Start time of each evaluation pose (eval_poses.parquet ``time_s``); a
        read belongs to the last pose starting at or before it. If None, the
        ``cycle`` column is the pose index.
    antenna_pitch_rad : float or dict
        Antenna tilt [rad] (scalar or per antenna name) when the table has no
        ``est_ant_pitch_rad`` column.
    min_fs_meas : float
        Groups with fs_meas below this are excluded from the percentages.

    Returns
    -------
    Fig7Result
    """
    sensor = check_sensor(sensor)
    require_columns(eval_reads, ("time_s", "antenna", "tag_id", "read", "rssi_dbm") + _EST_POSE,
                    "eval reads")
    lookup = tag_position_lookup(tags)
    df = eval_reads.loc[eval_reads["read"].astype(bool)
                        & np.isfinite(eval_reads["rssi_dbm"].to_numpy(np.float64))].copy()
    unknown = sorted(set(df["tag_id"].astype(str)) - set(lookup))
    if unknown:
        raise ValueError(f"eval reads name tag_id(s) {unknown[:5]} absent from the tags table")
    offsets = lattice_offsets(radius_m, shape, n_per_radius)
    cols = list(FIG7_COLUMNS)
    if df.empty:
        empty = pd.DataFrame({c: pd.Series(dtype=float) for c in cols})
        return Fig7Result(empty, pd.DataFrame(columns=["pose", "antenna", "time_s", "n_tags",
                                                       "pct_error"]),
                          percentile_summary([]), {}, float(radius_m), 0)
    df["pose"] = _pose_index(df, pose_times_s)
    pitch, roll = _pitch_roll(df, antenna_pitch_rad)
    poses = np.column_stack([df[list(_EST_POSE)].to_numpy(np.float64), pitch, roll])
    centre = np.stack([lookup[t] for t in df["tag_id"].astype(str)])
    geo = antenna_frame_geometry(poses, centre[:, None, :] + offsets[None, :, :])
    fs_points = np.asarray(sensor.fs(geo.d_m, geo.alpha_rad), dtype=np.float64)
    df["fs_model"] = fs_points.mean(axis=1)
    centre_geo = antenna_frame_geometry(poses, centre[:, None, :])
    df["d_est_m"] = centre_geo.d_m[:, 0]
    df["alpha_est_rad"] = centre_geo.alpha_rad[:, 0]
    df["fs_meas"] = normalise_rssi(df["rssi_dbm"].to_numpy(np.float64), sensor.rssi_range_dbm)
    g = df.groupby(["pose", "antenna", "tag_id"], sort=True)
    table = g.agg(time_s=("time_s", "min"), n_reads=("read", "size"),
                  d_est_m=("d_est_m", "mean"), alpha_est_rad=("alpha_est_rad", "mean"),
                  fs_meas=("fs_meas", "mean"), fs_model=("fs_model", "mean")).reset_index()
    table["excluded"] = table["fs_meas"] < float(min_fs_meas)
    with np.errstate(divide="ignore", invalid="ignore"):
        pct = np.abs(table["fs_model"] - table["fs_meas"]) / table["fs_meas"] * 100.0
    table["pct_error"] = np.where(table["excluded"], np.nan, pct)
    table = table[cols]
    per_pose = (table.loc[~table["excluded"]]
                .groupby(["pose", "antenna"], sort=True)
                .agg(time_s=("time_s", "min"), n_tags=("tag_id", "size"),
                     pct_error=("pct_error", "mean")).reset_index())
    ok = table.loc[~table["excluded"]]
    per_antenna = {str(a): percentile_summary(sub["pct_error"]) for a, sub in
                   ok.groupby("antenna", sort=True)}
    return Fig7Result(table=table, per_pose=per_pose, summary=percentile_summary(ok["pct_error"]),
                      per_antenna=per_antenna, radius_m=float(radius_m),
                      n_excluded=int(table["excluded"].sum()))


def read_fig7_table(path) -> pd.DataFrame:
    """Read ``truth/fig7_errors.parquet``; errors name the file and missing columns."""
    df = pd.read_parquet(path)
    require_columns(df, FIG7_COLUMNS, str(path))
    return df
