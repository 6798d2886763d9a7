"""Detection model learned from robot data after Vorst & Zell (2008).

Reference
---------
P. Vorst and A. Zell, "Semi-autonomous learning of an RFID sensor model for mobile robot
self-localization", European Robotics Symposium (EUROS), 2008.

The paper records RFID reads and robot poses during an exploration run, learns from
them the probability of detecting a tag as a function of the tag's position relative
to the antenna with non-parametric density estimation, and tunes the estimator's
smoothing for localisation; it models detection only, no signal strength.

Reproduced
    Learning ``P(read | x)`` over the tag position ``x = (d cos alpha, d sin alpha)`` in
    the antenna's Cartesian frame from the robot's reads and (MCL) poses, as the ratio of
    kernel (Parzen-window) density estimates of the read and of all attempt positions,
    ``P(read | x) = P(read) p(x | read) / p(x) = sum_i K(x - x_i) r_i / sum_i K(x - x_i)``,
    tabulated on a Cartesian grid, the model the particle filter looks up; the smoothing
    is chosen from data; detection only.
Simplified / our choices (only the paper's abstract was available to us: it names two
non-parametric density estimators without our being able to check which; we offer the
histogram and a Gaussian Parzen window, as bandwidth 0 and > 0 of one estimator)
    * Binned kernel estimate: reads and attempts are counted on the grid (cells of
      ``cell_m``) and both count maps are convolved with an isotropic Gaussian of
      standard deviation ``bandwidth_m`` (``bandwidth_m = 0``: the plain histogram of
      detection rates); the table is their ratio with a prior of ``prior_weight``
      attempts at the overall detection rate, so cells far from any data tend to it.
    * The paper tunes its estimator for the localisation error of a particle filter; we
      pick the bandwidth among the candidates by ``n_folds``-fold cross-validated
      Bernoulli log-likelihood of the training attempts (no localisation loop here). The
      folds hold whole tags (:func:`~._common.group_folds`, the attempts' ``group``): a
      tag's attempts follow one another along the tour and are strongly correlated, so
      folds that split a tag score each attempt against its own neighbours in time and
      favour the least smoothing. Attempts without tag labels are taken as independent
      (one fold per attempt at random).
    * Outside the disc d < d_max (no training data) the probability is 0, as for the
      grid-count baseline.
    * No RSSI: ``fs = 1`` (so ``rho = fT``) and ``fs_dbm = NaN``; ``predicts_rssi`` is
      False so scoring can skip the RSSI comparison.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.ndimage import gaussian_filter

from pipeline.configschema import check_keys

from ._common import Attempts, CompetitorModel, check_rssi_range, group_folds

__all__ = ["VORST2008", "Vorst2008Model", "fit_vorst2008"]

VORST2008 = "vorst2008"
_P_CLIP = 1e-6  # probabilities in the cross-validation log-likelihood are clipped to this


@dataclass(frozen=True, eq=False)
class Vorst2008Model(CompetitorModel):
    """Detection probability tabulated on a Cartesian grid in the antenna frame.

    Attributes
    ----------
    d_max_m : float
        The grid spans [-d_max_m, d_max_m]^2 (x forward, y to the left) [m]; the model
        predicts 0 at d >= d_max_m.
    cell_m : float
        Cell size [m].
    table : numpy.ndarray, shape (n, n), float64
        P(read) per cell, ``table[ix, iy]``, ``ix = floor((x + d_max_m) / cell_m)``.
    bandwidth_m : float
        Chosen Gaussian kernel standard deviation [m] (0: histogram).
    rssi_range_dbm : (float, float)
        Kept for the SensorLike interface (the model predicts no RSSI).
    cv_bandwidths_m, cv_log_likelihood : tuple of float
        The candidates and their mean held-out log-likelihood per attempt.
    n_attempts : int
        Training attempts.
    cv_n_groups : int
        Tags the folds were grouped by (0: attempts without tag labels, folded one by one).
    """

    d_max_m: float
    cell_m: float
    table: np.ndarray
    bandwidth_m: float
    rssi_range_dbm: tuple = (-80.0, -30.0)
    cv_bandwidths_m: tuple = ()
    cv_log_likelihood: tuple = ()
    n_attempts: int = 0
    cv_n_groups: int = 0

    KIND = VORST2008
    REFERENCE = ("Vorst & Zell, 'Semi-autonomous learning of an RFID sensor model for mobile "
                 "robot self-localization', EUROS 2008")
    DESCRIPTION = "kernel-smoothed detection rate on a Cartesian antenna-frame grid; no RSSI"
    predicts_rssi = False

    def __post_init__(self) -> None:
        object.__setattr__(self, "rssi_range_dbm", check_rssi_range(self.rssi_range_dbm))
        for name in ("d_max_m", "cell_m"):
            v = float(getattr(self, name))
            if not (np.isfinite(v) and v > 0):
                raise ValueError(f"Vorst2008Model: {name} must be finite and > 0, got {v!r}")
            object.__setattr__(self, name, v)
        n = _n_cells(self.d_max_m, self.cell_m)
        t = np.asarray(self.table, dtype=np.float64)
        if t.shape != (n, n) or not np.all((t >= 0) & (t <= 1)):
            raise ValueError(f"Vorst2008Model: table must be ({n}, {n}) in [0, 1], got {t.shape}")
        object.__setattr__(self, "table", t)
        object.__setattr__(self, "bandwidth_m", float(self.bandwidth_m))
        object.__setattr__(self, "cv_bandwidths_m", tuple(float(v) for v in self.cv_bandwidths_m))
        object.__setattr__(self, "cv_log_likelihood",
                           tuple(float(v) for v in self.cv_log_likelihood))
        object.__setattr__(self, "n_attempts", int(self.n_attempts))
        object.__setattr__(self, "cv_n_groups", int(self.cv_n_groups))

    def _detection(self, d, a):
        ix, iy = _cell(d, a, self.d_max_m, self.cell_m)
        return np.where(d < self.d_max_m, self.table[ix, iy], 0.0)

    def params_dict(self) -> dict:
        return {"d_max_m": self.d_max_m, "cell_m": self.cell_m, "table": self.table.tolist(),
                "bandwidth_m": self.bandwidth_m, "cv_bandwidths_m": list(self.cv_bandwidths_m),
                "cv_log_likelihood": list(self.cv_log_likelihood),
                "n_attempts": self.n_attempts, "cv_n_groups": self.cv_n_groups}

    @classmethod
    def from_params(cls, params: dict, rssi_range_dbm, where: str) -> Vorst2008Model:
        req = {"d_max_m", "cell_m", "table", "bandwidth_m"}
        check_keys(params, req | {"cv_bandwidths_m", "cv_log_likelihood", "n_attempts",
                                  "cv_n_groups"}, where, required=req)
        return cls(d_max_m=float(params["d_max_m"]), cell_m=float(params["cell_m"]),
                   table=np.asarray(params["table"], dtype=np.float64),
                   bandwidth_m=float(params["bandwidth_m"]), rssi_range_dbm=rssi_range_dbm,
                   cv_bandwidths_m=tuple(params.get("cv_bandwidths_m", ())),
                   cv_log_likelihood=tuple(params.get("cv_log_likelihood", ())),
                   n_attempts=int(params.get("n_attempts", 0)),
                   cv_n_groups=int(params.get("cv_n_groups", 0)))


def _n_cells(d_max_m: float, cell_m: float) -> int:
    return int(np.ceil(2.0 * d_max_m / cell_m - 1e-9))


def _cell(d, a, d_max_m: float, cell_m: float):
    """Cartesian cell indices (clipped into the grid) of polar positions."""
    n = _n_cells(d_max_m, cell_m)
    ix = np.clip(np.floor((d * np.cos(a) + d_max_m) / cell_m).astype(np.int64), 0, n - 1)
    iy = np.clip(np.floor((d * np.sin(a) + d_max_m) / cell_m).astype(np.int64), 0, n - 1)
    return ix, iy


def _rate(reads: np.ndarray, att: np.ndarray, sigma_cells: float, p0: float,
          prior_weight: float) -> np.ndarray:
    if sigma_cells > 0:
        reads = gaussian_filter(reads, sigma_cells, mode="constant", cval=0.0, truncate=4.0)
        att = gaussian_filter(att, sigma_cells, mode="constant", cval=0.0, truncate=4.0)
    return np.clip((reads + prior_weight * p0) / (att + prior_weight), 0.0, 1.0)


def fit_vorst2008(attempts: Attempts, rssi_range_dbm, rng: np.random.Generator, *,
                  d_max_m: float, cell_m: float = 0.1, bandwidths_m=None, n_folds: int = 5,
                  prior_weight: float = 1.0) -> Vorst2008Model:
    """Kernel-smoothed detection-rate table, bandwidth by cross-validation (see module doc).

    Parameters
    ----------
    attempts : Attempts
        Training attempts; those with d >= `d_max_m` are ignored. Their ``group`` (tag),
        where given, keeps each tag's attempts in one fold.
    rssi_range_dbm : (float, float)
        Stored for the interface only.
    rng : numpy.random.Generator
        Assigns the tags (or attempts) to cross-validation folds.
    d_max_m, cell_m : float
        Grid extent and cell size [m].
    bandwidths_m : sequence of float, optional
        Candidate kernel standard deviations [m] (>= 0); default
        ``cell_m * (0, 0.5, 1, 1.5, 2, 3, 4, 6)``.
    n_folds : int
        Cross-validation folds (>= 2).
    prior_weight : float
        Pseudo-attempts at the overall detection rate added to every cell (> 0).
    """
    if not (cell_m > 0 and d_max_m > 0 and prior_weight > 0):
        raise ValueError("fit_vorst2008: d_max_m, cell_m and prior_weight must be > 0")
    if int(n_folds) < 2:
        raise ValueError(f"fit_vorst2008: n_folds must be >= 2, got {n_folds}")
    bws = (cell_m * np.array([0, 0.5, 1, 1.5, 2, 3, 4, 6]) if bandwidths_m is None
           else np.asarray(bandwidths_m, dtype=np.float64).ravel())
    if bws.size == 0 or np.any(~(bws >= 0)):
        raise ValueError(f"fit_vorst2008: bandwidths_m must be >= 0, got {bws}")
    att = attempts.within(d_max_m)
    if len(att) < int(n_folds):
        raise ValueError(f"fit_vorst2008: {len(att)} attempts for {n_folds} folds")
    n = _n_cells(d_max_m, cell_m)
    ix, iy = _cell(att.d, att.alpha, d_max_m, cell_m)
    flat = ix * n + iy
    r = att.read.astype(np.float64)
    if att.group is not None:
        n_groups = len(np.unique(att.group))
        fold = group_folds(att.group, n_folds, rng)
    else:  # independent attempts
        n_groups = 0
        fold = rng.permutation(len(att)) % int(n_folds)

    def counts(sel):
        a_ = np.bincount(flat[sel], minlength=n * n).reshape(n, n).astype(np.float64)
        r_ = np.bincount(flat[sel], weights=r[sel], minlength=n * n).reshape(n, n)
        return r_, a_

    scores = np.zeros(bws.size)
    for f in range(int(n_folds)):
        test = fold == f
        r_tr, a_tr = counts(~test)
        p0 = r_tr.sum() / max(a_tr.sum(), 1.0)
        for b, bw in enumerate(bws):
            p = np.clip(_rate(r_tr, a_tr, bw / cell_m, p0, prior_weight).ravel()[flat[test]],
                        _P_CLIP, 1.0 - _P_CLIP)
            scores[b] += np.sum(np.where(att.read[test], np.log(p), np.log1p(-p)))
    scores /= len(att)
    best = int(np.argmax(scores))
    r_all, a_all = counts(np.ones(len(att), bool))
    table = _rate(r_all, a_all, bws[best] / cell_m, r_all.sum() / a_all.sum(), prior_weight)
    return Vorst2008Model(d_max_m=d_max_m, cell_m=cell_m, table=table,
                          bandwidth_m=float(bws[best]), rssi_range_dbm=rssi_range_dbm,
                          cv_bandwidths_m=tuple(bws), cv_log_likelihood=tuple(scores),
                          n_attempts=len(att), cv_n_groups=n_groups)
