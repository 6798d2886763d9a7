"""Joint tag-detection and signal-strength model after Joho, Plagemann & Burgard (2009).

Reference
---------
D. Joho, C. Plagemann and W. Burgard, "Modeling RFID signal strength and tag detection
for localization and mapping", Proc. IEEE International Conference on Robotics and
Automation (ICRA), 2009.

The paper's sensor model integrates the two things a UHF reader reports about a tag
relative to the antenna: whether it was detected and, if so, the received signal
strength. An observation ``z = (read, s)`` of a tag at position ``x`` in the antenna
frame has the likelihood

    p(z | x) = p(read | x) * p(s | x, read)            if read,
    p(z | x) = 1 - p(read | x)                          otherwise,

with a detection probability and a Gaussian RSSI distribution both learned from robot
data; the paper uses this likelihood to localise tags and the robot
(:meth:`Joho2009Model.log_likelihood`).

Reproduced
    The joint likelihood above; detection and RSSI models learned from the robot's own
    reads with its (MCL) poses; the per-position Gaussian of RSSI given a read.
Simplified / our choices (the paper's full text was not available to us; where it
leaves a choice open, or where we could not check it, we choose and say so)
    * The position relative to the antenna is binned into the pipeline's polar
      (d, alpha) cells (:class:`~pipeline.evaluation.cells.CellGrid`) so the inputs match
      the fuzzy model's; per cell the detection rate is reads / attempts and the RSSI a
      Gaussian with the cell's sample mean and standard deviation.
    * Cells without attempts take the detection rate of the nearest cell with attempts;
      cells with fewer than ``min_reads`` RSSI values take mean and standard deviation
      from the nearest cell with enough; standard deviations are floored at
      ``sigma_floor_db`` (the reader's RSSI quantisation) and probabilities at
      ``p_floor`` inside the likelihood (so one surprising read cannot veto a position).
    * Beyond the grid (d >= d_max) the detection probability is 0 and the RSSI that of
      the outermost cell at the same bearing.
    * The paper's environment- and tag-specific corrections are not reproduced: the
      SensorLike interface has no tag or map argument.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from pipeline.configschema import check_keys
from pipeline.evaluation.cells import CellGrid
from pipeline.sensormodels._common import Attempts, CompetitorModel, check_rssi_range, nearest_fill

__all__ = ["JOHO2009", "Joho2009Model", "fit_joho2009"]

JOHO2009 = "joho2009"
_LOG_SQRT_2PI = 0.5 * np.log(2.0 * np.pi)


@dataclass(frozen=True, eq=False)
class Joho2009Model(CompetitorModel):
    """Per-cell detection rate and Gaussian RSSI (see module doc).

    Attributes
    ----------
    grid : CellGrid
    n_attempts, n_reads : numpy.ndarray, shape (n_d, n_alpha), int64
        Attempts and reads per cell.
    n_rssi : numpy.ndarray, shape (n_d, n_alpha), int64
        Reads with a reported (finite) RSSI per cell.
    rssi_mean_dbm, rssi_std_db : numpy.ndarray, shape (n_d, n_alpha), float64
        Sample mean [dBm] and standard deviation (ddof = 1) [dB] of those RSSI values
        (0 where there are too few to define them).
    rssi_range_dbm : (float, float)
        Normalisation range of fs.
    min_reads : int
        Cells with fewer RSSI values borrow mean and deviation from the nearest cell.
    sigma_floor_db : float
        Floor on the RSSI standard deviation [dB].
    p_floor : float
        Detection probabilities are clipped to [p_floor, 1 - p_floor] in the likelihood.
    """

    grid: CellGrid
    n_attempts: np.ndarray
    n_reads: np.ndarray
    n_rssi: np.ndarray
    rssi_mean_dbm: np.ndarray
    rssi_std_db: np.ndarray
    rssi_range_dbm: tuple = (-80.0, -30.0)
    min_reads: int = 5
    sigma_floor_db: float = 0.5
    p_floor: float = 1e-3

    KIND = JOHO2009
    REFERENCE = ("Joho, Plagemann & Burgard, 'Modeling RFID signal strength and tag detection "
                 "for localization and mapping', ICRA 2009")
    DESCRIPTION = "per-(d, alpha)-cell detection rate and Gaussian RSSI; joint read likelihood"
    predicts_rssi = True

    def __post_init__(self) -> None:
        object.__setattr__(self, "rssi_range_dbm", check_rssi_range(self.rssi_range_dbm))
        shape = self.grid.shape
        for name in ("n_attempts", "n_reads", "n_rssi"):
            v = np.asarray(getattr(self, name), dtype=np.int64)
            if v.shape != shape or np.any(v < 0):
                raise ValueError(f"Joho2009Model: {name} must be non-negative with the grid's "
                                 f"shape {shape}, got {v.shape}")
            object.__setattr__(self, name, v)
        for name in ("rssi_mean_dbm", "rssi_std_db"):
            v = np.asarray(getattr(self, name), dtype=np.float64)
            if v.shape != shape or not np.all(np.isfinite(v)):
                raise ValueError(f"Joho2009Model: {name} must be finite with shape {shape}")
            object.__setattr__(self, name, v)
        if np.any(self.n_reads > self.n_attempts) or np.any(self.n_rssi > self.n_reads):
            raise ValueError("Joho2009Model: need n_rssi <= n_reads <= n_attempts in every cell")
        if int(self.min_reads) < 1:
            raise ValueError(f"Joho2009Model: min_reads must be >= 1, got {self.min_reads}")
        if not self.sigma_floor_db > 0:
            raise ValueError(f"Joho2009Model: sigma_floor_db must be > 0, got {self.sigma_floor_db}")
        if not 0 < self.p_floor < 0.5:
            raise ValueError(f"Joho2009Model: p_floor must be in (0, 0.5), got {self.p_floor}")
        if not self.n_rssi.any():
            raise ValueError("Joho2009Model: no read with an RSSI in any cell")
        seen = self.n_attempts > 0
        p = np.where(seen, self.n_reads / np.maximum(self.n_attempts, 1), 0.0)
        object.__setattr__(self, "_p", nearest_fill(p, seen))
        enough = self.n_rssi >= int(self.min_reads)
        if not enough.any():  # pool every read: one Gaussian for the whole grid
            n = self.n_rssi.sum()
            mu = float((self.n_rssi * self.rssi_mean_dbm).sum() / n)
            ss = ((self.n_rssi - 1).clip(0) * self.rssi_std_db ** 2
                  + self.n_rssi * (self.rssi_mean_dbm - mu) ** 2).sum()
            mu_t = np.full(shape, mu)
            sd_t = np.full(shape, np.sqrt(ss / max(n - 1, 1)))
        else:
            mu_t = nearest_fill(self.rssi_mean_dbm, enough)
            sd_t = nearest_fill(self.rssi_std_db, enough)
        object.__setattr__(self, "_mu", mu_t)
        object.__setattr__(self, "_sd", np.fmax(sd_t, float(self.sigma_floor_db)))

    # ------------------------------------------------------------------ lookup
    def _cells(self, d, a, clip_d: bool):
        if clip_d:  # beyond the grid: the outermost cell at the same bearing
            d = np.minimum(d, np.nextafter(self.grid.d_max_m, 0.0))
        return self.grid.index(d, a)

    def _detection(self, d, a):
        idx = self._cells(d, a, clip_d=False)
        return np.where(idx.valid, self._p[idx.i_d, idx.i_alpha], 0.0)

    def _rssi_dbm(self, d, a):
        idx = self._cells(d, a, clip_d=True)
        return self._mu[idx.i_d, idx.i_alpha]

    def _sigma_db(self, d, a):
        idx = self._cells(d, a, clip_d=True)
        return self._sd[idx.i_d, idx.i_alpha]

    def rssi_sigma_db(self, d, alpha) -> np.ndarray:
        """Standard deviation of the RSSI given a read [dB] (floored); broadcasts like :meth:`fT`."""
        return self._apply(self._sigma_db, d, alpha)

    def log_likelihood(self, d, alpha, read, rssi_dbm) -> np.ndarray:
        """log p(read, rssi | d, alpha), the paper's joint observation likelihood.

        Parameters
        ----------
        d, alpha : array_like
            Tag distance [m] and bearing [rad] in the antenna frame.
        read : array_like of bool
            Whether the tag was read.
        rssi_dbm : array_like
            RSSI of the read [dBm]; ignored where not read; NaN where read means "read,
            RSSI not reported" (detection term only).

        Returns
        -------
        numpy.ndarray
            All four inputs broadcast together; natural log; NaN where d or alpha is NaN.
        """
        d, a, r, s = np.broadcast_arrays(np.asarray(d, dtype=np.float64),
                                         np.asarray(alpha, dtype=np.float64),
                                         np.asarray(read), np.asarray(rssi_dbm, dtype=np.float64))
        if r.dtype != bool:
            if not np.all(np.isin(r, (0, 1))):
                raise ValueError("read must be boolean (or 0/1)")
            r = r.astype(bool)
        p = np.clip(self.fT(d, a), self.p_floor, 1.0 - self.p_floor)
        mu = self.expected_rssi_dbm(d, a)
        sd = self.rssi_sigma_db(d, a)
        has = r & np.isfinite(s)
        z = np.where(has, (s - mu) / sd, 0.0)
        gauss = np.where(has, -0.5 * z * z - np.log(sd) - _LOG_SQRT_2PI, 0.0)
        return np.where(r, np.log(p) + gauss, np.log1p(-p))

    # ------------------------------------------------------------- persistence
    def params_dict(self) -> dict:
        return {"grid": self.grid.to_dict(), "n_attempts": self.n_attempts.tolist(),
                "n_reads": self.n_reads.tolist(), "n_rssi": self.n_rssi.tolist(),
                "rssi_mean_dbm": self.rssi_mean_dbm.tolist(),
                "rssi_std_db": self.rssi_std_db.tolist(), "min_reads": int(self.min_reads),
                "sigma_floor_db": float(self.sigma_floor_db), "p_floor": float(self.p_floor)}

    @classmethod
    def from_params(cls, params: dict, rssi_range_dbm, where: str) -> Joho2009Model:
        keys = {"grid", "n_attempts", "n_reads", "n_rssi", "rssi_mean_dbm", "rssi_std_db",
                "min_reads", "sigma_floor_db", "p_floor"}
        check_keys(params, keys, where, required=keys)
        return cls(grid=CellGrid.from_dict(params["grid"], f"{where}: grid"),
                   **{k: np.asarray(params[k]) for k in
                      ("n_attempts", "n_reads", "n_rssi", "rssi_mean_dbm", "rssi_std_db")},
                   rssi_range_dbm=rssi_range_dbm, min_reads=int(params["min_reads"]),
                   sigma_floor_db=float(params["sigma_floor_db"]),
                   p_floor=float(params["p_floor"]))


def fit_joho2009(attempts: Attempts, rssi_range_dbm, grid: CellGrid | None = None, *,
                 min_reads: int = 5, sigma_floor_db: float = 0.5,
                 p_floor: float = 1e-3) -> Joho2009Model:
    """Count attempts, reads and RSSI moments per (d, alpha) cell.

    Parameters
    ----------
    attempts : Attempts
        Training attempts (MCL geometry); those outside the grid are ignored.
    rssi_range_dbm : (float, float)
    grid : CellGrid, optional
    min_reads, sigma_floor_db, p_floor
        See :class:`Joho2009Model`.
    """
    grid = CellGrid() if grid is None else grid
    att = attempts.within(grid.d_max_m)
    if len(att) == 0:
        raise ValueError("fit_joho2009: no attempts inside the grid")
    n_att = grid.count(att.d, att.alpha)
    n_read = grid.count(att.d, att.alpha, att.read.astype(float))
    has = att.has_rssi
    d, a, s = att.d[has], att.alpha[has], att.rssi[has]
    n = grid.count(d, a)
    mean = grid.count(d, a, s) / np.maximum(n, 1)
    # second pass about the cell mean: no cancellation in the variance
    idx = grid.index(d, a)
    dev2 = (s - mean[idx.i_d, idx.i_alpha]) ** 2
    var = grid.count(d, a, dev2) / np.maximum(n - 1, 1)
    std = np.where(n >= 2, np.sqrt(var), 0.0)
    return Joho2009Model(grid=grid, n_attempts=n_att.round().astype(np.int64),
                         n_reads=n_read.round().astype(np.int64),
                         n_rssi=n.round().astype(np.int64), rssi_mean_dbm=mean,
                         rssi_std_db=std, rssi_range_dbm=rssi_range_dbm, min_reads=min_reads,
                         sigma_floor_db=sigma_floor_db, p_floor=p_floor)
