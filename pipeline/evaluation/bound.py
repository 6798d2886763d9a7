"""An oracle bound on the RSSI error of any (d, alpha) cell model, and a model's excess.

The bound. On a set of held-out links with noise-free RSSI ``y_i`` in (d, alpha) cells
``c(i)``, the function constant on each cell with the least squared error *on these
links* is the links' own cell mean ``ybar_c``; its RMSE

    B = sqrt(mean_i (y_i - ybar_c(i))^2)

is therefore a lower bound on the RMSE of every function constant on those cells, scored
on the same links (:func:`cell_mean_bound`). For the MAE the least constant per cell is
the cell's *median*, not its mean (a mean's MAE can be beaten by the median's):
:attr:`CellMeanBound.mae_db` is the cell medians' MAE, the MAE bound. It is an oracle (it uses the held-out truth
itself), not a model. A model that varies within a cell can beat it only by resolving
structure inside the cells; that the cells bound a smooth model is an approximation that
improves as the cells shrink, while the bound itself falls with the cell size (down to 0
when each link has a cell of its own), so :func:`bound_by_cell_size` shows it at several
sizes. Only cells holding at least ``min_count`` links take part (a cell of one link is
its own mean).

The excess (:func:`excess_over_bound`). For predictions ``f_i`` on the same links,
exactly (the cross terms vanish because deviations from a cell mean sum to 0 in the cell)

    mean (y - f)^2 = B^2 + mean_i (fbar_c(i) - ybar_c(i))^2
                         + mean_i [(f_i - fbar_c(i))^2 - 2 (y_i - ybar_c(i)) (f_i - fbar_c(i))],

``fbar_c`` the model's mean over the cell's links: the *between-cell* term (the model's
cell means against the truth's) is >= 0 by construction, the *within-cell* term is signed
(negative: the model follows the truth inside the cells, which no cell model can).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import pandas as pd

from pipeline.evaluation.cells import CellGrid
from pipeline.evaluation.comparison import closing_links
from pipeline.evaluation.truth import true_rssi_dbm

__all__ = ["BoundExcess", "CellMeanBound", "bound_by_cell_size", "cell_mean_bound",
           "excess_over_bound"]


@dataclass(frozen=True)
class CellMeanBound:
    """The held-out truth's own (d, alpha) cell means on its own links (module doc).

    Attributes
    ----------
    grid : CellGrid
        The cells.
    min_count : int
        Cells with fewer links were left out.
    rows : numpy.ndarray (n_rows,), bool
        Rows of the reads table that are the bound's links.
    cell : numpy.ndarray (n_links,), int64
        Each link's flat cell index.
    truth_dbm : numpy.ndarray (n_links,), float64
        Noise-free RSSI of each link [dBm].
    cell_mean_dbm : numpy.ndarray (n_links,), float64
        Its cell's mean of ``truth_dbm`` over the links [dBm].
    """

    grid: CellGrid
    min_count: int
    rows: np.ndarray
    cell: np.ndarray
    truth_dbm: np.ndarray
    cell_mean_dbm: np.ndarray

    @property
    def n_links(self) -> int:
        """Links of the bound."""
        return int(self.truth_dbm.size)

    @property
    def n_cells(self) -> int:
        """Cells of the bound."""
        return int(np.unique(self.cell).size)

    @property
    def rmse_db(self) -> float:
        """The bound B [dB] (NaN without links)."""
        if self.n_links == 0:
            return float("nan")
        return float(np.sqrt(np.mean((self.truth_dbm - self.cell_mean_dbm) ** 2)))

    @property
    def mae_db(self) -> float:
        """The MAE bound [dB]: each link against its cell's median of ``truth_dbm`` (the
        constant with the least absolute error in a cell; NaN without links)."""
        if self.n_links == 0:
            return float("nan")
        return float(np.mean(np.abs(self.truth_dbm - _cell_medians(self.truth_dbm, self.cell))))

    def to_dict(self) -> dict:
        """JSON-able summary: ``rmse_db``, ``mae_db``, ``n_links``, ``n_cells``, the cell size."""
        return {"rmse_db": self.rmse_db, "mae_db": self.mae_db, "n_links": self.n_links, "n_cells": self.n_cells,
                "d_bin_m": self.grid.d_bin_m, "alpha_bin_deg": self.grid.alpha_bin_deg,
                "min_count": self.min_count}


def _cell_means(values: np.ndarray, cell: np.ndarray) -> np.ndarray:
    """Per item, the mean of ``values`` over the items of its cell."""
    _, inv, count = np.unique(cell, return_inverse=True, return_counts=True)
    inv = inv.reshape(-1)
    return (np.bincount(inv, weights=values) / count)[inv]


def _cell_medians(values: np.ndarray, cell: np.ndarray) -> np.ndarray:
    """Per item, the median of ``values`` over the items of its cell."""
    med = pd.Series(values).groupby(np.asarray(cell)).transform("median")
    return med.to_numpy(np.float64)


def cell_mean_bound(reads: pd.DataFrame, grid: CellGrid, budget, *, d_max_m: float,
                    min_count: int = 5) -> CellMeanBound:
    """The oracle bound of (d, alpha) cell models on the closing links of ``reads``.

    Parameters
    ----------
    reads : pandas.DataFrame
        reads.parquet-format table (d_true_m, alpha_true_rad, gain_db): the held-out links.
    grid : CellGrid
        The cells (true geometry).
    budget : propagation.LinkBudget
        Closing threshold and the noise-free RSSI of a gain.
    d_max_m : float
        Only links with ``d_true_m < d_max_m`` [m] (the models' training domain).
    min_count : int
        Cells with fewer closing links are left out (>= 2: a lone link is its own mean).

    Returns
    -------
    CellMeanBound
    """
    if int(min_count) < 2:
        raise ValueError(f"cell_mean_bound: min_count must be >= 2, got {min_count}")
    keep = closing_links(reads, budget, d_max_m)
    idx = grid.index(reads["d_true_m"].to_numpy(np.float64),
                     reads["alpha_true_rad"].to_numpy(np.float64))
    keep &= idx.valid
    cells, count = np.unique(idx.flat[keep], return_counts=True)
    full = cells[count >= int(min_count)]
    keep &= np.isin(idx.flat, full)
    cell = idx.flat[keep].astype(np.int64)
    truth = np.asarray(true_rssi_dbm(reads["gain_db"].to_numpy(np.float64)[keep], budget),
                       dtype=np.float64)
    return CellMeanBound(grid, int(min_count), keep, cell, truth,
                         _cell_means(truth, cell) if truth.size else truth.copy())


@dataclass(frozen=True)
class BoundExcess:
    """A model's RMSE on a bound's links, split as in the module doc.

    Attributes
    ----------
    rmse_db : float
        The model's RMSE on the bound's links [dB].
    bound_db : float
        The bound B [dB].
    between_cells_db : float
        ``sqrt`` of the between-cell term (>= 0): its cell means against the truth's [dB].
    within_cells_db2 : float
        The within-cell term [dB^2], signed.
    """

    rmse_db: float
    bound_db: float
    between_cells_db: float
    within_cells_db2: float

    def to_dict(self) -> dict:
        return {"rmse_db": self.rmse_db, "bound_db": self.bound_db,
                "between_cells_db": self.between_cells_db,
                "within_cells_db2": self.within_cells_db2}


def excess_over_bound(bound: CellMeanBound, predicted_dbm) -> BoundExcess:
    """Split the RMSE of predictions on the bound's links (module doc).

    Parameters
    ----------
    bound : CellMeanBound
    predicted_dbm : array_like (n_links,)
        The model's RSSI at each of the bound's links [dBm] (finite).

    Returns
    -------
    BoundExcess
    """
    f = np.asarray(predicted_dbm, dtype=np.float64).reshape(-1)
    if f.shape != bound.truth_dbm.shape or not np.all(np.isfinite(f)):
        raise ValueError(f"excess_over_bound: need {bound.n_links} finite predictions, "
                         f"got shape {f.shape}")
    if bound.n_links == 0:
        nan = float("nan")
        return BoundExcess(nan, nan, nan, nan)
    y, ybar = bound.truth_dbm, bound.cell_mean_dbm
    fbar = _cell_means(f, bound.cell)
    mse = float(np.mean((y - f) ** 2))
    between = float(np.mean((fbar - ybar) ** 2))
    b2 = bound.rmse_db ** 2
    return BoundExcess(float(np.sqrt(mse)), bound.rmse_db, float(np.sqrt(between)),
                       mse - b2 - between)


def bound_by_cell_size(reads: pd.DataFrame, grid: CellGrid, budget, *, d_max_m: float,
                       min_count: int = 5, scales=(0.5, 1.0, 2.0, 4.0),
                       models: dict | None = None) -> list[dict]:
    """The bound at cells ``scale`` times the grid's in d and alpha, with the models'
    RMSE on each bound's links.

    Parameters
    ----------
    reads, grid, budget, d_max_m, min_count
        As :func:`cell_mean_bound`.
    scales : sequence of float
        Cell-size factors (> 0) applied to ``grid.d_bin_m`` and ``grid.alpha_bin_deg``.
    models : dict of str -> SensorLike, optional
        Models whose ``fs_dbm`` at the links' true geometry is scored on each bound's links.

    Returns
    -------
    list of dict
        Per scale: :meth:`CellMeanBound.to_dict` plus ``scale`` and
        ``<model>_rmse_db`` per model.
    """
    out = []
    for s in scales:
        if not float(s) > 0:
            raise ValueError(f"bound_by_cell_size: scales must be > 0, got {s!r}")
        g = CellGrid(d_max_m=grid.d_max_m, d_bin_m=min(grid.d_bin_m * float(s), grid.d_max_m),
                     alpha_bin_deg=min(grid.alpha_bin_deg * float(s), 360.0))
        b = cell_mean_bound(reads, g, budget, d_max_m=d_max_m, min_count=min_count)
        row = {"scale": float(s), **b.to_dict()}
        for name, m in (models or {}).items():
            if not b.n_links:  # no cell holds min_count links: nothing to score (a fuzzy
                row[f"{name}_rmse_db"] = float("nan")  # model refuses an empty input)
                continue
            sel = reads.loc[b.rows]
            pred = np.asarray(m.fs_dbm(sel["d_true_m"].to_numpy(np.float64),
                                       sel["alpha_true_rad"].to_numpy(np.float64)), np.float64)
            row[f"{name}_rmse_db"] = float(np.sqrt(np.mean((pred - b.truth_dbm) ** 2)))
        out.append(row)
    return out
