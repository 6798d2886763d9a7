"""A sector read region with two constant detection rates: the project's own baseline,
kept under the key ``liu2006``.

What it is
    The antenna's read region is a circular sector in the antenna frame (``d <
    range_m`` and ``|wrap(alpha - boresight_rad)| < half_width_rad``, the cone of a patch
    antenna); a tag inside is detected with one constant probability, outside with
    another. Detection only: it predicts no RSSI (``fs = 1``, ``fs_dbm = NaN``, so no RSSI
    or Fig. 7 score is computed for it).
Where the name comes from
    Cicirelli, Milella & Di Paola (2011) cite a "Liu et al. (2006)" for a simplified
    antenna model of this kind. Its reference could not be checked here (the chapter's
    reference list was not available to us; Liu, Corner & Shenoy, "Ferret: RFID
    localization for pervasive multimedia", UbiComp 2006, models a reader's coverage
    region, but that it is the paper cited is our guess, not established). So this is
    not a reproduction of any paper: the shape, the fit and the detection-only form are
    the project's choices. The key ``liu2006`` stays so that run directories and tables
    keep their names; its display name says what it is.
Fit
    Maximum likelihood. For every candidate sector on a grid (range in steps of
    ``d_step_m`` up to d_max; half-width in steps of ``angle_step_deg`` up to 180 deg;
    boresight in the same steps within +-``boresight_max_deg``, or fixed at 0) the two
    probabilities are their maximum-likelihood values reads / attempts inside and
    outside, and the sector with the highest Bernoulli log-likelihood of the training
    attempts (within d_max) wins (ties: the first, i.e. the smallest range, then
    half-width, then the most negative boresight). A parameter that ends on the edge of
    its search grid (the range at d_max, the boresight at +-``boresight_max_deg``) is
    named in ``at_search_bound``: the likelihood wanted more than the search allowed,
    and the fitted value is the bound, not an optimum.
    The region and p_outside hold at every distance, beyond d_max too (the model has no
    other notion of range).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.special import xlogy

from fuzzymodel import wrap_angle
from pipeline.configschema import check_keys
from pipeline.sensormodels._common import Attempts, CompetitorModel, check_rssi_range

__all__ = ["LIU2006", "Liu2006Model", "fit_liu2006"]

#: The model's stable key (run directories, tables); see the module doc for its name.
LIU2006 = "liu2006"
_FIELDS = ("range_m", "half_width_rad", "boresight_rad", "p_inside", "p_outside")
_LEGACY = {"rssi_inside_dbm", "rssi_outside_dbm"}  # constant RSSI of earlier files: ignored


@dataclass(frozen=True, eq=False)
class Liu2006Model(CompetitorModel):
    """Sector read region with two constant detection probabilities, no RSSI (module doc).

    Attributes
    ----------
    range_m : float
        Outer radius of the sector [m].
    half_width_rad : float
        Half of the sector's opening angle [rad], in (0, pi].
    boresight_rad : float
        Bearing of the sector's axis in the antenna frame [rad].
    p_inside, p_outside : float
        Detection probabilities inside / outside the sector.
    rssi_range_dbm : (float, float)
        Kept for the SensorLike interface (the model predicts no RSSI).
    train_log_likelihood : float
        Bernoulli log-likelihood of the training attempts at the fit (NaN if unknown).
    n_attempts : int
        Training attempts.
    at_search_bound : tuple of str
        Fitted parameters that sit on the edge of their search grid (``"range_m"``,
        ``"boresight_rad"``): bounds, not optima.
    """

    range_m: float
    half_width_rad: float
    boresight_rad: float
    p_inside: float
    p_outside: float
    rssi_range_dbm: tuple = (-80.0, -30.0)
    train_log_likelihood: float = float("nan")
    n_attempts: int = 0
    at_search_bound: tuple = ()

    KIND = LIU2006
    #: What to call it in tables and figures.
    DISPLAY_NAME = "sector read region, two detection rates (project's own)"
    REFERENCE = ("none reproduced: the project's own sector read region, after the "
                 "'simplified antenna model' Cicirelli, Milella & Di Paola (2011) attribute to "
                 "Liu et al. (2006), whose paper was not checked")
    DESCRIPTION = "sector read region, constant detection probability inside / outside; no RSSI"
    predicts_rssi = False

    def __post_init__(self) -> None:
        object.__setattr__(self, "rssi_range_dbm", check_rssi_range(self.rssi_range_dbm))
        for name in _FIELDS:
            v = float(getattr(self, name))
            if not np.isfinite(v):
                raise ValueError(f"Liu2006Model: {name} must be finite, got {v!r}")
            object.__setattr__(self, name, v)
        if not self.range_m > 0:
            raise ValueError(f"Liu2006Model: range_m must be > 0, got {self.range_m}")
        if not 0 < self.half_width_rad <= np.pi:
            raise ValueError(f"Liu2006Model: half_width_rad must be in (0, pi], "
                             f"got {self.half_width_rad}")
        for name in ("p_inside", "p_outside"):
            if not 0 <= getattr(self, name) <= 1:
                raise ValueError(f"Liu2006Model: {name} must be in [0, 1]")
        object.__setattr__(self, "train_log_likelihood", float(self.train_log_likelihood))
        object.__setattr__(self, "n_attempts", int(self.n_attempts))
        bound = tuple(str(v) for v in self.at_search_bound)
        if not set(bound) <= {"range_m", "boresight_rad"}:
            raise ValueError(f"Liu2006Model: at_search_bound names unknown parameters {bound}")
        object.__setattr__(self, "at_search_bound", bound)

    def inside(self, d, alpha) -> np.ndarray:
        """Whether (d [m], alpha [rad]) lies in the read region; broadcasts."""
        d, a = np.broadcast_arrays(np.asarray(d, dtype=np.float64),
                                   np.asarray(alpha, dtype=np.float64))
        return self._inside(d, wrap_angle(a))

    def _inside(self, d, a) -> np.ndarray:
        delta = np.abs(wrap_angle(a - self.boresight_rad))
        in_angle = (delta < self.half_width_rad) | (self.half_width_rad >= np.pi)
        return (d < self.range_m) & in_angle

    def _detection(self, d, a):
        return np.where(self._inside(d, a), self.p_inside, self.p_outside)

    def params_dict(self) -> dict:
        out = {k: float(getattr(self, k)) for k in _FIELDS}
        ll = self.train_log_likelihood
        out["train_log_likelihood"] = float(ll) if np.isfinite(ll) else None
        out["n_attempts"] = int(self.n_attempts)
        out["at_search_bound"] = list(self.at_search_bound)
        return out

    @classmethod
    def from_params(cls, params: dict, rssi_range_dbm, where: str) -> Liu2006Model:
        check_keys(params, set(_FIELDS) | _LEGACY | {"train_log_likelihood", "n_attempts",
                                                     "at_search_bound"},
                   where, required=set(_FIELDS))
        ll = params.get("train_log_likelihood")
        return cls(**{k: float(params[k]) for k in _FIELDS}, rssi_range_dbm=rssi_range_dbm,
                   train_log_likelihood=float("nan") if ll is None else float(ll),
                   n_attempts=int(params.get("n_attempts", 0)),
                   at_search_bound=tuple(params.get("at_search_bound", ())))


def _bernoulli_ll(k: np.ndarray, n: np.ndarray) -> np.ndarray:
    """Maximised Bernoulli log-likelihood of k successes in n trials (0 where n = 0)."""
    p = k / np.maximum(n, 1)
    return xlogy(k, p) + xlogy(n - k, 1.0 - p)


def fit_liu2006(attempts: Attempts, rssi_range_dbm, *, d_max_m: float, d_step_m: float = 0.05,
                angle_step_deg: float = 2.5, fit_boresight: bool = True,
                boresight_max_deg: float = 45.0) -> Liu2006Model:
    """Maximum-likelihood sector and rates (see module doc); parameters on the edge of
    their search grid are named in the result's ``at_search_bound``.

    Parameters
    ----------
    attempts : Attempts
        Training attempts; those with d >= `d_max_m` are ignored.
    rssi_range_dbm : (float, float)
        Stored for the interface only.
    d_max_m : float
        Largest distance used and largest candidate range [m].
    d_step_m, angle_step_deg : float
        Resolution of the candidate ranges [m] and angles [deg].
    fit_boresight : bool
        Search the boresight in +-`boresight_max_deg` (else fixed at 0).
    """
    if not (d_step_m > 0 and angle_step_deg > 0 and d_max_m > 0):
        raise ValueError("fit_liu2006: d_max_m, d_step_m and angle_step_deg must be > 0")
    att = attempts.within(d_max_m)
    if len(att) == 0 or not att.read.any() or att.read.all():
        raise ValueError("fit_liu2006: need attempts within d_max_m with both reads and misses")
    n_d = int(np.ceil(d_max_m / d_step_m - 1e-9))
    a_step = np.deg2rad(angle_step_deg)
    n_a = int(np.ceil(np.pi / a_step - 1e-9))
    i_d = np.minimum((att.d / d_step_m).astype(np.int64), n_d - 1)
    n_b = int(np.floor(boresight_max_deg / angle_step_deg + 1e-9)) if fit_boresight else 0
    best = (-np.inf, 0.0, 0, 0)
    r = att.read.astype(np.float64)
    for b in a_step * np.arange(-n_b, n_b + 1):
        delta = np.abs(wrap_angle(att.alpha - b))
        i_a = np.minimum((delta / a_step).astype(np.int64), n_a - 1)
        flat = i_d * n_a + i_a
        n = np.bincount(flat, minlength=n_d * n_a).reshape(n_d, n_a).cumsum(0).cumsum(1)
        k = np.bincount(flat, weights=r, minlength=n_d * n_a).reshape(n_d, n_a).cumsum(0).cumsum(1)
        n_tot, k_tot = n[-1, -1], k[-1, -1]
        ll = _bernoulli_ll(k, n) + _bernoulli_ll(k_tot - k, n_tot - n)
        ll[(n == 0) | (n == n_tot)] = -np.inf  # both groups must hold attempts
        j, l_ = np.unravel_index(int(np.argmax(ll)), ll.shape)
        if ll[j, l_] > best[0]:
            best = (float(ll[j, l_]), float(b), int(j), int(l_))
    if not np.isfinite(best[0]):
        raise ValueError("fit_liu2006: no sector splits the attempts into two non-empty groups")
    ll, b, j, l_ = best
    model = Liu2006Model(range_m=(j + 1) * d_step_m, half_width_rad=min((l_ + 1) * a_step, np.pi),
                         boresight_rad=b, p_inside=0.0, p_outside=0.0,
                         rssi_range_dbm=rssi_range_dbm)
    ins = model._inside(att.d, att.alpha)
    bound = []
    if j == n_d - 1:  # the largest range searched: d_max
        bound.append("range_m")
    if n_b > 0 and abs(b) >= n_b * a_step - 1e-12:
        bound.append("boresight_rad")
    return Liu2006Model(range_m=model.range_m, half_width_rad=model.half_width_rad,
                        boresight_rad=b, p_inside=float(att.read[ins].mean()),
                        p_outside=float(att.read[~ins].mean()), rssi_range_dbm=rssi_range_dbm,
                        train_log_likelihood=ll, n_attempts=len(att),
                        at_search_bound=tuple(bound))
