"""Read likelihoods of a sensor model and of the propagation oracle, vectorised.

An observation of a tag in one attempt slot is ``z = (read, rssi)``. For a tag at a
candidate position, seen from the slot's antenna at distance d and bearing alpha,

    log p(z) = log P(read) + log N(rssi; mu, sigma)      for a read,
    log p(z) = log (1 - P(read))                         for a miss,

(Joho, Plagemann & Burgard, ICRA 2009; the chapter's ``rho = fs fT`` is its two factors
without the normalisation). Sources of P(read), mu and sigma:

* :class:`ModelLikelihood`, a ``SensorLike`` model: ``P(read) = fT(d, alpha)`` (for a
  model that uses the tag's height above the antenna, ``fT_at_height(d, alpha, dz)``
  where the caller passes ``dz_m``: :func:`~pipeline.evaluation.interface.detection_probability`),
  ``mu = fs_dbm(d, alpha)``, sigma from the model where it has one
  (``rssi_sigma_db(d, alpha)``, e.g. Joho 2009 per cell) else the ``sigma_rssi_db``
  given (e.g. :func:`rssi_residual_std`, the training residual std). A model without RSSI
  (``predicts_rssi`` False, or ``fs_dbm`` NaN at a pair) contributes the detection term
  only. A model with its own ``log_likelihood(d, alpha, read, rssi_dbm)`` is used through
  it (``use_own_likelihood``).
* :class:`~.oracle_likelihood.OracleLikelihood` (its own module), the reader itself given
  the true one-way gains (as ray traced): it builds the same :class:`GaussianTerms`.

Robustness (both sources), so that one surprising observation cannot veto a position:

* probabilities are clipped to ``[eps, 1 - eps]``, ``eps = EPS = 1e-3`` by default (a
  read where the source says "never" costs log(1e-3) = -6.9 nats, as much as a 3.7
  sigma RSSI residual; Joho 2009's ``p_floor`` is the same number);
* the RSSI residual is clipped at ``z_clip = Z_CLIP = 5`` standard deviations (the
  density floor of a 5 sigma outlier, -12.5 nats below the peak); a gain of -inf
  (not traced: out of range) gives the floor.

Learned models are valid where they were trained (``d < d_max_m``). Beyond it (when
``d_max_m`` is given) every model gets the same rule: ``P(read) = p_far`` up to
``d_far_m`` and eps beyond, the RSSI of a read there uniform over the model's
``rssi_range_dbm`` (density ``1 / (hi - lo)``); :func:`fit_far_detection` estimates
``p_far`` and ``d_far_m`` from the training reads. Pairs beyond ``d_max_m`` are not
evaluated by the model at all, which is also what makes the (slots x candidates)
matrices cheap.

Every source turns arrays of pairs into :class:`GaussianTerms` (or :class:`OwnTerms`):
the miss term of every pair and, for the RSSI of a read, the read term, so a caller can
combine the same per-pair predictions with the outcomes of many tags.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import pandas as pd

from pipeline.evaluation.interface import detection_probability, uses_tag_height
from pipeline.localisation.observations import near_geometry, pair_geometry

__all__ = [
    "EPS",
    "Z_CLIP",
    "GaussianTerms",
    "ModelLikelihood",
    "OwnTerms",
    "fit_far_detection",
    "rssi_residual_std",
]

#: Default clip of every probability to [EPS, 1 - EPS] (see module doc).
EPS = 1e-3
#: Default clip of the RSSI residual, in standard deviations (see module doc).
Z_CLIP = 5.0
_LOG_SQRT_2PI = 0.5 * np.log(2.0 * np.pi)


def _check_eps(eps: float) -> float:
    eps = float(eps)
    if not 0.0 < eps < 0.5:
        raise ValueError(f"eps must be in (0, 0.5), got {eps!r}")
    return eps


def _check_zclip(z_clip: float) -> float:
    z = float(z_clip)
    if not z > 0:
        raise ValueError(f"z_clip must be > 0, got {z_clip!r}")
    return z


class GaussianTerms:
    """Per-pair terms of a read likelihood with a Gaussian (or flat) RSSI density.

    All arrays share one shape P (or broadcast to it; scalars allowed).

    Parameters
    ----------
    log_read : numpy.ndarray
        ``log P(read)`` (clipped probability).
    log_miss : numpy.ndarray
        ``log (1 - P(read))``.
    rssi_mean_dbm : numpy.ndarray
        Mean RSSI of a read [dBm]; -inf gives the z_clip floor; NaN: no Gaussian, the
        flat density applies.
    rssi_sigma_db : numpy.ndarray or float
        Its standard deviation [dB] (> 0).
    rssi_flat_logpdf : numpy.ndarray or float
        Log-density [1/dB] of a read's RSSI where the mean is NaN; 0 = no RSSI term
        (detection only).
    z_clip : float
    """

    def __init__(self, log_read, log_miss, rssi_mean_dbm, rssi_sigma_db,
                 rssi_flat_logpdf=0.0, z_clip: float = Z_CLIP) -> None:
        self.log_read = np.asarray(log_read, dtype=np.float64)
        self.log_miss = np.asarray(log_miss, dtype=np.float64)
        self.z_clip = float(z_clip)
        mu = np.asarray(rssi_mean_dbm, dtype=np.float64)
        sd = np.asarray(rssi_sigma_db, dtype=np.float64)
        flat = np.asarray(rssi_flat_logpdf, dtype=np.float64)
        nan = np.isnan(mu)
        # NaN mean encoded as mean 0, 1/sigma 0, normalisation = the flat log-density, so
        # read_loglik needs no branch: the Gaussian term is then exactly the flat one
        lnorm = -np.log(sd) - _LOG_SQRT_2PI
        if nan.any():
            self._mu = np.where(nan, 0.0, mu)
            self._inv = np.where(nan, 0.0, 1.0 / sd)
            self._lnorm = np.where(nan, flat, lnorm)
        else:
            self._mu, self._inv, self._lnorm = mu, 1.0 / sd, lnorm

    @staticmethod
    def _take(a, index):
        return a if (index is None or a.ndim == 0) else a[index]

    def read_loglik(self, rssi_dbm, index=None) -> np.ndarray:
        """``log p(read, rssi)`` at the pairs ``[index]``, broadcast with `rssi_dbm`.

        NaN RSSI (a read without a reported RSSI): detection term only.
        """
        r = np.asarray(rssi_dbm, dtype=np.float64)
        finite = np.isfinite(r)
        r0 = r if finite.all() else np.where(finite, r, 0.0)
        mu, inv = self._take(self._mu, index), self._take(self._inv, index)
        with np.errstate(invalid="ignore"):
            z = np.minimum(np.abs(r0 - mu) * inv, self.z_clip)
        g = self._take(self._lnorm, index) - 0.5 * z * z
        if not finite.all():
            g = np.where(finite, g, 0.0)
        return g + self._take(self.log_read, index)

    def loglik(self, read, rssi_dbm, index=None) -> np.ndarray:
        """Log-likelihood of outcomes (read, rssi) at the pairs ``[index]`` (broadcasting)."""
        read = np.asarray(read, dtype=bool)
        return np.where(read, self.read_loglik(rssi_dbm, index),
                        self._take(self.log_miss, index))


@dataclass(frozen=True)
class OwnTerms:
    """Per-pair terms of a model with its own ``log_likelihood(d, alpha, read, rssi)``.

    Pairs with ``near`` False (beyond the model's domain) take the constants
    ``far_log_read`` (+ ``far_rssi_logpdf`` for a reported RSSI) and ``log_miss``.
    """

    model: object
    d_m: np.ndarray
    alpha_rad: np.ndarray
    near: np.ndarray
    log_miss: np.ndarray
    far_log_read: np.ndarray
    far_rssi_logpdf: float
    use_rssi: bool = True

    def read_loglik(self, rssi_dbm, index=None) -> np.ndarray:
        """``log p(read, rssi)`` at the pairs ``[index]``, broadcast with `rssi_dbm`."""
        arrs = (self.d_m, self.alpha_rad, self.near, self.far_log_read)
        if index is not None:
            arrs = tuple(v[index] for v in arrs)
        r = np.asarray(rssi_dbm, dtype=np.float64)
        if not self.use_rssi:  # detection only: the model's read term without an RSSI
            r = np.full(r.shape, np.nan)
        d, a, near, flr, r = np.broadcast_arrays(*arrs, r)
        out = flr + np.where(np.isfinite(r), self.far_rssi_logpdf, 0.0)
        if near.any():
            out[near] = self.model.log_likelihood(d[near], a[near],
                                                  np.ones(int(near.sum()), dtype=bool), r[near])
        return out

    def loglik(self, read, rssi_dbm, index=None) -> np.ndarray:
        read = np.asarray(read, dtype=bool)
        lm = self.log_miss if index is None else self.log_miss[index]
        return np.where(read, self.read_loglik(rssi_dbm, index), lm)


class ModelLikelihood:
    """Read likelihood of a ``SensorLike`` model (see module doc).

    Parameters
    ----------
    model : SensorLike
        ``fT``, ``fs_dbm`` (and ``rssi_range_dbm``); optionally ``predicts_rssi``,
        ``rssi_sigma_db(d, alpha)`` and ``log_likelihood(d, alpha, read, rssi_dbm)``.
    sigma_rssi_db : float, optional
        RSSI standard deviation [dB] for a model without ``rssi_sigma_db`` (e.g. the
        training residual std, :func:`rssi_residual_std`). Required when such a model's
        RSSI is used.
    eps : float
        Probability clip, default :data:`EPS`.
    z_clip : float
        RSSI residual clip [sigma], default :data:`Z_CLIP`.
    d_max_m : float, optional
        The model's domain (training ``d_max_m``); beyond it the far rule applies
        (module doc). None: the model is evaluated at every distance.
    p_far : float
        Detection probability for ``d_max_m <= d < d_far_m`` (required with ``d_max_m``).
    d_far_m : float
        Beyond this distance P(read) = eps [m] (default inf).
    use_rssi : bool
        False: detection term only, whatever the model predicts.
    use_own_likelihood : bool
        Use the model's ``log_likelihood`` when it has one (default True).
    name : str, optional
        For messages and results.
    """

    def __init__(self, model, *, sigma_rssi_db: float | None = None, eps: float = EPS,
                 z_clip: float = Z_CLIP, d_max_m: float | None = None,
                 p_far: float | None = None, d_far_m: float = np.inf, use_rssi: bool = True,
                 use_own_likelihood: bool = True, name: str | None = None) -> None:
        for m in ("fT", "fs_dbm", "rssi_range_dbm"):
            if not hasattr(model, m):
                raise TypeError(f"ModelLikelihood: {type(model).__name__} lacks {m!r}; "
                                "expected a SensorLike model")
        self.model = model
        self.name = name or type(model).__name__
        self.eps = _check_eps(eps)
        self.z_clip = _check_zclip(z_clip)
        lo, hi = (float(v) for v in model.rssi_range_dbm)
        if not (np.isfinite(lo) and np.isfinite(hi) and hi > lo):
            raise ValueError(f"{self.name}: rssi_range_dbm must be (lo, hi) with lo < hi")
        self.use_rssi = bool(use_rssi) and bool(getattr(model, "predicts_rssi", True))
        self.own = bool(use_own_likelihood) and callable(getattr(model, "log_likelihood", None))
        self.has_sigma = callable(getattr(model, "rssi_sigma_db", None))
        #: The model's P(read) depends on the tag's height above the antenna (callers
        #: pass ``dz_m`` to :meth:`terms`; others may skip computing it).
        self.uses_height = uses_tag_height(model)
        if sigma_rssi_db is not None and not (np.isfinite(sigma_rssi_db) and sigma_rssi_db > 0):
            raise ValueError(f"{self.name}: sigma_rssi_db must be finite and > 0, "
                             f"got {sigma_rssi_db!r}")
        if self.use_rssi and not self.own and not self.has_sigma and sigma_rssi_db is None:
            raise ValueError(f"{self.name}: the model predicts RSSI but has no rssi_sigma_db; "
                             "pass sigma_rssi_db (e.g. rssi_residual_std(model, training reads, "
                             "d_max_m)) or use_rssi=False")
        self.sigma_rssi_db = None if sigma_rssi_db is None else float(sigma_rssi_db)
        if d_max_m is not None:
            if not (np.isfinite(d_max_m) and d_max_m > 0):
                raise ValueError(f"{self.name}: d_max_m must be finite and > 0, got {d_max_m!r}")
            if p_far is None or not 0.0 <= float(p_far) <= 1.0:
                raise ValueError(f"{self.name}: with d_max_m, pass p_far in [0, 1] (the "
                                 f"detection rate beyond it, fit_far_detection), got {p_far!r}")
            if not float(d_far_m) >= float(d_max_m):
                raise ValueError(f"{self.name}: d_far_m ({d_far_m}) must be >= d_max_m "
                                 f"({d_max_m})")
        self.d_max_m = None if d_max_m is None else float(d_max_m)
        self.p_far = None if p_far is None else float(p_far)
        self.d_far_m = float(d_far_m)
        self.flat_logpdf = -np.log(hi - lo) if self.use_rssi else 0.0
        self._far_values = None  # the far rule's log P(read), log P(miss): below, beyond d_far_m
        if self.d_max_m is not None:
            p = self.far_probability(np.array([-np.inf, np.inf]))
            self._far_values = (np.log(p), np.log1p(-p))

    def __repr__(self) -> str:
        return (f"ModelLikelihood({self.name}, own={self.own}, rssi={self.use_rssi}, "
                f"d_max_m={self.d_max_m}, p_far={self.p_far})")

    @property
    def alpha_needed_within_m(self) -> float:
        """Pairs farther than this need no bearing (inf: all)."""
        return np.inf if self.d_max_m is None else self.d_max_m

    def far_probability(self, d: np.ndarray) -> np.ndarray:
        """Clipped P(read) of the far rule at distances `d` (``p_far`` below ``d_far_m``)."""
        p = np.where(d < self.d_far_m, self.p_far, 0.0)
        return np.clip(p, self.eps, 1.0 - self.eps)

    def far_log_miss(self, d_m) -> np.ndarray:
        """``log(1 - P(read))`` of pairs beyond ``d_max_m`` (the far rule) at `d_m`."""
        return np.log1p(-self.far_probability(np.asarray(d_m, dtype=np.float64)))

    def far_read_loglik(self, d_m, rssi_dbm) -> np.ndarray:
        """``log p(read, rssi)`` of pairs beyond ``d_max_m`` (the far rule), broadcasting."""
        d, r = np.broadcast_arrays(np.asarray(d_m, dtype=np.float64),
                                   np.asarray(rssi_dbm, dtype=np.float64))
        return np.log(self.far_probability(d)) + np.where(np.isfinite(r), self.flat_logpdf, 0.0)

    def terms(self, d_m, alpha_rad, dz_m=None) -> GaussianTerms | OwnTerms:
        """Per-pair terms at distances `d_m` [m] and bearings `alpha_rad` [rad] (broadcast).

        Bearings beyond ``d_max_m`` are not used (may be NaN). ``dz_m`` (broadcast), the
        tag's height above the antenna [m] where the caller knows it, reaches a model that
        uses it (:attr:`uses_height`); the others ignore it.
        """
        d, a = np.broadcast_arrays(np.asarray(d_m, dtype=np.float64),
                                   np.asarray(alpha_rad, dtype=np.float64))
        shape = d.shape
        z = None
        if dz_m is not None and self.uses_height:
            z = np.broadcast_to(np.asarray(dz_m, dtype=np.float64), shape).reshape(-1)
        d, a = d.reshape(-1), a.reshape(-1)
        near = np.isfinite(d) if self.d_max_m is None else d < self.d_max_m
        near &= np.isfinite(a)
        far_p = self.far_probability(d) if self.d_max_m is not None else np.full(d.shape, self.eps)
        m = self.model
        if self.own:
            log_miss = np.log1p(-far_p)
            if near.any():
                n = int(near.sum())
                log_miss[near] = m.log_likelihood(d[near], a[near], np.zeros(n, bool),
                                                  np.full(n, np.nan))
            return OwnTerms(m, d.reshape(shape), a.reshape(shape), near.reshape(shape),
                            log_miss.reshape(shape), np.log(far_p).reshape(shape),
                            self.flat_logpdf, self.use_rssi)
        p = far_p
        mu = np.full(d.shape, np.nan)
        sd = np.ones(d.shape)
        dn, an = d[near], a[near]
        if dn.size:
            pn = np.asarray(detection_probability(m, dn, an, None if z is None else z[near]),
                            dtype=np.float64)
            p[near] = np.clip(np.nan_to_num(pn, nan=0.0), self.eps, 1.0 - self.eps)
            if self.use_rssi:
                mu[near] = m.fs_dbm(dn, an)
                if self.has_sigma:
                    sd[near] = m.rssi_sigma_db(dn, an)
                else:
                    sd[near] = self.sigma_rssi_db
        flat = np.full(d.shape, self.flat_logpdf)
        if self.use_rssi:
            # a pair inside the domain without an RSSI prediction (NaN): detection only
            flat[near & np.isnan(mu)] = 0.0
        return GaussianTerms(np.log(p).reshape(shape), np.log1p(-p).reshape(shape),
                             mu.reshape(shape), sd.reshape(shape), flat.reshape(shape),
                             self.z_clip)

    def _far_loglik(self, d: np.ndarray, read: np.ndarray, rssi: np.ndarray) -> np.ndarray:
        """The far rule's log-likelihood of every (n, k) pair: one of two values per tag
        (``d`` below or beyond ``d_far_m``), exactly as the terms compute it (log P(read)
        plus the flat RSSI density of a reported RSSI)."""
        log_p, log_miss = self._far_values
        rssi_term = np.where(np.isfinite(rssi), self.flat_logpdf, 0.0)
        v_read = rssi_term[None, :] + log_p[:, None]  # (2, k): below, beyond d_far_m
        v_miss = log_miss[:, None]
        v = np.where(read[None, :], v_read, v_miss)
        return np.where(d < self.d_far_m, v[0], v[1])

    def pair_loglik(self, d_m, alpha_rad, read, rssi_dbm, dz_m=None) -> np.ndarray:
        """``log p(read, rssi | d, alpha)`` of every (pose, tag) pair of one attempt slot.

        Equal, value for value, to ``terms(d_m, alpha_rad).loglik(read[None], rssi[None])``;
        faster where most pairs lie beyond ``d_max_m`` (the robot filter: ~80 % of its
        particle-tag pairs): those take one of two far-rule values per tag (``d`` below or
        beyond ``d_far_m``) without full-size term arrays, and the model is evaluated on
        the near pairs, as by the terms.

        Parameters
        ----------
        d_m, alpha_rad : numpy.ndarray, shape (n, k)
            Distances [m] and bearings [rad] (bearings beyond ``d_max_m`` may be NaN).
        read : array_like of bool, shape (k,)
            The slot's outcome per tag.
        rssi_dbm : array_like, shape (k,)
            RSSI of a read [dBm]; NaN: not read, or read without an RSSI.
        dz_m : array_like, broadcast to (n, k), optional
            Tag heights above the antennas [m], for a model that uses them (:meth:`terms`).

        Returns
        -------
        numpy.ndarray, shape (n, k), float64
        """
        d = np.asarray(d_m, dtype=np.float64)
        a = np.asarray(alpha_rad, dtype=np.float64)
        read = np.asarray(read, dtype=bool)
        rssi = np.asarray(rssi_dbm, dtype=np.float64)
        if d.ndim != 2 or a.shape != d.shape or {read.shape, rssi.shape} != {(d.shape[1],)}:
            raise ValueError(f"pair_loglik: d_m and alpha_rad must be (n, k) and read, rssi_dbm "
                             f"(k,); got {d.shape}, {a.shape}, {read.shape}, {rssi.shape}")
        z = None if dz_m is None else np.broadcast_to(np.asarray(dz_m, dtype=np.float64), d.shape)
        if self.d_max_m is None:  # no far rule: every pair is the model's
            return self.terms(d, a, z).loglik(read[None, :], rssi[None, :])
        out = self._far_loglik(d, read, rssi)
        near = (d < self.d_max_m) & np.isfinite(a)
        if not near.any():
            return out
        cols = np.nonzero(near)[1]
        dn, an, rn, readn = d[near], a[near], rssi[cols], read[cols]
        # the model sees the batch the terms give it (every near pair, in the same order):
        # a model may round differently in another batch (ANFIS's matrix product does, for
        # a single row), and the filter's resampling would then differ
        out[near] = self.terms(dn, an, None if z is None else z[near]).loglik(readn, rn)
        return out

    def pose_loglik(self, antenna_poses, points_m, read, rssi_dbm) -> np.ndarray:
        """``log p`` of one attempt slot's outcomes of `points_m`, per antenna pose.

        Equal, value for value, to ``pair_loglik(d, alpha, read, rssi_dbm).sum(axis=1)``
        with ``d, alpha = pair_geometry(antenna_poses, points_m, alpha_needed_within_m)``,
        in fewer passes over the (n, k) pairs (the robot filter's inner loop): the near
        pairs are found once, by flat index, and their bearings are never scattered into
        an (n, k) matrix. A model that uses the tag's height above the antenna
        (:attr:`uses_height`) gets each pair's: the point's z less the pose's.

        Parameters
        ----------
        antenna_poses : array_like, shape (n, 4) or (n, 6)
            [x_m, y_m, z_m, yaw_rad(, pitch_rad, roll_rad)].
        points_m : array_like, shape (k, 3)
            Tag positions [m].
        read, rssi_dbm : array_like, shape (k,)
            As :meth:`pair_loglik`.

        Returns
        -------
        numpy.ndarray, shape (n,), float64
        """
        read = np.asarray(read, dtype=bool)
        rssi = np.asarray(rssi_dbm, dtype=np.float64)
        k = len(np.asarray(points_m, dtype=np.float64).reshape(-1, 3))
        if {read.shape, rssi.shape} != {(k,)}:
            raise ValueError(f"pose_loglik: read and rssi_dbm must be ({k},), one per point, "
                             f"got {read.shape}, {rssi.shape}")
        pts = np.asarray(points_m, dtype=np.float64).reshape(-1, 3)
        pz = np.asarray(antenna_poses, dtype=np.float64)[:, 2]
        if self.d_max_m is None:
            d, a = pair_geometry(antenna_poses, pts, self.alpha_needed_within_m)
            dz = pts[None, :, 2] - pz[:, None] if self.uses_height else None
            return self.pair_loglik(d, a, read, rssi, dz).sum(axis=1)
        d, sel, an = near_geometry(antenna_poses, pts, self.d_max_m)
        out = self._far_loglik(d, read, rssi)
        if len(sel):
            cols = sel % d.shape[1]
            dz = pts[cols, 2] - pz[sel // d.shape[1]] if self.uses_height else None
            out.ravel()[sel] = self.terms(d.ravel()[sel], an, dz).loglik(read[cols], rssi[cols])
        return out.sum(axis=1)

    def log_likelihood(self, d_m, alpha_rad, read, rssi_dbm) -> np.ndarray:
        """Elementwise ``log p(read, rssi | d, alpha)`` (all four broadcast)."""
        d, a, r, s = np.broadcast_arrays(np.asarray(d_m, dtype=np.float64),
                                         np.asarray(alpha_rad, dtype=np.float64),
                                         np.asarray(read, dtype=bool),
                                         np.asarray(rssi_dbm, dtype=np.float64))
        return self.terms(d, a).loglik(r, s)

    def sample(self, d_m, alpha_rad, rng: np.random.Generator):
        """Outcomes drawn from the model (unclipped fT; RSSI ~ N(fs_dbm, sigma)).

        Returns ``(read, rssi_dbm)`` of the broadcast shape; RSSI NaN where not read
        or where the model predicts none.
        """
        d, a = np.broadcast_arrays(np.asarray(d_m, dtype=np.float64),
                                   np.asarray(alpha_rad, dtype=np.float64))
        m = self.model
        p = np.nan_to_num(np.asarray(m.fT(d, a), dtype=np.float64), nan=0.0)
        read = rng.random(d.shape) < p
        z = rng.standard_normal(d.shape)
        if not self.use_rssi:
            return read, np.full(d.shape, np.nan)
        mu = np.asarray(m.fs_dbm(d, a), dtype=np.float64)
        if self.has_sigma:
            sd = np.asarray(m.rssi_sigma_db(d, a), dtype=np.float64)
        else:
            sd = self.sigma_rssi_db if self.sigma_rssi_db is not None else 0.0
        return read, np.where(read, mu + sd * z, np.nan)


# ----------------------------------------------------------------------------- helpers
def _geometry_columns(reads, pose: str, table: str):
    """(d, alpha, read, rssi) of a reads table, or of an object with those attributes."""
    if all(hasattr(reads, k) for k in ("d", "alpha", "read", "rssi")):  # sensormodels.Attempts
        arrs = (reads.d, reads.alpha, reads.read, reads.rssi)
        if len(arrs[0]) == 0:
            raise ValueError(f"{table}: no attempts")
        return tuple(np.asarray(a, dtype=bool if i == 2 else np.float64)
                     for i, a in enumerate(arrs))
    if pose not in ("est", "true"):
        raise ValueError(f"pose must be 'est' or 'true', got {pose!r}")
    if not isinstance(reads, pd.DataFrame):
        raise ValueError(f"{table}: expected a reads DataFrame or Attempts, got "
                         f"{type(reads).__name__}")
    cols = ("read", "rssi_dbm", f"d_{pose}_m", f"alpha_{pose}_rad")
    missing = [c for c in cols if c not in reads.columns]
    if missing:
        raise ValueError(f"{table}: missing column(s) {missing}")
    if len(reads) == 0:
        raise ValueError(f"{table}: the read log is empty")
    return (reads[f"d_{pose}_m"].to_numpy(np.float64),
            reads[f"alpha_{pose}_rad"].to_numpy(np.float64),
            reads["read"].to_numpy(bool), reads["rssi_dbm"].to_numpy(np.float64))


def rssi_residual_std(model, reads: pd.DataFrame, d_max_m: float, pose: str = "est",
                      table: str = "reads") -> float:
    """Standard deviation [dB] of ``rssi - fs_dbm(d, alpha)`` over the reads with d < d_max_m.

    `reads` is the TRAINING tour's ``reads.parquet`` (the model's own residual, what a
    robot can know) or a :class:`pipeline.sensormodels.Attempts`; ValueError if no read
    has an RSSI there.
    """
    d, a, r, s = _geometry_columns(reads, pose, table)
    keep = r & np.isfinite(s) & np.isfinite(d) & np.isfinite(a) & (d < float(d_max_m))
    if keep.sum() < 2:
        raise ValueError(f"{table}: fewer than 2 reads with an RSSI within d < {d_max_m} m")
    res = s[keep] - np.asarray(model.fs_dbm(d[keep], a[keep]), dtype=np.float64)
    res = res[np.isfinite(res)]
    if len(res) < 2:
        raise ValueError(f"{table}: the model predicts no RSSI at the reads")
    return float(np.std(res, ddof=1))


def fit_far_detection(reads: pd.DataFrame, d_max_m: float, pose: str = "est",
                      quantile: float = 0.99, table: str = "reads") -> tuple[float, float]:
    """``(p_far, d_far_m)`` of the far rule from the TRAINING reads (table or Attempts).

    ``d_far_m`` is the `quantile` of the distances of reads at ``d >= d_max_m`` (d_max_m
    itself when there are none) and ``p_far`` the read rate of the attempts with
    ``d_max_m <= d < d_far_m`` (0 when there are none).
    """
    d, _, r, _ = _geometry_columns(reads, pose, table)
    ok = np.isfinite(d) & (d >= float(d_max_m))
    far_reads = d[ok & r]
    if len(far_reads) == 0:
        return 0.0, float(d_max_m)
    d_far = float(np.quantile(far_reads, float(quantile)))
    band = ok & (d < d_far)
    p = float(r[band].mean()) if band.any() else 0.0
    return p, d_far
