"""Small-scale fading about a local-mean gain: the oracle's read likelihood on local means.

What the reads contain. The reader simulation (:func:`pipeline.acquisition.reader.
reader_response`) draws no fading of its own: it takes the *coherent* one-way gain ``g``
the ray tracer gives at the antenna's exact pose (the paths summed with their phases),
closes the link when ``g >= g_T`` (``g_T = budget.min_gain_db()``, tag and reader
thresholds in one, noise-free) and reports
``RSSI = Q(P_tx + 2 G(g) + M - 2 L + N(0, sigma_n^2))``, ``Q`` the reader's rounding.
A likelihood evaluated on the *local mean* ``g_bar`` (the same paths summed in power:
what a grid coarser than a quarter wavelength can know, :mod:`.robot_oracle`, and the
coarse pass of :mod:`.global_oracle`) must therefore carry the law of ``g / g_bar``.

The model. With many paths of random phase the coherent sum is a complex Gaussian about a
fixed (line-of-sight) part: ``E = g / g_bar`` has the Rician power law of unit mean with
factor ``K`` (power of the fixed part over the scattered part; ``K = 0``: Rayleigh,
``E ~ Exp(1)``). Its density and survival function are (Rice; e.g. Goldsmith, *Wireless
Communications*, 2005, Sec. 3.2.1, eq. 3.37, with ``Omega = 1``)::

    f_E(e) = (K + 1) exp(-K - (K + 1) e) I0(2 sqrt(K (K + 1) e)),
    P(E >= e) = Q1(sqrt(2 K), sqrt(2 (K + 1) e)) = ncx2.sf(2 (K + 1) e; 2, 2 K).

The backscatter link is monostatic and reciprocal: the same channel carries the carrier
to the tag and the reply back, so the fading enters the RSSI *twice*, fully correlated:
``RSSI = mu_bar + X`` with ``mu_bar = reader_rssi_dbm(g_bar)`` and ``X = 20 log10 E``
(twice the one-way dB). For Rayleigh fading ``ln E`` is a Gumbel (minimum) variable, so
``X`` has mean ``-gamma 20 / ln 10 = -5.01 dB`` (the log bias: the mean of the dB lies
below the dB of the mean) and standard deviation ``pi / sqrt(6) * 20 / ln 10 = 11.14 dB``
(:data:`RAYLEIGH_RSSI_MEAN_DB`, :data:`RAYLEIGH_RSSI_SIGMA_DB`; one way: half of each).

The likelihood (:class:`FadedLikelihood`). The link closes when ``X >= t`` with
``t = T - mu_bar`` (``T = reader_rssi_dbm(g_T)``), so

    P(read | g_bar) = (1 - q) P(E >= g_T / g_bar),
    p(read, rssi = r | g_bar) = (1 - q) integral_{u >= t} f_X(u) phi_s(r - mu_bar - u) du,

``q`` the anti-collision miss probability, ``phi_s`` the reader's noise (and quantisation,
variance ``step^2 / 12``, as :class:`~.oracle_likelihood.OracleLikelihood`; plus any extra
Gaussian spread of the local mean itself, ``extra_sigma_db``), evaluated by Gauss-Legendre
quadrature over ``u`` within 6 ``s`` of the residual. Not a Gaussian: the density is
skewed (a long tail towards deep fades) and truncated where the link stops closing.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy import integrate, stats
from scipy.special import i0e

from pipeline.localisation.likelihood import EPS, Z_CLIP, _check_eps, _check_zclip
from pipeline.localisation.oracle_likelihood import OracleGains, OracleLikelihood

__all__ = [
    "RAYLEIGH",
    "RAYLEIGH_POWER_SIGMA_DB",
    "RAYLEIGH_RSSI_MEAN_DB",
    "RAYLEIGH_RSSI_SIGMA_DB",
    "FadedLikelihood",
    "FadedTerms",
    "FadingModel",
]

_DB_PER_NEPER_RSSI = 20.0 / np.log(10.0)  # X = 20 log10 E = (20 / ln 10) ln E
#: Mean of the RSSI's fading offset ``20 log10 E`` for Rayleigh fading [dB]: ``-gamma 20 / ln 10``.
RAYLEIGH_RSSI_MEAN_DB = float(-np.euler_gamma * _DB_PER_NEPER_RSSI)
#: Its standard deviation [dB]: ``pi / sqrt(6) * 20 / ln 10`` (twice the one-way value).
RAYLEIGH_RSSI_SIGMA_DB = float(np.pi / np.sqrt(6.0) * _DB_PER_NEPER_RSSI)
#: Standard deviation of a Rayleigh-faded one-way power in dB (10 log10 of Exp(1)).
RAYLEIGH_POWER_SIGMA_DB = 0.5 * RAYLEIGH_RSSI_SIGMA_DB
_N_NODES = 24  # Gauss-Legendre nodes over +-6 s: the Gaussian's integral to < 1e-8
_HALF_WIDTH = 6.0  # the noise kernel's support in standard deviations
_NODES, _WEIGHTS = np.polynomial.legendre.leggauss(_N_NODES)


@dataclass(frozen=True)
class FadingModel:
    """Rician fading of a one-way power about its local mean (see module doc).

    Attributes
    ----------
    k_factor : float
        Rician K (linear, >= 0): power of the fixed part over the scattered part;
        0 is Rayleigh fading.
    """

    k_factor: float = 0.0

    def __post_init__(self) -> None:
        k = float(self.k_factor)
        if not (np.isfinite(k) and k >= 0):
            raise ValueError(f"FadingModel.k_factor must be finite and >= 0, got {self.k_factor!r}")
        object.__setattr__(self, "k_factor", k)

    def power_logpdf(self, ratio) -> np.ndarray:
        """``log f_E`` of the power ratio ``E = g / g_bar`` (>= 0; unit mean)."""
        e = np.asarray(ratio, dtype=np.float64)
        k = self.k_factor
        z = 2.0 * np.sqrt(k * (k + 1.0) * np.maximum(e, 0.0))
        with np.errstate(divide="ignore"):
            out = np.log(k + 1.0) - k - (k + 1.0) * e + np.log(i0e(z)) + z
        return np.where(e >= 0, out, -np.inf)

    def power_logsf(self, ratio) -> np.ndarray:
        """``log P(E >= ratio)``."""
        e = np.maximum(np.asarray(ratio, dtype=np.float64), 0.0)
        if self.k_factor == 0.0:
            return -e  # Exp(1)
        k = self.k_factor
        return stats.ncx2.logsf(2.0 * (k + 1.0) * e, 2, 2.0 * k)

    def sample_power_ratio(self, shape, rng: np.random.Generator) -> np.ndarray:
        """Draws of ``E``: ``|sqrt(K / (K + 1)) + CN(0, 1 / (K + 1))|^2``."""
        k = self.k_factor
        re = np.sqrt(k / (k + 1.0)) + rng.standard_normal(shape) * np.sqrt(0.5 / (k + 1.0))
        im = rng.standard_normal(shape) * np.sqrt(0.5 / (k + 1.0))
        return re * re + im * im

    def rssi_offset_logpdf(self, x_db) -> np.ndarray:
        """Log-density [1/dB] of the RSSI's fading offset ``X = 20 log10 E`` at ``x_db``."""
        x = np.asarray(x_db, dtype=np.float64)
        ln_e = x / _DB_PER_NEPER_RSSI
        return self.power_logpdf(np.exp(ln_e)) + ln_e - np.log(_DB_PER_NEPER_RSSI)

    def rssi_offset_moments_db(self) -> tuple[float, float]:
        """Mean and standard deviation [dB] of ``X = 20 log10 E``: closed form for
        Rayleigh (module doc), by quadrature of the density otherwise."""
        if self.k_factor == 0.0:
            return RAYLEIGH_RSSI_MEAN_DB, RAYLEIGH_RSSI_SIGMA_DB

        def pdf(x):
            return float(np.exp(self.rssi_offset_logpdf(x)))

        m1 = integrate.quad(lambda x: x * pdf(x), -200.0, 40.0, limit=400)[0]
        m2 = integrate.quad(lambda x: (x - m1) ** 2 * pdf(x), -200.0, 40.0, limit=400)[0]
        return float(m1), float(np.sqrt(m2))


#: Rayleigh fading (K = 0): no path dominates the local mean.
RAYLEIGH = FadingModel(0.0)


class FadedTerms:
    """Per-pair terms of :class:`FadedLikelihood` (any shape P), for the filters.

    Attributes
    ----------
    log_read, log_miss : numpy.ndarray (P)
        ``log P(read)``, ``log (1 - P(read))`` (clipped probabilities).
    """

    def __init__(self, lik: FadedLikelihood, log_read, log_miss, mean_dbm, threshold_dbm) -> None:
        self._lik = lik
        self.log_read = np.asarray(log_read, dtype=np.float64)
        self.log_miss = np.asarray(log_miss, dtype=np.float64)
        self._mu = np.asarray(mean_dbm, dtype=np.float64)
        self._t = float(threshold_dbm)

    def read_loglik(self, rssi_dbm, index=None) -> np.ndarray:
        """``log p(read, rssi)`` at the pairs ``[index]``, broadcast with ``rssi_dbm``
        (NaN RSSI: the detection term only)."""
        mu = self._mu if index is None else self._mu[index]
        lr = self.log_read if index is None else self.log_read[index]
        r = np.asarray(rssi_dbm, dtype=np.float64)
        mu, lr, r = np.broadcast_arrays(mu, lr, r)
        out = lr.copy()
        ok = np.isfinite(r)
        if ok.any():
            out[ok] = lr[ok] + self._lik.rssi_logpdf_given_read(r[ok], mu[ok], self._t)
        return out

    def loglik(self, read, rssi_dbm, index=None) -> np.ndarray:
        """Log-likelihood of outcomes (read, rssi) at the pairs ``[index]`` (broadcasting);
        the RSSI density is evaluated at the reads only."""
        lm = self.log_miss if index is None else self.log_miss[index]
        mu = self._mu if index is None else self._mu[index]
        lr = self.log_read if index is None else self.log_read[index]
        read, lm, mu, lr, r = np.broadcast_arrays(np.asarray(read, bool), lm, mu, lr,
                                                  np.asarray(rssi_dbm, dtype=np.float64))
        out = lm.copy()
        sel = read & np.isfinite(r)
        out[read] = lr[read]
        if sel.any():
            out[sel] += self._lik.rssi_logpdf_given_read(r[sel], mu[sel], self._t)
        return out


class FadedLikelihood:
    """The reader's read likelihood given *local-mean* one-way gains (see module doc).

    Parameters
    ----------
    oracle : OracleLikelihood
        The reader (budget, thresholds, miss probability, RSSI noise and quantisation).
    fading : FadingModel
        The law of the coherent gain about its local mean.
    extra_sigma_db : float
        Gaussian spread of the local mean itself in the RSSI domain [dB] (e.g. a coarse
        model's error), added in quadrature to the reader's noise (>= 0).
    eps, z_clip : float
        Probability clip and RSSI density floor (the density of a ``z_clip`` sigma outlier
        of a Gaussian with the total spread), as :mod:`.likelihood`.
    """

    def __init__(self, oracle: OracleLikelihood, fading: FadingModel = RAYLEIGH, *,
                 extra_sigma_db: float = 0.0, eps: float = EPS, z_clip: float = Z_CLIP) -> None:
        if not float(extra_sigma_db) >= 0:
            raise ValueError(f"extra_sigma_db must be >= 0, got {extra_sigma_db!r}")
        self.oracle = oracle
        self.fading = fading
        self.budget = oracle.budget
        self.miss_probability = oracle.miss_probability
        self.noise_sigma_db = float(np.hypot(oracle.sigma_db, float(extra_sigma_db)))
        self.eps = _check_eps(eps)
        self.z_clip = _check_zclip(z_clip)
        self.threshold_dbm = oracle.threshold_dbm
        _, fs = fading.rssi_offset_moments_db()
        total = float(np.hypot(fs, self.noise_sigma_db))
        self._log_floor = -np.log(total) - 0.5 * np.log(2 * np.pi) - 0.5 * self.z_clip ** 2

    def read_probability(self, gain_db, miss_probability=None) -> np.ndarray:
        """Unclipped ``P(read)`` of local-mean one-way gains [dB] (-inf: 0)."""
        q = self.miss_probability if miss_probability is None else miss_probability
        g = np.asarray(gain_db, dtype=np.float64)
        with np.errstate(over="ignore", invalid="ignore"):
            ratio = 10.0 ** ((self.budget.min_gain_db() - g) / 10.0)  # g_T / g_bar
        p = np.exp(self.fading.power_logsf(np.nan_to_num(ratio, posinf=np.inf)))
        return np.where(np.isfinite(g), p, 0.0) * (1.0 - np.asarray(q, dtype=np.float64))

    def rssi_logpdf_given_read(self, rssi_dbm, mean_dbm, threshold_dbm=None) -> np.ndarray:
        """``log p(rssi | read)`` [1/dB] given the local mean's RSSI ``mean_dbm``
        (``reader_rssi_dbm(g_bar)``; -inf allowed), floored (class doc).

        ``p(rssi | read) = integral_{u >= t} f_X(u) phi_s(rssi - mean - u) du / P(X >= t)``,
        ``t = threshold_dbm - mean_dbm`` (default threshold: the reader's,
        ``reader_rssi_dbm(budget.min_gain_db())``)."""
        t_abs = self.threshold_dbm if threshold_dbm is None else float(threshold_dbm)
        r = np.asarray(rssi_dbm, dtype=np.float64)
        mu = np.asarray(mean_dbm, dtype=np.float64)
        r, mu = np.broadcast_arrays(r, mu)
        out = np.full(r.shape, self._log_floor)
        ok = np.isfinite(mu) & np.isfinite(r)
        if not ok.any():
            return out
        x = r[ok] - mu[ok]  # observed offset from the local mean's RSSI
        t = t_abs - mu[ok]  # the fading offset below which the link does not close
        s = self.noise_sigma_db
        lo = np.maximum(t, x - _HALF_WIDTH * s)
        hi = x + _HALF_WIDTH * s
        width = np.maximum(hi - lo, 0.0)
        u = 0.5 * (lo + hi)[:, None] + 0.5 * width[:, None] * _NODES[None, :]
        log_k = (self.fading.rssi_offset_logpdf(u) - 0.5 * ((x[:, None] - u) / s) ** 2
                 - np.log(s) - 0.5 * np.log(2 * np.pi))
        with np.errstate(divide="ignore", invalid="ignore"):
            joint = np.log(0.5 * width) + np.log(np.exp(log_k) @ _WEIGHTS)
            log_closed = self.fading.power_logsf(np.exp(t / _DB_PER_NEPER_RSSI))
            cond = joint - log_closed
        out[ok] = np.maximum(np.where(np.isfinite(cond), cond, -np.inf), self._log_floor)
        return out

    def terms(self, gain_db, miss_probability=None) -> FadedTerms:
        """Per-pair terms of local-mean gains [dB] (any shape; -inf where not traced)."""
        g = np.asarray(gain_db, dtype=np.float64)
        if np.any(np.isnan(g)):
            raise ValueError("local-mean gains contain NaN (use -inf for untraced pairs)")
        p = np.clip(self.read_probability(g, miss_probability), self.eps, 1.0 - self.eps)
        mu = np.asarray(self.budget.reader_rssi_dbm(g), dtype=np.float64)
        return FadedTerms(self, np.log(p), np.log1p(-p), mu, self.threshold_dbm)

    def log_likelihood(self, gain_db, read, rssi_dbm) -> np.ndarray:
        """Elementwise ``log p(read, rssi | g_bar)``."""
        return self.terms(gain_db).loglik(read, rssi_dbm)

    def with_gains(self, gain_db, miss_probability=None):
        """Bind a (slots x candidates) matrix of local-mean gains for
        :func:`~pipeline.localisation.localise_tags` (as :meth:`OracleLikelihood.with_gains`)."""
        return OracleGains(self, gain_db, miss_probability)
