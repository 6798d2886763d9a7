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
    Learning ``P(read | x)`` over the tag position on the ground plane, ``x = (r cos alpha,
    r sin alpha)`` with ``r`` the HORIZONTAL range from the antenna to the tag and alpha
    its bearing (a robot on a floor localises in the plane), from the robot's reads and
    (MCL) poses, as the ratio of kernel (Parzen-window) density estimates of the read and
    of all attempt positions,
    ``P(read | x) = P(read) p(x | read) / p(x) = sum_i K(x - x_i) r_i / sum_i K(x - x_i)``,
    tabulated on a Cartesian grid, the model the particle filter looks up; the smoothing
    is chosen from data; detection only.
What the model sees
    Fitting: each attempt's horizontal range ``r = sqrt(d^2 - dz^2)`` from its 3-D range d
    and its tag's height above the antenna dz (the link table's tag height less its
    antenna's, :func:`~._common.tag_height_differences`; an attempt without one is an
    error, not a tag in the antenna's plane). Using d itself for r would put a tag
    0.9 m above the antenna at 1 m horizontally 35 % too far out on the grid.
    Prediction where the tag's height is known (the paper's model):
    :meth:`Vorst2008Model.fT_at_height` ``(d, alpha, dz)`` looks the ground-plane table up
    at ``r = sqrt(d^2 - dz^2)``, 0 at d >= d_max_m. Every caller that knows the height
    goes through it (:func:`pipeline.evaluation.interface.detection_probability`, which
    gives any other model plain ``fT``): the tag localiser (each candidate's height less
    the slot antenna's), the robot filter (each mapped tag's height less the particle's
    antenna's) and the held-out scores (each link's tag height less its true antenna's:
    the Brier score per link; the cell MAE's cell prediction is the mean over the cell's
    held-out links of the table at the cell centre and each link's height).
    Prediction where it is not (``fT(d, alpha)``: the truth grids' cell centres over
    (d, alpha), the surfaces of the figures, the Fig. 6 view): the ground-plane table
    averaged over the tag heights of the model's own training link table at that range,
    ``fT(d, alpha) = sum_k w_k(d) P(read | sqrt(d^2 - dz_k^2), alpha)``, ``w_k(d)`` the share
    of the training attempts in d's range bin (of ``cell_m``; all bins pooled where it is
    empty) whose height difference falls in bin k (0.1 m), over the bins with
    ``|dz_k| <= d`` (a range shorter than every such height: the antenna's own cell). It
    is tabulated at load on a polar grid (``cell_m`` / 5 in range, 0.5 deg in bearing)
    and looked up. Feeding a caller that knows the height this mix instead would blur the
    competitor's model over heights it could tell apart.
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
    * Outside the disc d < d_max (3-D range: no training data) the probability is 0, as
      for the grid-count baseline.
    * An antenna tilted out of the horizontal measures alpha in its own frame; the
      ground plane is then that frame's (the default robot's antennas are not tilted).
    * No RSSI: ``fs = 1`` (so ``rho = fT``) and ``fs_dbm = NaN``; ``predicts_rssi`` is
      False so scoring can skip the RSSI comparison.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.ndimage import gaussian_filter

from pipeline.configschema import check_keys
from pipeline.sensormodels._common import Attempts, CompetitorModel, check_rssi_range, group_folds

__all__ = ["VORST2008", "Vorst2008Model", "fit_vorst2008"]

VORST2008 = "vorst2008"
_P_CLIP = 1e-6  # probabilities in the cross-validation log-likelihood are clipped to this
#: Bin width of the training attempts' tag heights above the antenna [m].
DZ_BIN_M = 0.1
#: The polar lookup table of fT(d, alpha): range step (in cells) and bearing bins.
_POLAR_D_PER_CELL = 5
_POLAR_N_ALPHA = 720


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
        P(read) per ground-plane cell, ``table[ix, iy]``, ``ix = floor((x + d_max_m) /
        cell_m)``, x = r cos alpha with r the horizontal range.
    dz_centres_m : numpy.ndarray, shape (k,), float64
        Centres of the bins of the training tags' heights above the antenna [m].
    dz_weights : numpy.ndarray, shape (n_d, k), float64
        Training attempts per (3-D range bin of ``cell_m``, height bin): the height mix
        :meth:`fT` averages the ground-plane table over (module docstring).
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
    dz_centres_m: np.ndarray
    dz_weights: np.ndarray
    rssi_range_dbm: tuple = (-80.0, -30.0)
    cv_bandwidths_m: tuple = ()
    cv_log_likelihood: tuple = ()
    n_attempts: int = 0
    cv_n_groups: int = 0

    KIND = VORST2008
    REFERENCE = ("Vorst & Zell, 'Semi-autonomous learning of an RFID sensor model for mobile "
                 "robot self-localization', EUROS 2008")
    DESCRIPTION = ("kernel-smoothed detection rate on a Cartesian grid of the antenna's ground "
                   "plane (horizontal range) at the tag's height where known, else averaged "
                   "over the training tag heights; no RSSI")
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
        c = np.asarray(self.dz_centres_m, dtype=np.float64).reshape(-1)
        w = np.asarray(self.dz_weights, dtype=np.float64)
        n_d = _n_range_bins(self.d_max_m, self.cell_m)
        if (c.size == 0 or not np.isfinite(c).all() or w.shape != (n_d, c.size)
                or not np.all(w >= 0) or not w.sum() > 0):
            raise ValueError(f"Vorst2008Model: dz_centres_m (k,) finite and dz_weights ({n_d}, k) "
                             f">= 0 with some weight, got {c.shape} and {w.shape}")
        object.__setattr__(self, "dz_centres_m", c)
        object.__setattr__(self, "dz_weights", w)
        object.__setattr__(self, "_polar", self._polar_table())
        object.__setattr__(self, "bandwidth_m", float(self.bandwidth_m))
        object.__setattr__(self, "cv_bandwidths_m", tuple(float(v) for v in self.cv_bandwidths_m))
        object.__setattr__(self, "cv_log_likelihood",
                           tuple(float(v) for v in self.cv_log_likelihood))
        object.__setattr__(self, "n_attempts", int(self.n_attempts))
        object.__setattr__(self, "cv_n_groups", int(self.cv_n_groups))

    def ground_plane_fT(self, r, alpha) -> np.ndarray:  # noqa: N802 - the chapter's name
        """The ground-plane table at horizontal range ``r`` [m] and bearing ``alpha`` [rad]
        (broadcast; 0 at r >= d_max_m): the paper's model, for a caller that knows the
        tag's height."""
        return np.clip(self._apply(self._ground, r, alpha), 0.0, 1.0)

    def fT_at_height(self, d, alpha, dz) -> np.ndarray:  # noqa: N802 - the chapter's name
        """P(read) of a tag at 3-D range ``d`` [m], bearing ``alpha`` [rad] and height
        ``dz`` [m] above the antenna (broadcast): the ground-plane table at the horizontal
        range ``sqrt(d^2 - dz^2)`` (0 where ``|dz| >= d``: the antenna's own cell), 0 at
        ``d >= d_max_m`` as :meth:`fT`; NaN in, NaN out."""
        d, a, z = np.broadcast_arrays(np.asarray(d, dtype=np.float64),
                                      np.asarray(alpha, dtype=np.float64),
                                      np.asarray(dz, dtype=np.float64))
        r = np.sqrt(np.maximum(d * d - z * z, 0.0))
        r = np.where(np.isfinite(z), r, np.nan)
        return np.where(d < self.d_max_m, self.ground_plane_fT(r, a), np.where(
            np.isfinite(d) & np.isfinite(r), 0.0, np.nan))

    def _ground(self, r, a):
        ix, iy = _cell(r, a, self.d_max_m, self.cell_m)
        return np.where(r < self.d_max_m, self.table[ix, iy], 0.0)

    def height_mix(self, d_m: float) -> tuple[np.ndarray, np.ndarray]:
        """``(dz [m], weight)`` of the training heights :meth:`fT` averages over at 3-D
        range `d_m`: the height bins with ``|dz| <= d``, weights summing to 1."""
        c, w = self.dz_centres_m, self.dz_weights
        i = min(int(np.floor(float(d_m) / self.cell_m)), len(w) - 1)
        wk = w[i] if w[i].sum() > 0 else w.sum(axis=0)
        wk = np.where(np.abs(c) <= d_m, wk, 0.0)
        if not wk.sum() > 0:  # shorter than every height seen: the antenna's own cell
            return np.array([min(float(d_m), float(np.min(np.abs(c))))]), np.ones(1)
        keep = wk > 0
        return c[keep], wk[keep] / wk.sum()

    def _polar_table(self) -> np.ndarray:
        """fT on the polar grid (range bins of cell_m / 5 up to d_max_m, 0.5 deg bearings):
        the ground-plane table averaged over :meth:`height_mix` at each bin's centre."""
        step = self.cell_m / _POLAR_D_PER_CELL
        n_d = int(np.ceil(self.d_max_m / step - 1e-9))
        a = -np.pi + (np.arange(_POLAR_N_ALPHA) + 0.5) * (2 * np.pi / _POLAR_N_ALPHA)
        out = np.empty((n_d, _POLAR_N_ALPHA))
        for i in range(n_d):
            d = (i + 0.5) * step
            dz, w = self.height_mix(d)
            r = np.sqrt(np.maximum(d * d - dz * dz, 0.0))
            out[i] = w @ self._ground(np.repeat(r[:, None], a.size, axis=1),
                                      np.broadcast_to(a, (r.size, a.size)))
        return out

    def _detection(self, d, a):
        step = self.cell_m / _POLAR_D_PER_CELL
        i = np.clip(np.floor(d / step).astype(np.int64), 0, self._polar.shape[0] - 1)
        j = np.floor((a + np.pi) / (2 * np.pi) * _POLAR_N_ALPHA).astype(np.int64) % _POLAR_N_ALPHA
        return np.where(d < self.d_max_m, self._polar[i, j], 0.0)

    def params_dict(self) -> dict:
        return {"d_max_m": self.d_max_m, "cell_m": self.cell_m, "table": self.table.tolist(),
                "bandwidth_m": self.bandwidth_m, "dz_centres_m": self.dz_centres_m.tolist(),
                "dz_weights": self.dz_weights.tolist(),
                "cv_bandwidths_m": list(self.cv_bandwidths_m),
                "cv_log_likelihood": list(self.cv_log_likelihood),
                "n_attempts": self.n_attempts, "cv_n_groups": self.cv_n_groups}

    @classmethod
    def from_params(cls, params: dict, rssi_range_dbm, where: str) -> Vorst2008Model:
        req = {"d_max_m", "cell_m", "table", "bandwidth_m", "dz_centres_m", "dz_weights"}
        check_keys(params, req | {"cv_bandwidths_m", "cv_log_likelihood", "n_attempts",
                                  "cv_n_groups"}, where, required=req)
        return cls(d_max_m=float(params["d_max_m"]), cell_m=float(params["cell_m"]),
                   table=np.asarray(params["table"], dtype=np.float64),
                   bandwidth_m=float(params["bandwidth_m"]),
                   dz_centres_m=np.asarray(params["dz_centres_m"], dtype=np.float64),
                   dz_weights=np.asarray(params["dz_weights"], dtype=np.float64),
                   rssi_range_dbm=rssi_range_dbm,
                   cv_bandwidths_m=tuple(params.get("cv_bandwidths_m", ())),
                   cv_log_likelihood=tuple(params.get("cv_log_likelihood", ())),
                   n_attempts=int(params.get("n_attempts", 0)),
                   cv_n_groups=int(params.get("cv_n_groups", 0)))


def _n_cells(d_max_m: float, cell_m: float) -> int:
    return int(np.ceil(2.0 * d_max_m / cell_m - 1e-9))


def _n_range_bins(d_max_m: float, cell_m: float) -> int:
    return int(np.ceil(d_max_m / cell_m - 1e-9))


def _cell(d, a, d_max_m: float, cell_m: float):
    """Cartesian cell indices (clipped into the grid) of polar positions (range, bearing)."""
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
        where given, keeps each tag's attempts in one fold; their ``dz`` (tag height
        above the antenna) is required: the table is over the horizontal range.
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
    if attempts.dz is None:
        raise ValueError("fit_vorst2008: the attempts carry no tag heights (Attempts(dz_m=...), "
                         "attempts_from_reads(dz_m=tag_height_differences(...))): Vorst & Zell's "
                         "table is over the horizontal range; pass dz_m=0 for tags in the "
                         "antennas' plane")
    att = attempts.within(d_max_m)
    if len(att) < int(n_folds):
        raise ValueError(f"fit_vorst2008: {len(att)} attempts for {n_folds} folds")
    n = _n_cells(d_max_m, cell_m)
    r_h = np.sqrt(np.maximum(att.d ** 2 - att.dz ** 2, 0.0))  # horizontal range
    ix, iy = _cell(r_h, att.alpha, d_max_m, cell_m)
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
    # the training heights per 3-D range bin: what fT(d, alpha) averages the table over
    kz = np.round(att.dz / DZ_BIN_M).astype(np.int64)
    k0 = int(kz.min())
    n_d = _n_range_bins(d_max_m, cell_m)
    i_d = np.clip(np.floor(att.d / cell_m).astype(np.int64), 0, n_d - 1)
    dz_w = np.zeros((n_d, int(kz.max()) - k0 + 1))
    np.add.at(dz_w, (i_d, kz - k0), 1.0)
    return Vorst2008Model(d_max_m=d_max_m, cell_m=cell_m, table=table,
                          bandwidth_m=float(bws[best]),
                          dz_centres_m=DZ_BIN_M * np.arange(k0, int(kz.max()) + 1),
                          dz_weights=dz_w, rssi_range_dbm=rssi_range_dbm,
                          cv_bandwidths_m=tuple(bws), cv_log_likelihood=tuple(scores),
                          n_attempts=len(att), cv_n_groups=n_groups)
