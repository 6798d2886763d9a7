"""Training sets of the sensor model, built from a read log.

Cicirelli, Milella and Di Paola (2011) train two Takagi-Sugeno systems over
(d, alpha): the signal-strength model fs on every read within range, its target the
RSSI normalised to [0, 1] with a fixed range, and the tag-detection model fT on a
(d, alpha) grid, its target ``fT = n+ / (n+ + n-)`` per cell, where n+ counts read
attempts in which a tag in the cell was read and n- those in which it was not.
"In range" means ``d < d_max_m`` (the grid's extent); an attempt is one read cycle of
the active antenna, so n- counts cycles, as the chapter defines it.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import pandas as pd

from fuzzymodel import normalise_rssi
from pipeline.acquisition.config import POSE_SOURCES
from pipeline.acquisition.readlog import read_table, write_table

__all__ = ["TrainingSet", "rssi_range_from_data", "ssm_samples", "tdm_samples"]


@dataclass
class TrainingSet:
    """Inputs and targets for one fuzzy model.

    Attributes
    ----------
    X : numpy.ndarray
        Inputs (n, 2) [d_m, alpha_rad], float64.
    y : numpy.ndarray
        Targets (n,), float64 in [0, 1]: normalised RSSI (``kind="ssm"``) or detection
        ratio fT (``kind="tdm"``).
    kind : str
        ``"ssm"`` or ``"tdm"``.
    n_pos : numpy.ndarray or None
        Per-cell read counts n+ (n,), int64 (TDM only).
    n_neg : numpy.ndarray or None
        Per-cell missed-attempt counts n- (n,), int64 (TDM only).
    rssi_range_dbm : tuple of float or None
        (lo, hi) normalisation range of the RSSI target in dBm (SSM only).
    description : dict
        How the set was built (pose source, d_max_m, bin sizes, counts).
    """

    X: np.ndarray
    y: np.ndarray
    kind: str
    n_pos: np.ndarray | None = None
    n_neg: np.ndarray | None = None
    rssi_range_dbm: tuple[float, float] | None = None
    description: dict = field(default_factory=dict)

    def __post_init__(self) -> None:
        self.X = np.asarray(self.X, dtype=float).reshape(-1, 2)
        self.y = np.asarray(self.y, dtype=float).reshape(-1)
        if len(self.X) != len(self.y):
            raise ValueError(f"TrainingSet: X has {len(self.X)} rows but y has {len(self.y)}")
        if self.kind not in ("ssm", "tdm"):
            raise ValueError(f"TrainingSet: kind must be 'ssm' or 'tdm', got {self.kind!r}")

    def __len__(self) -> int:
        return len(self.y)

    @property
    def weights(self) -> np.ndarray | None:
        """Read attempts per cell n+ + n- (TDM), the sample weights of the fT fit.

        Returns
        -------
        numpy.ndarray, shape (n,), float64, or None
            ``n_pos + n_neg`` per cell (>= ``min_attempts`` >= 1), aligned with ``X``
            and ``y``; passed as ``sample_weight`` to ``fuzzymodel.ANFIS.from_fcm`` /
            ``fit`` so a cell weighs as many attempts as it saw. None for SSM (one
            sample per read, unweighted).
        """
        if self.n_pos is None or self.n_neg is None:
            return None
        return (np.asarray(self.n_pos, dtype=np.int64)
                + np.asarray(self.n_neg, dtype=np.int64)).astype(np.float64)

    def to_frame(self) -> pd.DataFrame:
        """Columns d_m, alpha_rad, y (and n_pos, n_neg for TDM)."""
        cols = {"d_m": self.X[:, 0], "alpha_rad": self.X[:, 1], "y": self.y}
        if self.n_pos is not None:
            cols["n_pos"] = np.asarray(self.n_pos, dtype=np.int64)
            cols["n_neg"] = np.asarray(self.n_neg, dtype=np.int64)
        return pd.DataFrame(cols)

    def to_parquet(self, path: str | Path) -> Path:
        """Write as Parquet (temp file + rename); kind, range and description as metadata."""
        meta = {
            "kind": self.kind,
            "rssi_range_dbm": None if self.rssi_range_dbm is None else list(self.rssi_range_dbm),
            "description": self.description,
        }
        return write_table(self.to_frame(), path, meta)

    @classmethod
    def from_parquet(cls, path: str | Path) -> TrainingSet:
        """Read a set written by :meth:`to_parquet`."""
        df, meta = read_table(path)
        if "kind" not in meta:
            raise ValueError(f"{path}: not a TrainingSet file (no 'kind' in its metadata)")
        rng_ = meta.get("rssi_range_dbm")
        return cls(
            X=df[["d_m", "alpha_rad"]].to_numpy(float),
            y=df["y"].to_numpy(float),
            kind=meta["kind"],
            n_pos=df["n_pos"].to_numpy(np.int64) if "n_pos" in df else None,
            n_neg=df["n_neg"].to_numpy(np.int64) if "n_neg" in df else None,
            rssi_range_dbm=None if rng_ is None else (float(rng_[0]), float(rng_[1])),
            description=meta.get("description", {}),
        )


def _pose_columns(reads: pd.DataFrame, pose: str) -> tuple[str, str]:
    if pose not in POSE_SOURCES:
        raise ValueError(f"pose must be one of {POSE_SOURCES}, got {pose!r}")
    d_col, a_col = f"d_{pose}_m", f"alpha_{pose}_rad"
    missing = [c for c in (d_col, a_col, "read") if c not in reads.columns]
    if missing:
        raise ValueError(f"reads table lacks column(s) {missing}")
    return d_col, a_col


def _normalise(rssi_dbm: np.ndarray, rng_dbm: tuple[float, float]) -> np.ndarray:
    return normalise_rssi(rssi_dbm, rng_dbm, clip=True)


def rssi_range_from_data(rssi_dbm: np.ndarray) -> tuple[float, float]:
    """Default normalisation range: (floor(min), ceil(max)) of the RSSI, whole dBm.

    Raises
    ------
    ValueError
        If there is no finite RSSI or all values are equal.
    """
    r = np.asarray(rssi_dbm, dtype=float)
    r = r[np.isfinite(r)]
    if len(r) == 0:
        raise ValueError("no reads to take an RSSI range from")
    lo, hi = float(np.floor(r.min())), float(np.ceil(r.max()))
    if hi <= lo:
        hi = lo + 1.0
    return lo, hi


def ssm_samples(
    reads: pd.DataFrame,
    d_max_m: float = 3.0,
    rssi_range_dbm: tuple[float, float] | None = None,
    pose: str = "est",
) -> TrainingSet:
    """Signal-strength-model samples: every read with ``d < d_max_m``.

    Parameters
    ----------
    reads : pandas.DataFrame
        Read log (``reads.parquet`` columns).
    d_max_m : float
        Largest distance kept, metres (exclusive).
    rssi_range_dbm : (float, float), optional
        Fixed (lo, hi) normalisation range; RSSI outside it is clipped to [0, 1].
        Default :func:`rssi_range_from_data` on the kept reads.
    pose : {"est", "true"}
        Use d and alpha from estimated (MCL) or true antenna poses.

    Returns
    -------
    TrainingSet
        ``X`` (n, 2) [d_m, alpha_rad]; ``y`` = (RSSI - lo) / (hi - lo), clipped.
    """
    d_col, a_col = _pose_columns(reads, pose)
    if not d_max_m > 0:
        raise ValueError(f"d_max_m must be > 0, got {d_max_m!r}")
    sel = reads["read"].to_numpy(bool) & (reads[d_col].to_numpy(float) < d_max_m)
    rssi = reads["rssi_dbm"].to_numpy(float)[sel]
    rng_dbm = (
        rssi_range_from_data(rssi)
        if rssi_range_dbm is None
        else tuple(float(v) for v in rssi_range_dbm)
    )
    X = np.column_stack([reads[d_col].to_numpy(float)[sel], reads[a_col].to_numpy(float)[sel]])
    y = _normalise(rssi, rng_dbm) if len(rssi) else np.empty(0)
    n_clipped = int(np.sum((rssi < rng_dbm[0]) | (rssi > rng_dbm[1])))
    desc = {
        "pose": pose,
        "d_max_m": float(d_max_m),
        "n_reads": int(sel.sum()),
        "n_clipped": n_clipped,
    }
    return TrainingSet(X=X, y=y, kind="ssm", rssi_range_dbm=rng_dbm, description=desc)


def tdm_samples(
    reads: pd.DataFrame,
    d_bin_m: float = 0.25,
    alpha_bin_deg: float = 10.0,
    d_max_m: float = 3.0,
    pose: str = "est",
    min_attempts: int = 1,
) -> TrainingSet:
    """Tag-detection-model samples: detection ratio per (d, alpha) cell.

    Cells tile ``0 <= d < d_max_m`` in steps of ``d_bin_m`` and alpha in
    [-pi, pi) in steps of ``alpha_bin_deg`` (alpha = pi falls in the first bin's
    wrap-around, i.e. the bin starting at -pi). Every attempt row with ``d < d_max_m``
    counts once: n+ if read, n- if not. ``fT = n+ / (n+ + n-)``.

    Parameters
    ----------
    reads : pandas.DataFrame
        Read log, one row per (attempt, tag).
    d_bin_m, alpha_bin_deg : float
        Cell size in metres and degrees (> 0).
    d_max_m : float
        Grid extent in distance, metres; the "in range" limit of n-.
    pose : {"est", "true"}
        Antenna poses the geometry comes from.
    min_attempts : int
        Cells with fewer attempts are dropped.

    Returns
    -------
    TrainingSet
        ``X`` the centres of the kept cells (n, 2) [d_m, alpha_rad], ``y`` fT, and
        ``n_pos``/``n_neg``, ordered by d bin then alpha bin.
    """
    d_col, a_col = _pose_columns(reads, pose)
    for name, v in (("d_bin_m", d_bin_m), ("alpha_bin_deg", alpha_bin_deg), ("d_max_m", d_max_m)):
        if not (np.isfinite(v) and v > 0):
            raise ValueError(f"{name} must be finite and > 0, got {v!r}")
    if int(min_attempts) < 1:
        raise ValueError(f"min_attempts must be >= 1, got {min_attempts!r}")
    n_d = int(np.ceil(d_max_m / d_bin_m - 1e-9))
    a_bin = np.deg2rad(alpha_bin_deg)
    n_a = int(round(2 * np.pi / a_bin))
    if abs(n_a * a_bin - 2 * np.pi) > 1e-9:
        raise ValueError(f"alpha_bin_deg must divide 360, got {alpha_bin_deg!r}")
    d = reads[d_col].to_numpy(float)
    a = reads[a_col].to_numpy(float)
    read = reads["read"].to_numpy(bool)
    sel = d < d_max_m
    i_d = np.minimum((d[sel] / d_bin_m).astype(np.int64), n_d - 1)
    i_a = np.floor((a[sel] + np.pi) / a_bin).astype(np.int64) % n_a
    cell = i_d * n_a + i_a
    n_pos = np.bincount(cell[read[sel]], minlength=n_d * n_a)
    n_all = np.bincount(cell, minlength=n_d * n_a)
    keep = n_all >= int(min_attempts)
    idx = np.flatnonzero(keep)
    d_c = (idx // n_a + 0.5) * d_bin_m
    a_c = -np.pi + (idx % n_a + 0.5) * a_bin
    n_p, n_n = n_pos[idx], (n_all - n_pos)[idx]
    y = n_p / np.maximum(n_p + n_n, 1)
    desc = {
        "pose": pose,
        "d_max_m": float(d_max_m),
        "d_bin_m": float(d_bin_m),
        "alpha_bin_deg": float(alpha_bin_deg),
        "min_attempts": int(min_attempts),
        "n_attempts": int(sel.sum()),
        "n_cells": int(n_d * n_a),
        "n_cells_kept": int(len(idx)),
    }
    return TrainingSet(
        X=np.column_stack([d_c, a_c]),
        y=y,
        kind="tdm",
        n_pos=n_p.astype(np.int64),
        n_neg=n_n.astype(np.int64),
        description=desc,
    )
