"""The propagation truth the learned models are compared with.

Noise-free link (docs/physics.md, "The backscatter link"): with the ray-traced one-way
gain ``gain_db`` and a ``propagation.LinkBudget`` ``budget``,

- true RSSI ``budget.reader_rssi_dbm(gain_db)`` [dBm] (no reader noise or quantisation);
- the link closes where ``budget.detected(gain_db)`` (tag and reader thresholds);
- the true probability of a read is ``closed * (1 - miss_probability)``, the
  reader's anti-collision miss probability being the only remaining loss: the constant
  ``anticollision_miss_probability`` of the ``"fixed"`` inventory, or per attempt for
  the Gen2 reader, ``1 - p_singulated(n)`` with ``n`` the tags whose links close in the
  attempt's antenna slot
  (:func:`pipeline.acquisition.singulation.miss_probability_of_attempts`).

Over the (d, alpha) plane, :func:`detection_truth` bins read attempts by their
TRUE geometry (``d_true_m``, ``alpha_true_rad``) into a :class:`~.cells.CellGrid`;
per cell the true detection probability is the mean over its attempts of
``closed * (1 - miss_probability)`` (with a constant: the fraction of attempts whose
noise-free link closes, times ``1 - miss_probability``); the true RSSI is the
mean noise-free RSSI of the closing attempts.

The grid and model predictions at its centres are saved as
``truth/detection_grid.npz`` (see :meth:`TruthGrid.save`).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pandas as pd

from pipeline.evaluation.cells import CellGrid
from pipeline.evaluation.interface import check_sensor
from pipeline.evaluation.tables import require_columns
from scenes.fileio import atomic_save_npz, read_npz

__all__ = [
    "TruthGrid",
    "check_miss_probability",
    "detection_truth",
    "true_detected",
    "true_rssi_dbm",
]


def _gain(gain_db) -> np.ndarray:
    g = np.asarray(gain_db, dtype=np.float64)
    if np.any(np.isnan(g)):
        raise ValueError("gain_db contains NaN (use -inf for links that were not traced)")
    return g


def check_miss_probability(miss_probability, shape: tuple, what: str):
    """A miss probability as a float (scalar given) or a float64 array broadcast to ``shape``.

    Parameters
    ----------
    miss_probability : float or array_like
        Values in [0, 1).
    shape : tuple of int
        Shape an array must broadcast to (e.g. ``(rows,)``).
    what : str
        What an array holds, for the error message.

    Returns
    -------
    float or numpy.ndarray
        A Python float for a scalar (the constant path, unchanged numbers), else an
        array of ``shape``.
    """
    q = np.asarray(miss_probability, dtype=np.float64)
    if not np.all((q >= 0.0) & (q < 1.0)):
        raise ValueError(f"miss_probability must be in [0, 1), got {miss_probability!r}")
    if q.ndim == 0:
        return float(q)
    try:
        return np.broadcast_to(q, shape)
    except ValueError:
        raise ValueError(f"miss_probability has shape {q.shape}, expected a float or {what} "
                         f"{shape}") from None


def true_rssi_dbm(gain_db, budget) -> np.ndarray:
    """Noise-free reader RSSI [dBm] of links of one-way gain `gain_db` [dB].

    ``P_rx = P_tx + 2 G + M - 2 L_pol`` via ``budget.reader_rssi_dbm``; -inf
    where the gain is -inf (not traced).
    """
    g = _gain(gain_db)
    with np.errstate(invalid="ignore"):
        return np.asarray(budget.reader_rssi_dbm(g), dtype=np.float64)


def true_detected(gain_db, budget) -> np.ndarray:
    """True where the noise-free link closes both thresholds (``budget.detected``)."""
    g = _gain(gain_db)
    out = np.zeros(g.shape, dtype=bool)
    fin = np.isfinite(g)
    if fin.any():
        out[fin] = np.asarray(budget.detected(g[fin]), dtype=bool)
    return out


@dataclass(frozen=True)
class TruthGrid:
    """True detection probability and RSSI per (d, alpha) cell.

    Attributes
    ----------
    grid : CellGrid
        The cells.
    n_attempts : numpy.ndarray, shape (n_d, n_alpha), int64
        Read attempts whose true geometry lies in the cell.
    n_closed : numpy.ndarray, shape (n_d, n_alpha), int64
        Of those, attempts whose noise-free link closes.
    n_reads : numpy.ndarray, shape (n_d, n_alpha), int64
        Of those, attempts the simulated reader reported (``read`` column).
    p_detect : numpy.ndarray, shape (n_d, n_alpha), float64
        Mean of ``closed * (1 - miss_probability)`` over the cell's attempts
        (``n_closed / n_attempts * (1 - miss_probability)`` for a constant); NaN where no
        attempt.
    rssi_dbm : numpy.ndarray, shape (n_d, n_alpha), float64
        Mean noise-free RSSI of the closing attempts [dBm]; NaN where none.
    miss_probability : float
        Anti-collision miss probability used: the constant, or for a per-attempt one its
        mean over the closing attempts in the grid (0 where none closes).
    """

    grid: CellGrid
    n_attempts: np.ndarray
    n_closed: np.ndarray
    n_reads: np.ndarray
    p_detect: np.ndarray
    rssi_dbm: np.ndarray
    miss_probability: float

    def model_arrays(self, sensors: dict) -> dict[str, np.ndarray]:
        """Model predictions at the cell centres, keys ``<name>__fs_dbm``, ``<name>__fT``.

        Parameters
        ----------
        sensors : dict of str -> SensorLike
        """
        D, A = self.grid.centre_mesh()
        out = {}
        for name, s in sensors.items():
            s = check_sensor(s, f"sensor {name!r}")
            if "__" in name:
                raise ValueError(f"sensor name {name!r} must not contain '__'")
            out[f"{name}__fs_dbm"] = np.asarray(s.fs_dbm(D, A), dtype=np.float64)
            out[f"{name}__fT"] = np.asarray(s.fT(D, A), dtype=np.float64)
        return out

    def save(self, path, sensors: dict | None = None) -> Path:
        """Write ``truth/detection_grid.npz`` atomically.

        Keys: d_edges_m (n_d+1,), alpha_edges_rad (n_alpha+1,), d_centres_m,
        alpha_centres_rad, n_attempts, n_closed, n_reads, p_detect, rssi_dbm
        (n_d, n_alpha), grid (JSON string of :meth:`CellGrid.to_dict`),
        miss_probability (scalar), model_names (str array) and, per model name,
        ``<name>__fs_dbm`` and ``<name>__fT`` (n_d, n_alpha) at the cell centres.
        """
        import json

        path = Path(path)
        path.parent.mkdir(parents=True, exist_ok=True)
        extra = self.model_arrays(sensors or {})
        atomic_save_npz(
            path, d_edges_m=self.grid.d_edges_m, alpha_edges_rad=self.grid.alpha_edges_rad,
            d_centres_m=self.grid.d_centres_m, alpha_centres_rad=self.grid.alpha_centres_rad,
            n_attempts=self.n_attempts, n_closed=self.n_closed, n_reads=self.n_reads,
            p_detect=self.p_detect, rssi_dbm=self.rssi_dbm,
            grid=np.array(json.dumps(self.grid.to_dict())),
            miss_probability=np.array(self.miss_probability),
            model_names=np.array(sorted(sensors or {}), dtype=str), **extra,
        )
        return path

    @classmethod
    def load(cls, path) -> TruthGrid:
        """Read the truth part of a file written by :meth:`save`."""
        import json

        path = Path(path)
        with read_npz(path) as z:
            need = {"grid", "n_attempts", "n_closed", "n_reads", "p_detect", "rssi_dbm",
                    "miss_probability"}
            missing = sorted(need - set(z.files))
            if missing:
                raise ValueError(f"{path}: missing key(s) {missing}")
            grid = CellGrid.from_dict(json.loads(str(z["grid"])), f"{path}: grid")
            return cls(grid=grid, n_attempts=z["n_attempts"], n_closed=z["n_closed"],
                       n_reads=z["n_reads"], p_detect=z["p_detect"], rssi_dbm=z["rssi_dbm"],
                       miss_probability=float(z["miss_probability"]))


def detection_truth(
    reads: pd.DataFrame,
    budget,
    grid: CellGrid | None = None,
    miss_probability=0.0,
) -> TruthGrid:
    """Per-cell true detection probability and RSSI from read attempts at TRUE geometry.

    Parameters
    ----------
    reads : pandas.DataFrame
        reads.parquet-format table (columns read, d_true_m, alpha_true_rad, gain_db).
    budget : propagation.LinkBudget
        Supplies ``detected`` and ``reader_rssi_dbm``.
    grid : CellGrid, optional
        Cells; default ``CellGrid()`` (3 m, 0.25 m, 15 deg).
    miss_probability : float or array_like, shape (rows,), in [0, 1)
        Reader anti-collision miss probability of a closing attempt: one for all, or one
        per row of ``reads`` (the Gen2 reader's,
        :func:`pipeline.acquisition.singulation.miss_probability_of_attempts`).

    Returns
    -------
    TruthGrid
    """
    require_columns(reads, ("read", "d_true_m", "alpha_true_rad", "gain_db"), "reads")
    grid = CellGrid() if grid is None else grid
    q = check_miss_probability(miss_probability, (len(reads),), "one per row of reads")
    d = reads["d_true_m"].to_numpy(np.float64)
    a = reads["alpha_true_rad"].to_numpy(np.float64)
    g = reads["gain_db"].to_numpy(np.float64)
    closed = true_detected(g, budget)
    rssi = np.where(closed, true_rssi_dbm(np.where(closed, g, 0.0), budget), 0.0)
    n_att = grid.count(d, a).astype(np.int64)
    n_closed = grid.count(d, a, closed.astype(float)).astype(np.int64)
    n_reads = grid.count(d, a, reads["read"].to_numpy(bool).astype(float)).astype(np.int64)
    rssi_sum = grid.count(d, a, rssi)
    if np.ndim(q) == 0:
        with np.errstate(invalid="ignore", divide="ignore"):
            p = np.where(n_att > 0, n_closed / np.maximum(n_att, 1) * (1.0 - q), np.nan)
        q_used = float(q)
    else:
        p_sum = grid.count(d, a, closed * (1.0 - q))
        with np.errstate(invalid="ignore", divide="ignore"):
            p = np.where(n_att > 0, p_sum / np.maximum(n_att, 1), np.nan)
        in_grid = grid.index(d, a).valid & closed
        q_used = float(q[in_grid].mean()) if in_grid.any() else 0.0
    with np.errstate(invalid="ignore", divide="ignore"):
        rssi_mean = np.where(n_closed > 0, rssi_sum / np.maximum(n_closed, 1), np.nan)
    return TruthGrid(grid=grid, n_attempts=n_att, n_closed=n_closed, n_reads=n_reads,
                     p_detect=p, rssi_dbm=rssi_mean, miss_probability=q_used)
