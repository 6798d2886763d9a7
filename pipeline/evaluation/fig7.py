"""Chapter Fig. 7: error of the RSSI model along the evaluation path.

Cicirelli, Milella & Di Paola (2011), Sec. 5 (Fig. 7): on a held-out path the
robot reads the tags; at each pose the model's fs is averaged over the points
within 10 cm of the tag (the tag position is known only to that accuracy),
giving f̄s, and compared with the measured RSSI s normalised to [0, 1]:

    Error = |f̄s - s| x 100  [%],

an absolute difference of normalised quantities expressed in per cent (of the
RSSI range), bounded in [0, 100]; the chapter reports it mostly below 20 %.
Here, per (pose, antenna, tag) with reads:

- ``fs_meas`` (s) = normalise_rssi(rssi_dbm, sensor.rssi_range_dbm), averaged
  over the reads of the same pose, antenna and tag;
- ``fs_model`` (f̄s) = mean of ``sensor.fs(d, alpha)`` over a deterministic
  lattice of points within `radius_m` of the tag
  (:func:`~.geometry.lattice_offsets`), (d, alpha) taken in the ESTIMATED
  antenna frame (``est_ant_*`` columns), as the robot would;
- ``error_pct`` = |fs_model - fs_meas| x 100, the chapter's metric, for every
  group;
- ``rel_error_pct`` = |fs_model - fs_meas| / fs_meas x 100, a relative error
  NOT used by the chapter, kept for comparison; NaN where fs_meas <
  `min_fs_meas` (the ratio explodes as fs_meas -> 0);
- ``in_domain`` = d_est_m <= `d_max_m`: the tag centre lies within the distance
  the model was trained on (``training.d_max_m``). The summary statistics are
  of the in-domain groups; the others are summarised apart
  (``beyond_training_domain``), as the model there extrapolates.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import pandas as pd

from fuzzymodel import normalise_rssi
from pipeline.evaluation.geometry import antenna_frame_geometry, lattice_offsets
from pipeline.evaluation.interface import check_sensor
from pipeline.evaluation.metrics import PercentileSummary, nan_to_none, percentile_summary
from pipeline.evaluation.tables import require_columns, tag_position_lookup, write_parquet_atomic

__all__ = ["FIG7_COLUMNS", "Fig7Result", "fig7_errors", "fig7_summary", "read_fig7_table"]

_EST_POSE = ("est_ant_x_m", "est_ant_y_m", "est_ant_z_m", "est_ant_yaw_rad")
#: Columns of :attr:`Fig7Result.table` (and of ``truth/fig7_errors.parquet``).
FIG7_COLUMNS = ("pose", "antenna", "tag_id", "time_s", "n_reads", "d_est_m", "alpha_est_rad",
                "in_domain", "fs_meas", "fs_model", "error_pct", "rel_error_pct")
_PER_POSE_COLUMNS = ("pose", "antenna", "time_s", "n_tags", "error_pct")
#: The chapter's mark: Fig. 7 errors mostly below 20 %.
_MARK_PCT = 20.0


def fig7_summary(error_pct) -> dict:
    """Statistics of chapter Fig. 7 errors, as written to ``metrics.json``.

    Parameters
    ----------
    error_pct : array_like, shape (n_groups,)
        ``error_pct`` values [%] (non-finite entries are ignored).

    Returns
    -------
    dict
        ``n_groups`` (finite values used), ``median_pct``, ``p90_pct``,
        ``mean_pct``, ``max_pct`` [%] and ``share_below_20pct`` (fraction of
        groups with error_pct < 20, in [0, 1]); NaN statistics when empty.
    """
    v = np.asarray(error_pct, dtype=np.float64).ravel()
    v = v[np.isfinite(v)]
    s = percentile_summary(v)
    return {
        "n_groups": int(s.n),
        "median_pct": s.median,
        "p90_pct": s.p90,
        "mean_pct": s.mean,
        "max_pct": s.max,
        "share_below_20pct": float(np.mean(v < _MARK_PCT)) if v.size else float("nan"),
    }


@dataclass(frozen=True)
class Fig7Result:
    """Chapter Fig. 7 error of the RSSI model along the evaluation path.

    Error = |f̄s - s| x 100 [%] (chapter Sec. 5), f̄s the model's fs averaged
    within `radius_m` of the tag, s the measured normalised RSSI.

    Attributes
    ----------
    table : pandas.DataFrame
        One row per (pose, antenna, tag) with reads, columns :data:`FIG7_COLUMNS`:
        pose (int, evaluation-pose index), antenna, tag_id, time_s (first read)
        [s], n_reads, d_est_m [m] / alpha_est_rad [rad] (tag centre in the
        estimated antenna frame, mean over the reads), in_domain (bool,
        d_est_m <= d_max_m), fs_meas, fs_model (both in [0, 1]), error_pct
        (= |fs_model - fs_meas| x 100, chapter Sec. 5) [%], rel_error_pct
        (= |fs_model - fs_meas| / fs_meas x 100, NaN where fs_meas <
        min_fs_meas; not the chapter's metric) [%].
    per_pose : pandas.DataFrame
        One row per (pose, antenna) with in-domain groups: pose, antenna,
        time_s, n_tags, error_pct (mean over the pose's in-domain tags) [%].
    summary : PercentileSummary
        Of ``table.error_pct`` over the in-domain rows [%].
    per_antenna : dict
        ``{antenna (str): PercentileSummary}`` of the same, per antenna.
    radius_m : float
        Neighbourhood radius used [m].
    d_max_m : float
        Training-domain limit on d_est_m [m]; inf when none was given.
    min_fs_meas : float
        fs_meas below which rel_error_pct is NaN.
    """

    table: pd.DataFrame
    per_pose: pd.DataFrame
    summary: PercentileSummary
    per_antenna: dict
    radius_m: float
    d_max_m: float = float("inf")
    min_fs_meas: float = 0.02

    @property
    def n_rel_excluded(self) -> int:
        """Groups whose rel_error_pct is NaN (fs_meas < min_fs_meas)."""
        return int(self.table["rel_error_pct"].isna().sum())

    def to_dict(self) -> dict:
        """JSON-able summary (no per-group arrays); NaN -> None.

        Keys: ``metric`` (the definition), ``n_groups``, ``median_pct``,
        ``p90_pct``, ``mean_pct``, ``max_pct``, ``share_below_20pct`` of
        ``error_pct`` over the in-domain groups (chapter Sec. 5,
        |f̄s - s| x 100); ``beyond_training_domain`` (the same keys over the
        groups with d_est_m > d_max_m); ``per_antenna`` (the same keys per
        antenna, in-domain); ``rel_error_median_pct`` / ``rel_error_n_groups``
        (median of the relative error |f̄s - s| / s x 100 over the in-domain
        groups with s >= min_fs_meas; not the chapter's metric);
        ``n_groups_total``, ``radius_m``, ``d_max_m`` (None if unbounded),
        ``min_fs_meas``.
        """
        t = self.table
        inside = t["in_domain"].to_numpy(bool)
        rel = t.loc[inside, "rel_error_pct"].to_numpy(np.float64)
        rel = rel[np.isfinite(rel)]
        out = {"metric": "chapter Sec. 5: |fs_model - fs_meas| x 100 on normalised RSSI [%], "
                         "groups with d_est_m <= d_max_m"}
        out.update(fig7_summary(t.loc[inside, "error_pct"]))
        out["beyond_training_domain"] = fig7_summary(t.loc[~inside, "error_pct"])
        out["per_antenna"] = {str(a): fig7_summary(sub["error_pct"]) for a, sub in
                              t.loc[inside].groupby("antenna", sort=True)}
        out["rel_error_median_pct"] = float(np.median(rel)) if rel.size else float("nan")
        out["rel_error_n_groups"] = int(rel.size)
        out.update({"n_groups_total": int(len(t)), "radius_m": self.radius_m,
                    "d_max_m": self.d_max_m if np.isfinite(self.d_max_m) else None,
                    "min_fs_meas": self.min_fs_meas})
        return nan_to_none(out)

    def write_table(self, path):
        """Write :attr:`table` to Parquet (``truth/fig7_errors.parquet``), atomically."""
        return write_parquet_atomic(self.table, path)


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


def _empty_table() -> pd.DataFrame:
    cols = {c: pd.Series(dtype=float) for c in FIG7_COLUMNS}
    cols["in_domain"] = pd.Series(dtype=bool)
    return pd.DataFrame(cols)


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
    d_max_m: float | None = None,
    min_fs_meas: float = 0.02,
) -> Fig7Result:
    """Chapter Fig. 7 error of `sensor` on the evaluation reads.

    Chapter Sec. 5: Error = |f̄s - s| x 100 [%], with s the measured RSSI
    normalised to [0, 1] and f̄s the model's fs averaged over the points within
    `radius_m` (10 cm) of the tag. See the module doc for every column.

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
        Start time of each evaluation pose (eval_poses.parquet ``time_s``) [s];
        a read belongs to the last pose starting at or before it. If None, the
        ``cycle`` column is the pose index.
    antenna_pitch_rad : float or dict
        Antenna tilt [rad] (scalar or per antenna name) when the table has no
        ``est_ant_pitch_rad`` column.
    d_max_m : float, optional
        Training domain (``training.d_max_m``) [m]: groups with d_est_m <=
        d_max_m are ``in_domain`` and make the summary; the others are
        summarised apart. None: every group is in the domain.
    min_fs_meas : float
        ``rel_error_pct`` is NaN where fs_meas < min_fs_meas (``error_pct`` is
        defined for every group).

    Returns
    -------
    Fig7Result
    """
    sensor = check_sensor(sensor)
    require_columns(eval_reads, ("time_s", "antenna", "tag_id", "read", "rssi_dbm") + _EST_POSE,
                    "eval reads")
    d_lim = float("inf") if d_max_m is None else float(d_max_m)
    if not d_lim > 0:
        raise ValueError(f"d_max_m must be > 0 (or None), got {d_max_m!r}")
    lookup = tag_position_lookup(tags)
    df = eval_reads.loc[eval_reads["read"].astype(bool)
                        & np.isfinite(eval_reads["rssi_dbm"].to_numpy(np.float64))].copy()
    unknown = sorted(set(df["tag_id"].astype(str)) - set(lookup))
    if unknown:
        raise ValueError(f"eval reads name tag_id(s) {unknown[:5]} absent from the tags table")
    offsets = lattice_offsets(radius_m, shape, n_per_radius)
    if df.empty:
        return Fig7Result(_empty_table(), pd.DataFrame(columns=list(_PER_POSE_COLUMNS)),
                          percentile_summary([]), {}, float(radius_m), d_lim, float(min_fs_meas))
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
    table["in_domain"] = table["d_est_m"].to_numpy(np.float64) <= d_lim
    diff = np.abs(table["fs_model"].to_numpy(np.float64) - table["fs_meas"].to_numpy(np.float64))
    table["error_pct"] = diff * 100.0  # chapter Sec. 5
    meas = table["fs_meas"].to_numpy(np.float64)
    small = meas < float(min_fs_meas)
    with np.errstate(divide="ignore", invalid="ignore"):
        table["rel_error_pct"] = np.where(small, np.nan, diff / meas * 100.0)
    table = table[list(FIG7_COLUMNS)]
    inside = table.loc[table["in_domain"]]
    per_pose = (inside.groupby(["pose", "antenna"], sort=True)
                .agg(time_s=("time_s", "min"), n_tags=("tag_id", "size"),
                     error_pct=("error_pct", "mean")).reset_index())
    per_antenna = {str(a): percentile_summary(sub["error_pct"]) for a, sub in
                   inside.groupby("antenna", sort=True)}
    return Fig7Result(table=table, per_pose=per_pose, summary=percentile_summary(inside["error_pct"]),
                      per_antenna=per_antenna, radius_m=float(radius_m), d_max_m=d_lim,
                      min_fs_meas=float(min_fs_meas))


def read_fig7_table(path) -> pd.DataFrame:
    """Read ``truth/fig7_errors.parquet``; errors name the file and missing columns."""
    df = pd.read_parquet(path)
    require_columns(df, FIG7_COLUMNS, str(path))
    return df
