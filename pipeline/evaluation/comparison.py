"""Learned model against the propagation truth: RSSI, detection probability, rho.

Definitions (errors are ``model - truth``; see :mod:`.metrics`):

RSSI (:func:`rssi_vs_truth`)
    On read attempts whose noise-free link closes and whose true distance is
    below ``d_max_m``: ``sensor.fs_dbm(d_true, alpha_true)`` against the
    noise-free ``budget.reader_rssi_dbm(gain_db)`` [dB]: MAE, RMSE, bias, ...

Detection (:func:`detection_vs_truth`)
    Per (d, alpha) cell with at least ``min_attempts`` attempts:
    ``sensor.fT(cell centre)`` against :attr:`TruthGrid.p_detect` (MAE, RMSE,
    bias; cells weigh equally). Brier score of ``sensor.fT(d_true, alpha_true)``
    on the actual read outcomes of the attempts inside the grid, beside two
    references on the same attempts: the truth's own Brier score (p_detect of
    the attempt's cell; the floor set by the reader's randomness and the cell
    size) and the climatological one (the base read rate).

rho, the chapter's Fig. 6 (:func:`rho_points_truth`, :func:`rho_vs_truth`)
    At world points around an antenna pose with ray-traced gains,
    ``rho_true = fs_true * p_true`` with fs_true the noise-free RSSI normalised
    by the model's range (0 where the link does not close) and
    ``p_true = closed * (1 - miss_probability)`` (Gen2: :mod:`pipeline.acquisition.singulation`);
    the model's ``sensor.rho(d, alpha)`` at the points' (d, alpha) in the TRUE
    antenna frame. MAE, RMSE, Pearson correlation.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pandas as pd

from fuzzymodel import normalise_rssi
from pipeline.evaluation.cells import CellGrid
from pipeline.evaluation.geometry import antenna_frame_geometry
from pipeline.evaluation.interface import check_sensor, detection_probability, uses_tag_height
from pipeline.evaluation.metrics import ErrorStats, brier_score, error_stats, nan_to_none
from pipeline.evaluation.tables import require_columns
from pipeline.evaluation.truth import (
    TruthGrid,
    check_miss_probability,
    true_detected,
    true_rssi_dbm,
)
from scenes.fileio import atomic_save_npz, read_npz

__all__ = [
    "DetectionComparison",
    "RhoComparison",
    "RhoPoints",
    "RssiComparison",
    "closing_links",
    "cell_centre_fT",
    "detection_vs_truth",
    "rho_points_truth",
    "rho_vs_truth",
    "rssi_cell_mean_floor",
    "rssi_vs_truth",
]


@dataclass(frozen=True)
class RssiComparison:
    """Learned RSSI [dBm] against the noise-free ray-traced RSSI at the true poses.

    Attributes
    ----------
    stats : ErrorStats
        Of ``fs_dbm(d_true, alpha_true) - rssi_true_dbm`` [dB].
    n_rows : int
        Attempts compared (closed links with d_true < d_max_m).
    d_max_m : float
        Distance limit used [m].
    """

    stats: ErrorStats
    n_rows: int
    d_max_m: float

    def to_dict(self) -> dict:
        """JSON-able dict; NaN -> None."""
        return nan_to_none({**self.stats.to_dict(), "n_rows": self.n_rows,
                            "d_max_m": self.d_max_m, "unit": "dB"})


def closing_links(reads: pd.DataFrame, budget, d_max_m: float) -> np.ndarray:
    """The attempts an RSSI comparison scores: the noise-free link closes and the true
    distance is below ``d_max_m``; shape (n_rows,) bool."""
    require_columns(reads, ("d_true_m", "alpha_true_rad", "gain_db"), "reads")
    return (true_detected(reads["gain_db"].to_numpy(np.float64), budget)
            & (reads["d_true_m"].to_numpy(np.float64) < float(d_max_m)))


def rssi_vs_truth(reads: pd.DataFrame, sensor, budget, d_max_m: float = 3.0) -> RssiComparison:
    """Compare ``sensor.fs_dbm`` with the noise-free RSSI (see module doc).

    Parameters
    ----------
    reads : pandas.DataFrame
        reads.parquet-format table (d_true_m, alpha_true_rad, gain_db).
    sensor : SensorLike
    budget : propagation.LinkBudget
    d_max_m : float
        Only attempts with d_true_m < d_max_m (the models' training domain).

    Returns
    -------
    RssiComparison
    """
    sensor = check_sensor(sensor)
    keep = closing_links(reads, budget, d_max_m)
    g = reads["gain_db"].to_numpy(np.float64)
    d = reads["d_true_m"].to_numpy(np.float64)
    truth = true_rssi_dbm(g[keep], budget)
    pred = np.asarray(sensor.fs_dbm(d[keep], reads["alpha_true_rad"].to_numpy(np.float64)[keep]),
                      dtype=np.float64)
    return RssiComparison(error_stats(pred, truth), int(keep.sum()), float(d_max_m))


def rssi_cell_mean_floor(reads: pd.DataFrame, truth: TruthGrid, budget, d_max_m: float = 3.0,
                         min_count: int = 5) -> ErrorStats:
    """Error of the best possible (d, alpha) cell model: the truth's own cell mean.

    A sensor model of (d, alpha) alone predicts one RSSI per geometry, while the
    ray-traced RSSI at a given (d, alpha) still varies with where the antenna and tag
    are in the corridor (multipath fading). Predicting each link by the mean true RSSI
    of its (d, alpha) cell (``truth.rssi_dbm``) is the floor of that model family at the
    grid's resolution; :func:`rssi_vs_truth` errors near it mean the model has learned
    what (d, alpha) can tell.

    Parameters
    ----------
    reads : pandas.DataFrame
        reads.parquet-format table (d_true_m, alpha_true_rad, gain_db).
    truth : TruthGrid
        :func:`~.truth.detection_truth` of the same reads.
    budget : propagation.LinkBudget
    d_max_m : float
        Only attempts with d_true_m < d_max_m.
    min_count : int
        Cells with fewer closing links are left out (their mean is mostly the link itself).

    Returns
    -------
    ErrorStats
        Of ``cell mean - truth`` over the closing links in cells with >= min_count links.
    """
    keep = closing_links(reads, budget, d_max_m)
    g = reads["gain_db"].to_numpy(np.float64)
    d = reads["d_true_m"].to_numpy(np.float64)
    idx = truth.grid.index(d[keep], reads["alpha_true_rad"].to_numpy(np.float64)[keep])
    ok = idx.valid & (truth.n_closed.ravel()[np.maximum(idx.flat, 0)] >= int(min_count))
    cell_mean = truth.rssi_dbm.ravel()[np.maximum(idx.flat, 0)]
    return error_stats(cell_mean[ok], true_rssi_dbm(g[keep][ok], budget))


@dataclass(frozen=True)
class DetectionComparison:
    """Learned fT against the true detection probability.

    Attributes
    ----------
    cells : ErrorStats
        Of ``fT(centre) - p_detect`` over cells with >= min_attempts attempts.
    n_cells : int
        Cells compared.
    min_attempts : int
        Threshold used.
    brier : float
        Brier score of fT at the true geometry on the read outcomes.
    brier_truth : float
        Brier score of the cell's true p_detect on the same outcomes.
    brier_climatology : float
        Brier score of the constant base rate on the same outcomes.
    n_attempts : int
        Attempts inside the grid used by the Brier scores.
    """

    cells: ErrorStats
    n_cells: int
    min_attempts: int
    brier: float
    brier_truth: float
    brier_climatology: float
    n_attempts: int

    def to_dict(self) -> dict:
        """JSON-able dict; NaN -> None."""
        return nan_to_none({**self.cells.to_dict(), "n_cells": self.n_cells,
                            "min_attempts": self.min_attempts, "brier": self.brier,
                            "brier_truth": self.brier_truth,
                            "brier_climatology": self.brier_climatology,
                            "n_attempts": self.n_attempts})


def cell_centre_fT(sensor, grid: CellGrid, cells=None, d_m=None,  # noqa: N802
                   alpha_rad=None, dz_m=None) -> np.ndarray:
    """The model's detection probability at the cells ``cells`` of `grid` (a bool mask of
    shape (n_d, n_alpha); None: every cell, flat row-major): ``fT`` at the cell centre;
    for a model that uses the tag's height above the antenna
    (:func:`~.interface.uses_tag_height`) given the links ``(d_m, alpha_rad, dz_m)``, the
    mean over each cell's links of the model at the cell centre and the link's height
    (cells without a link: ``fT`` at the centre), the height mix the cell's truth is a
    mean over."""
    D, A = grid.centre_mesh()
    sel = np.ones(D.shape, bool) if cells is None else np.asarray(cells, bool)
    out = np.asarray(sensor.fT(D[sel], A[sel]), dtype=np.float64)
    if dz_m is None or not uses_tag_height(sensor):
        return out
    idx = grid.index(np.asarray(d_m, np.float64), np.asarray(alpha_rad, np.float64))
    cell = idx.flat[idx.valid]
    dz = np.broadcast_to(np.asarray(dz_m, np.float64), idx.valid.shape)[idx.valid]
    p = np.asarray(detection_probability(sensor, D.ravel()[cell], A.ravel()[cell], dz), np.float64)
    n = np.bincount(cell, minlength=D.size)[sel.ravel()]
    s = np.bincount(cell, weights=p, minlength=D.size)[sel.ravel()]
    return np.where(n > 0, s / np.maximum(n, 1), out)


def detection_vs_truth(
    reads: pd.DataFrame, sensor, truth: TruthGrid, min_attempts: int = 20, dz_m=None
) -> DetectionComparison:
    """Compare ``sensor.fT`` with the true detection probability (see module doc).

    Parameters
    ----------
    reads : pandas.DataFrame
        The table `truth` was built from (read, d_true_m, alpha_true_rad).
    sensor : SensorLike
    truth : TruthGrid
        From :func:`~.truth.detection_truth`.
    min_attempts : int
        Cells with fewer attempts are not compared.
    dz_m : array_like (len(reads),), optional
        Each row's tag height above its (true) antenna [m]: a model that uses it is
        scored with it (:func:`~.interface.detection_probability` per row, and
        :func:`cell_centre_fT` per cell); other models ignore it.

    Returns
    -------
    DetectionComparison
    """
    sensor = check_sensor(sensor)
    require_columns(reads, ("read", "d_true_m", "alpha_true_rad"), "reads")
    if int(min_attempts) < 1:
        raise ValueError(f"min_attempts must be >= 1, got {min_attempts!r}")
    grid: CellGrid = truth.grid
    ok = truth.n_attempts >= int(min_attempts)
    d = reads["d_true_m"].to_numpy(np.float64)
    a = reads["alpha_true_rad"].to_numpy(np.float64)
    dz = None if dz_m is None else np.broadcast_to(np.asarray(dz_m, np.float64), d.shape)
    ft_cells = cell_centre_fT(sensor, grid, ok, d, a, dz)
    cells = error_stats(ft_cells, truth.p_detect[ok])
    idx = grid.index(d, a)
    outcome = reads["read"].to_numpy(bool)[idx.valid]
    ft_rows = np.asarray(detection_probability(sensor, d[idx.valid], a[idx.valid],
                                               None if dz is None else dz[idx.valid]),
                         dtype=np.float64)
    p_rows = truth.p_detect.ravel()[idx.flat[idx.valid]]
    base = float(outcome.mean()) if outcome.size else float("nan")
    return DetectionComparison(
        cells=cells, n_cells=int(ok.sum()), min_attempts=int(min_attempts),
        brier=brier_score(ft_rows, outcome), brier_truth=brier_score(p_rows, outcome),
        brier_climatology=brier_score(np.full(outcome.shape, base), outcome),
        n_attempts=int(outcome.size),
    )


@dataclass(frozen=True)
class RhoPoints:
    """Truth at world points around one antenna pose (the chapter's Fig. 6).

    Attributes
    ----------
    antenna_pose : numpy.ndarray, shape (6,)
        True antenna pose [x, y, z, yaw, pitch, roll] (m, rad).
    points_m : numpy.ndarray, shape (k, 3)
        World points [m].
    d_m, alpha_rad : numpy.ndarray, shape (k,)
        Points in the antenna frame [m], [rad].
    gain_db : numpy.ndarray, shape (k,)
        Ray-traced one-way gain [dB] (-inf: not traced).
    fs_true : numpy.ndarray, shape (k,)
        Noise-free RSSI normalised by `rssi_range_dbm`, 0 where the link does not close.
    p_true : numpy.ndarray, shape (k,)
        ``closed * (1 - miss_probability)``.
    rho_true : numpy.ndarray, shape (k,)
        ``fs_true * p_true``.
    rssi_range_dbm : tuple of float
        Normalisation range [dBm].
    grid_shape : tuple of int or None
        (n_d, n_alpha) if the points are a polar grid (row-major), else None.
    """

    antenna_pose: np.ndarray
    points_m: np.ndarray
    d_m: np.ndarray
    alpha_rad: np.ndarray
    gain_db: np.ndarray
    fs_true: np.ndarray
    p_true: np.ndarray
    rho_true: np.ndarray
    rssi_range_dbm: tuple
    grid_shape: tuple | None = None

    def save(self, path, sensors: dict | None = None) -> Path:
        """Write ``truth/rho_pose_<i>.npz`` atomically: every attribute, plus
        ``model_names`` and, per model, ``<name>__rho`` (k,) = sensor.rho(d, alpha)."""
        path = Path(path)
        path.parent.mkdir(parents=True, exist_ok=True)
        extra = {}
        for name, s in (sensors or {}).items():
            s = check_sensor(s, f"sensor {name!r}")
            extra[f"{name}__rho"] = np.asarray(s.rho(self.d_m, self.alpha_rad), dtype=np.float64)
        atomic_save_npz(path, antenna_pose=self.antenna_pose, points_m=self.points_m, d_m=self.d_m,
                 alpha_rad=self.alpha_rad, gain_db=self.gain_db, fs_true=self.fs_true,
                 p_true=self.p_true, rho_true=self.rho_true,
                 rssi_range_dbm=np.asarray(self.rssi_range_dbm, dtype=np.float64),
                 grid_shape=np.asarray(self.grid_shape or (0, 0), dtype=np.int64),
                 model_names=np.array(sorted(sensors or {}), dtype=str), **extra)
        return path

    @classmethod
    def load(cls, path) -> RhoPoints:
        """Read the truth part of a file written by :meth:`save`."""
        path = Path(path)
        with read_npz(path) as z:
            need = {"antenna_pose", "points_m", "d_m", "alpha_rad", "gain_db", "fs_true",
                    "p_true", "rho_true", "rssi_range_dbm", "grid_shape"}
            missing = sorted(need - set(z.files))
            if missing:
                raise ValueError(f"{path}: missing key(s) {missing}")
            shape = tuple(int(v) for v in z["grid_shape"])
            return cls(**{k: z[k] for k in need - {"rssi_range_dbm", "grid_shape"}},
                       rssi_range_dbm=tuple(float(v) for v in z["rssi_range_dbm"]),
                       grid_shape=shape if all(shape) else None)


def rho_points_truth(
    antenna_pose,
    points_m,
    gain_db,
    budget,
    rssi_range_dbm,
    miss_probability=0.0,
    grid_shape: tuple | None = None,
) -> RhoPoints:
    """True rho at `points_m` seen from `antenna_pose` (see module doc).

    Parameters
    ----------
    antenna_pose : array_like, shape (4,) or (6,)
        True antenna pose [x, y, z, yaw(, pitch, roll)].
    points_m : array_like, shape (k, 3)
        World points [m] (e.g. tag-like points traced with propagation.trace_links).
    gain_db : array_like, shape (k,)
        Their one-way gains [dB] from that pose (-inf: not traced).
    budget : propagation.LinkBudget
    rssi_range_dbm : (float, float)
        Normalisation range; use the sensor model's.
    miss_probability : float or array_like, shape (k,)
        Anti-collision miss probability of a closing link in [0, 1): one for the pose
        (the ``"fixed"`` reader's constant, or the Gen2 reader's at this pose), or one per
        point.
    grid_shape : (int, int), optional
        (n_d, n_alpha) when the points are a row-major polar grid (for the figure).

    Returns
    -------
    RhoPoints
    """
    pose = np.asarray(antenna_pose, dtype=np.float64).ravel()
    if pose.size == 4:
        pose = np.concatenate([pose, [0.0, 0.0]])
    if pose.size != 6:
        raise ValueError(f"antenna_pose must have 4 or 6 entries, got {pose.size}")
    pts = np.asarray(points_m, dtype=np.float64).reshape(-1, 3)
    g = np.asarray(gain_db, dtype=np.float64).ravel()
    if g.shape[0] != pts.shape[0]:
        raise ValueError(f"gain_db has {g.shape[0]} entries for {pts.shape[0]} points")
    if grid_shape is not None and int(np.prod(grid_shape)) != pts.shape[0]:
        raise ValueError(f"grid_shape {grid_shape} does not match {pts.shape[0]} points")
    q = check_miss_probability(miss_probability, (pts.shape[0],), "one per point")
    geo = antenna_frame_geometry(pose[None], pts)
    closed = true_detected(g, budget)
    rssi = true_rssi_dbm(np.where(closed, g, 0.0), budget)
    fs = np.where(closed, normalise_rssi(rssi, rssi_range_dbm), 0.0)
    p = closed * (1.0 - q)
    return RhoPoints(antenna_pose=pose, points_m=pts, d_m=geo.d_m[0], alpha_rad=geo.alpha_rad[0],
                     gain_db=g, fs_true=fs, p_true=p.astype(np.float64), rho_true=fs * p,
                     rssi_range_dbm=tuple(float(v) for v in rssi_range_dbm),
                     grid_shape=None if grid_shape is None else tuple(int(v) for v in grid_shape))


@dataclass(frozen=True)
class RhoComparison:
    """Learned rho against true rho over the Fig. 6 points.

    Attributes
    ----------
    stats : ErrorStats
        Of ``rho_model - rho_true`` over all points of all poses (correlation included).
    per_pose : list of ErrorStats
        The same per antenna pose, in input order.
    """

    stats: ErrorStats
    per_pose: list

    def to_dict(self) -> dict:
        """JSON-able dict; NaN -> None."""
        return nan_to_none({**self.stats.to_dict(),
                            "per_pose": [s.to_dict() for s in self.per_pose]})


def rho_vs_truth(rho_points, sensor) -> RhoComparison:
    """Compare ``sensor.rho`` with :attr:`RhoPoints.rho_true` over one or more poses.

    Parameters
    ----------
    rho_points : RhoPoints or sequence of RhoPoints
    sensor : SensorLike

    Returns
    -------
    RhoComparison
    """
    sensor = check_sensor(sensor)
    items = [rho_points] if isinstance(rho_points, RhoPoints) else list(rho_points)
    preds, truths, per = [], [], []
    for rp in items:
        pred = np.asarray(sensor.rho(rp.d_m, rp.alpha_rad), dtype=np.float64)
        preds.append(pred)
        truths.append(rp.rho_true)
        per.append(error_stats(pred, rp.rho_true))
    if not items:
        return RhoComparison(error_stats([], []), [])
    return RhoComparison(error_stats(np.concatenate(preds), np.concatenate(truths)), per)
