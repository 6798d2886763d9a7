"""Baselines fitted on the same data as the FCM/ANFIS model, with the same interface.

(a) Log-distance path loss with a fitted antenna pattern (e.g. Rappaport,
*Wireless Communications*, 2nd ed., eq. 4.68):

    rssi_dbm(d, alpha) = P0 - 10 n log10(d / d0) + G(alpha)

fitted by linear least squares on the reads (d, alpha, rssi_dbm). G is either

- ``"cosine"``: a cosine series ``sum_{k=1..K} c_k cos(k alpha)`` [dB] (even in
  alpha, as a pattern symmetric about boresight; P0 absorbs the constant term),
- ``"tr38901"``: the 3GPP TR 38.901 Table 7.3-1 horizontal cut relative to
  boresight, ``A_H(alpha) = -min(12 (alpha / 65 deg)^2, 30)`` [dB], times a
  fitted scale ``s`` (about 2 for the monostatic link, which crosses the
  pattern twice).

(b) Grid-count detection model after Hähnel et al. (2004), "Mapping and
localization with RFID technology", ICRA: per cell the count of reads over
attempts, predicted by lookup. Hähnel et al. use a Cartesian grid in the
antenna frame; here the cells are the (d, alpha) cells of
:class:`~.cells.CellGrid` so the inputs match the fuzzy model's. Cells without
attempts predict 0 (``fallback="zero"``) or the value of the nearest cell with
attempts (``"nearest"``, distance in cell units, bearing wrapping round);
distances beyond the grid predict 0.

:class:`BaselineSensorModel` combines them into an object with
``fs, fs_dbm, fT, rho`` like ``fuzzymodel.SensorModel``; saved as
``models/baselines.json``.
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pandas as pd

from fuzzymodel import denormalise_rssi, normalise_rssi, wrap_angle
from pipeline.configschema import check_keys
from pipeline.evaluation.cells import CellGrid
from pipeline.evaluation.tables import require_columns, write_json_atomic
from propagation import pattern_gain_db

__all__ = [
    "BASELINES_FORMAT",
    "BaselineSensorModel",
    "GridCountModel",
    "LogDistanceModel",
    "fit_baselines",
    "fit_grid_count",
    "fit_log_distance",
    "tr38901_horizontal_db",
]

#: Format tag of ``models/baselines.json``.
BASELINES_FORMAT = "rfidstudy.evaluation.baselines/1"
PATTERNS = ("cosine", "tr38901")


def tr38901_horizontal_db(alpha_rad) -> np.ndarray:
    """3GPP TR 38.901 Table 7.3-1 element pattern, horizontal cut, relative to boresight [dB].

    ``-min(12 (phi / 65 deg)^2, 30)`` with phi the bearing wrapped to (-180, 180] deg:
    :func:`propagation.pattern_gain_db` ``("tr38901", pi/2, phi)`` less its 8 dBi peak.
    """
    phi = wrap_angle(alpha_rad)
    theta = np.full_like(phi, np.pi / 2)
    return pattern_gain_db("tr38901", theta, phi) - pattern_gain_db("tr38901", np.pi / 2, 0.0)


@dataclass(frozen=True)
class LogDistanceModel:
    """Log-distance path loss plus fitted pattern (see module doc).

    Attributes
    ----------
    p0_dbm : float
        RSSI at ``d0_m`` on boresight minus G(0) for "cosine" (equal to it for
        "tr38901", whose G(0) = 0) [dBm].
    n : float
        Path-loss exponent (2 in free space for one way; the backscatter RSSI
        crosses the path twice, so about 4 in free space).
    d0_m : float
        Reference distance [m].
    pattern : {"cosine", "tr38901"}
    coefficients : tuple of float
        "cosine": (c_1, ..., c_K) [dB]; "tr38901": (s,) dimensionless.
    rmse_db : float
        Training residual RMSE [dB] (NaN if unknown).
    n_samples : int
        Training samples.
    """

    p0_dbm: float
    n: float
    d0_m: float = 1.0
    pattern: str = "cosine"
    coefficients: tuple = ()
    rmse_db: float = float("nan")
    n_samples: int = 0

    def __post_init__(self) -> None:
        if self.pattern not in PATTERNS:
            raise ValueError(f"LogDistanceModel: pattern must be one of {PATTERNS}, "
                             f"got {self.pattern!r}")
        if not (np.isfinite(self.d0_m) and self.d0_m > 0):
            raise ValueError(f"LogDistanceModel: d0_m must be > 0, got {self.d0_m!r}")
        object.__setattr__(self, "coefficients", tuple(float(c) for c in self.coefficients))
        if self.pattern == "tr38901" and len(self.coefficients) != 1:
            raise ValueError("LogDistanceModel: pattern 'tr38901' needs exactly one coefficient "
                             f"(the scale), got {len(self.coefficients)}")

    def pattern_db(self, alpha_rad) -> np.ndarray:
        """G(alpha) [dB], same shape as `alpha_rad`."""
        a = np.asarray(alpha_rad, dtype=np.float64)
        if not self.coefficients:
            return np.zeros(a.shape)
        basis = _pattern_basis(a, self.pattern, len(self.coefficients))
        return (basis @ np.asarray(self.coefficients, dtype=np.float64)).reshape(a.shape)

    def predict_dbm(self, d_m, alpha_rad) -> np.ndarray:
        """RSSI [dBm] at distance `d_m` [m] (> 0) and bearing `alpha_rad` [rad]; broadcasts."""
        d, a = np.broadcast_arrays(np.asarray(d_m, dtype=np.float64),
                                   np.asarray(alpha_rad, dtype=np.float64))
        with np.errstate(divide="ignore"):
            out = self.p0_dbm - 10.0 * self.n * np.log10(d / self.d0_m)
        return out + self.pattern_db(a)

    def to_dict(self) -> dict:
        """JSON-able parameters."""
        return {"p0_dbm": float(self.p0_dbm), "n": float(self.n), "d0_m": float(self.d0_m),
                "pattern": self.pattern, "coefficients": list(self.coefficients),
                "rmse_db": None if not np.isfinite(self.rmse_db) else float(self.rmse_db),
                "n_samples": int(self.n_samples)}

    @classmethod
    def from_dict(cls, d: dict, where: str = "log_distance") -> LogDistanceModel:
        """Inverse of :meth:`to_dict`; errors name `where` and the key."""
        req = {"p0_dbm", "n", "d0_m", "pattern", "coefficients"}
        check_keys(d, req | {"rmse_db", "n_samples"}, where, required=req)
        rmse = d.get("rmse_db")
        return cls(p0_dbm=float(d["p0_dbm"]), n=float(d["n"]), d0_m=float(d["d0_m"]),
                   pattern=str(d["pattern"]), coefficients=tuple(d["coefficients"]),
                   rmse_db=float("nan") if rmse is None else float(rmse),
                   n_samples=int(d.get("n_samples", 0)))


def _pattern_basis(alpha_rad, pattern: str, n_terms: int) -> np.ndarray:
    a = wrap_angle(np.asarray(alpha_rad, dtype=np.float64).ravel())
    if pattern == "tr38901":
        return tr38901_horizontal_db(a)[:, None]
    k = np.arange(1, n_terms + 1)
    return np.cos(a[:, None] * k[None, :])


def fit_log_distance(d_m, alpha_rad, rssi_dbm, pattern: str = "cosine", n_harmonics: int = 2,
                     d0_m: float = 1.0) -> LogDistanceModel:
    """Least-squares fit of :class:`LogDistanceModel` to samples.

    Solves ``min || [1, -10 log10(d/d0), B(alpha)] [P0, n, c]^T - rssi ||_2``
    with ``numpy.linalg.lstsq``, B the pattern basis (K cosines, or the
    TR 38.901 cut).

    Parameters
    ----------
    d_m, alpha_rad, rssi_dbm : array_like, shape (n,)
        Distances [m] (> 0), bearings [rad], RSSI [dBm]; non-finite rows are dropped.
    pattern : {"cosine", "tr38901"}
    n_harmonics : int
        K for "cosine" (>= 0).
    d0_m : float
        Reference distance [m].

    Returns
    -------
    LogDistanceModel
    """
    if pattern not in PATTERNS:
        raise ValueError(f"pattern must be one of {PATTERNS}, got {pattern!r}")
    if pattern == "cosine" and int(n_harmonics) < 0:
        raise ValueError(f"n_harmonics must be >= 0, got {n_harmonics!r}")
    d = np.asarray(d_m, dtype=np.float64).ravel()
    a = np.asarray(alpha_rad, dtype=np.float64).ravel()
    y = np.asarray(rssi_dbm, dtype=np.float64).ravel()
    if not (d.shape == a.shape == y.shape):
        raise ValueError(f"d_m {d.shape}, alpha_rad {a.shape}, rssi_dbm {y.shape} differ")
    ok = np.isfinite(d) & np.isfinite(a) & np.isfinite(y) & (d > 0)
    d, a, y = d[ok], a[ok], y[ok]
    n_terms = 1 if pattern == "tr38901" else int(n_harmonics)
    n_par = 2 + n_terms
    if d.size < n_par:
        raise ValueError(f"fit_log_distance: {d.size} usable samples for {n_par} parameters")
    A = np.column_stack([np.ones_like(d), -10.0 * np.log10(d / d0_m),
                         _pattern_basis(a, pattern, n_terms)])
    coef, *_ = np.linalg.lstsq(A, y, rcond=None)
    res = A @ coef - y
    return LogDistanceModel(p0_dbm=float(coef[0]), n=float(coef[1]), d0_m=float(d0_m),
                            pattern=pattern, coefficients=tuple(coef[2:]),
                            rmse_db=float(np.sqrt(np.mean(res ** 2))), n_samples=int(d.size))


@dataclass(frozen=True)
class GridCountModel:
    """Per-cell read / attempt counts (Hähnel et al. 2004), see module doc.

    Attributes
    ----------
    grid : CellGrid
    n_reads : numpy.ndarray, shape (n_d, n_alpha), int64
    n_attempts : numpy.ndarray, shape (n_d, n_alpha), int64
    fallback : {"nearest", "zero"}
        Prediction in cells without attempts.
    """

    grid: CellGrid
    n_reads: np.ndarray
    n_attempts: np.ndarray
    fallback: str = "nearest"

    def __post_init__(self) -> None:
        if self.fallback not in ("nearest", "zero"):
            raise ValueError(f"GridCountModel: fallback must be 'nearest' or 'zero', "
                             f"got {self.fallback!r}")
        r = np.asarray(self.n_reads, dtype=np.int64)
        t = np.asarray(self.n_attempts, dtype=np.int64)
        if r.shape != self.grid.shape or t.shape != self.grid.shape:
            raise ValueError(f"GridCountModel: counts {r.shape}/{t.shape} do not match the grid "
                             f"{self.grid.shape}")
        if np.any(r < 0) or np.any(r > t):
            raise ValueError("GridCountModel: need 0 <= n_reads <= n_attempts in every cell")
        object.__setattr__(self, "n_reads", r)
        object.__setattr__(self, "n_attempts", t)
        object.__setattr__(self, "_table", self._fill())

    def _fill(self) -> np.ndarray:
        seen = self.n_attempts > 0
        p = np.where(seen, self.n_reads / np.maximum(self.n_attempts, 1), 0.0)
        if self.fallback == "zero" or seen.all() or not seen.any():
            return p
        n_a = self.grid.n_alpha
        si, sj = np.nonzero(seen)
        ui, uj = np.nonzero(~seen)
        dj = np.abs(uj[:, None] - sj[None, :])
        dj = np.minimum(dj, n_a - dj)  # bearing wraps round
        dist2 = (ui[:, None] - si[None, :]) ** 2 + dj ** 2
        nearest = np.argmin(dist2, axis=1)
        p[ui, uj] = p[si[nearest], sj[nearest]]
        return p

    @property
    def table(self) -> np.ndarray:
        """Predicted probability per cell, fallback applied, shape (n_d, n_alpha)."""
        return self._table.copy()

    def predict(self, d_m, alpha_rad) -> np.ndarray:
        """Detection probability at (d [m], alpha [rad]); broadcasts; 0 outside the grid."""
        d, a = np.broadcast_arrays(np.asarray(d_m, dtype=np.float64),
                                   np.asarray(alpha_rad, dtype=np.float64))
        idx = self.grid.index(d.ravel(), a.ravel())
        out = np.where(idx.valid, self._table[idx.i_d, idx.i_alpha], 0.0)
        return out.reshape(d.shape)

    def to_dict(self) -> dict:
        """JSON-able: grid, counts (nested lists), fallback."""
        return {"grid": self.grid.to_dict(), "n_reads": self.n_reads.tolist(),
                "n_attempts": self.n_attempts.tolist(), "fallback": self.fallback}

    @classmethod
    def from_dict(cls, d: dict, where: str = "grid_count") -> GridCountModel:
        """Inverse of :meth:`to_dict`; errors name `where` and the key."""
        req = {"grid", "n_reads", "n_attempts", "fallback"}
        check_keys(d, req, where, required=req)
        return cls(grid=CellGrid.from_dict(d["grid"], f"{where}: grid"),
                   n_reads=np.asarray(d["n_reads"], dtype=np.int64),
                   n_attempts=np.asarray(d["n_attempts"], dtype=np.int64),
                   fallback=str(d["fallback"]))


def fit_grid_count(d_m, alpha_rad, read, grid: CellGrid | None = None,
                   fallback: str = "nearest") -> GridCountModel:
    """Count reads and attempts per (d, alpha) cell.

    Parameters
    ----------
    d_m, alpha_rad : array_like, shape (n,)
        Attempt geometry [m], [rad].
    read : array_like of bool, shape (n,)
        Whether the attempt was read.
    grid : CellGrid, optional
    fallback : {"nearest", "zero"}

    Returns
    -------
    GridCountModel
    """
    grid = CellGrid() if grid is None else grid
    r = np.asarray(read).ravel()
    if r.dtype != bool:
        if not np.all(np.isin(r, (0, 1))):
            raise ValueError("read must be boolean")
        r = r.astype(bool)
    att = grid.count(d_m, alpha_rad).astype(np.int64)
    reads = grid.count(d_m, alpha_rad, r.astype(float)).astype(np.int64)
    return GridCountModel(grid=grid, n_reads=reads, n_attempts=att, fallback=fallback)


class BaselineSensorModel:
    """Baselines combined with the interface of ``fuzzymodel.SensorModel``.

    Parameters
    ----------
    rssi : LogDistanceModel
    detection : GridCountModel
    rssi_range_dbm : (float, float)
        Normalisation range of fs (use the fuzzy model's for comparability).
    """

    def __init__(self, rssi: LogDistanceModel, detection: GridCountModel,
                 rssi_range_dbm=(-80.0, -30.0)):
        if not isinstance(rssi, LogDistanceModel):
            raise TypeError(f"rssi must be a LogDistanceModel, got {type(rssi).__name__}")
        if not isinstance(detection, GridCountModel):
            raise TypeError(f"detection must be a GridCountModel, got {type(detection).__name__}")
        lo, hi = (float(v) for v in rssi_range_dbm)
        if not lo < hi:
            raise ValueError(f"rssi_range_dbm must be (lo, hi) with lo < hi, got {rssi_range_dbm}")
        self.rssi = rssi
        self.detection = detection
        self.rssi_range_dbm = (lo, hi)

    def fs(self, d, alpha) -> np.ndarray:
        """Normalised RSSI in [0, 1] (log-distance prediction, clipped)."""
        return normalise_rssi(self.rssi.predict_dbm(d, alpha), self.rssi_range_dbm)

    def fs_dbm(self, d, alpha) -> np.ndarray:
        """RSSI [dBm], clipped to the range like ``SensorModel.fs_dbm``."""
        return denormalise_rssi(self.fs(d, alpha), self.rssi_range_dbm)

    def fT(self, d, alpha) -> np.ndarray:  # noqa: N802 - the chapter's name
        """Detection probability from the grid counts."""
        return self.detection.predict(d, alpha)

    def rho(self, d, alpha) -> np.ndarray:
        """``fs * fT``."""
        return self.fs(d, alpha) * self.fT(d, alpha)

    def to_dict(self) -> dict:
        """JSON-able dict (format :data:`BASELINES_FORMAT`)."""
        return {"format": BASELINES_FORMAT,
                "description": "log-distance RSSI + Haehnel 2004 grid-count detection baselines",
                "rssi_range_dbm": list(self.rssi_range_dbm),
                "log_distance": self.rssi.to_dict(), "grid_count": self.detection.to_dict()}

    @classmethod
    def from_dict(cls, d: dict, where: str = "baselines") -> BaselineSensorModel:
        """Inverse of :meth:`to_dict`."""
        req = {"format", "rssi_range_dbm", "log_distance", "grid_count"}
        check_keys(d, req | {"description"}, where, required=req)
        if d["format"] != BASELINES_FORMAT:
            raise ValueError(f"{where}: format {d['format']!r}, expected {BASELINES_FORMAT!r}")
        return cls(LogDistanceModel.from_dict(d["log_distance"], f"{where}: log_distance"),
                   GridCountModel.from_dict(d["grid_count"], f"{where}: grid_count"),
                   tuple(d["rssi_range_dbm"]))

    def save(self, path) -> Path:
        """Write ``models/baselines.json`` atomically."""
        return write_json_atomic(self.to_dict(), path)

    @classmethod
    def load(cls, path) -> BaselineSensorModel:
        """Read a file written by :meth:`save`; errors name the file and key."""
        path = Path(path)
        try:
            d = json.loads(path.read_text())
        except FileNotFoundError:
            raise FileNotFoundError(f"baselines file {path} does not exist") from None
        except json.JSONDecodeError as exc:
            raise ValueError(f"{path}: not valid JSON ({exc})") from None
        return cls.from_dict(d, str(path))


def fit_baselines(reads: pd.DataFrame, rssi_range_dbm, grid: CellGrid | None = None,
                  pose: str = "est", pattern: str = "cosine", n_harmonics: int = 2,
                  fallback: str = "nearest") -> BaselineSensorModel:
    """Fit both baselines on a reads table, as the fuzzy model is trained.

    The RSSI model uses the read rows (finite rssi_dbm) with d < grid.d_max_m;
    the grid-count model every attempt inside the grid. Geometry from the
    ``d_<pose>_m`` / ``alpha_<pose>_rad`` columns (``pose`` "est": MCL poses, as
    on a robot; "true": ground truth).
    """
    if pose not in ("est", "true"):
        raise ValueError(f"pose must be 'est' or 'true', got {pose!r}")
    grid = CellGrid() if grid is None else grid
    dc, ac = f"d_{pose}_m", f"alpha_{pose}_rad"
    require_columns(reads, ("read", "rssi_dbm", dc, ac), "reads")
    d = reads[dc].to_numpy(np.float64)
    a = reads[ac].to_numpy(np.float64)
    rd = reads["read"].to_numpy(bool)
    rssi = reads["rssi_dbm"].to_numpy(np.float64)
    sel = rd & np.isfinite(rssi) & (d < grid.d_max_m)
    ld = fit_log_distance(d[sel], a[sel], rssi[sel], pattern=pattern, n_harmonics=n_harmonics)
    gc = fit_grid_count(d, a, rd, grid=grid, fallback=fallback)
    return BaselineSensorModel(ld, gc, rssi_range_dbm)
