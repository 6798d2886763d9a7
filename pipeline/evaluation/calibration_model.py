"""The calibration's model of an attempt and its likelihood (:mod:`.calibration`'s module
doc): the fitted parameters (:class:`CalibrationFit`), the construction parameters'
linearised gain change (:class:`MaterialTerms`), the prediction (:func:`predict`) and the
mean negative log-likelihood with its analytic gradient (:func:`nll`), which
:func:`.calibration.fit_calibration` maximises."""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass

import numpy as np
from scipy.special import digamma, expit, gammaln, log_ndtr, ndtr

__all__ = ["Attempts", "CalibrationFit", "MaterialTerms", "nll", "predict"]

@dataclass(frozen=True)
class MaterialTerms:
    """:class:`.calibration.MaterialModel`'s gain change linearised at ``at``: ``base_db + jac_db (theta - at)``
    ((n,), (n, k) dB per unit log ratio; ``at`` (k,); ``lower``/``upper`` the fit's range)."""

    at: np.ndarray
    base_db: np.ndarray
    jac_db: np.ndarray
    lower: np.ndarray
    upper: np.ndarray

    def delta_db(self, theta) -> np.ndarray:
        return self.base_db + self.jac_db @ (np.asarray(theta, np.float64) - self.at)

    def rows(self, mask) -> MaterialTerms:
        return MaterialTerms(self.at, self.base_db[mask], self.jac_db[mask], self.lower, self.upper)


@dataclass(frozen=True)
class CalibrationFit:
    """Fitted reader parameters (module doc), SI-like units in dB."""

    antenna_offsets_db: np.ndarray
    tag_sensitivity_offset_db: float
    rssi_offset_db: float
    rssi_noise_db: float
    detection_spread_db: float
    miss_probability: float = 0.0
    #: The RSSI's Student-t degrees of freedom (inf: Gaussian, the unrobust likelihood).
    rssi_dof: float = float("inf")
    #: Share of attempts read whatever their traced margin.
    stray_read_probability: float = 0.0
    #: Construction parameters, log ratio to the traced value (:class:`.calibration.MaterialModel`).
    material_log_ratios: np.ndarray = dataclasses.field(default_factory=lambda: np.zeros(0))
    #: With construction parameters: the reader's parameters fitted alone (no construction
    #: changed), for a calibrated study that leaves the building as traced.
    reader_only: CalibrationFit | None = None

    @classmethod
    def from_vector(cls, x: np.ndarray, n_antennas: int, robust: bool = True) -> CalibrationFit:
        """From the fit's vector: the k = n_antennas - 1 offsets, delta_s, r, log sigma_r,
        log sigma_t, logit q, log nu, logit s, then theta (nu and s ignored unless robust)."""
        k = n_antennas - 1
        return cls(np.r_[0.0, x[:k]], float(x[k]), float(x[k + 1]), float(np.exp(x[k + 2])),
                   float(np.exp(x[k + 3])), float(expit(x[k + 4])),
                   float(np.exp(x[k + 5])) if robust else float("inf"),
                   float(expit(x[k + 6])) if robust else 0.0,
                   np.asarray(x[k + 7:], np.float64))

    def as_dict(self) -> dict:
        return {f"antenna_offset_db[{i}]": float(v) for i, v in enumerate(self.antenna_offsets_db)} | {
            "tag_sensitivity_offset_db": self.tag_sensitivity_offset_db,
            "rssi_offset_db": self.rssi_offset_db, "rssi_noise_db": self.rssi_noise_db,
            "detection_spread_db": self.detection_spread_db,
            "miss_probability": self.miss_probability} | ({} if np.isinf(self.rssi_dof) else {
                "rssi_dof": self.rssi_dof, "stray_read_probability": self.stray_read_probability}) | {
            f"theta[{j}]": float(v) for j, v in enumerate(self.material_log_ratios)}


def _margin(gain, antenna, offsets, dsens, budget):
    g = gain + offsets[antenna]
    tag = np.asarray(budget.tag_power_dbm(g), np.float64) - (budget.tag_sensitivity_dbm + dsens)
    rx = np.asarray(budget.reader_rssi_dbm(g), np.float64)
    return np.minimum(tag, rx - budget.reader_sensitivity_dbm), rx


def predict(fit: CalibrationFit, gain_db, antenna, budget, terms: MaterialTerms | None = None):
    """Read probability and expected RSSI [dBm] of attempts under ``fit`` (module doc);
    ``terms`` the construction parameters' gain change for these rows."""
    g = np.asarray(gain_db, np.float64)
    if terms is not None:
        g = g + terms.delta_db(fit.material_log_ratios)
    m, rx = _margin(g, np.asarray(antenna, np.int64),
                    fit.antenna_offsets_db, fit.tag_sensitivity_offset_db, budget)
    s = fit.stray_read_probability
    p = (1.0 - fit.miss_probability) * (s + (1.0 - s) * ndtr(m / fit.detection_spread_db))
    return p, rx + fit.rssi_offset_db


def _slopes(budget) -> tuple[float, float]:
    """dB per dB of one-way gain of the tag's power and the reader's RSSI: the link budget's
    powers are affine in the gain (:class:`propagation.LinkBudget`: 1 and 2)."""
    g = np.array([0.0, 1.0])
    t, r = (np.asarray(f(g), np.float64) for f in (budget.tag_power_dbm, budget.reader_rssi_dbm))
    return float(t[1] - t[0]), float(r[1] - r[0])


@dataclass(frozen=True)
class Attempts:
    """What the likelihood needs of the attempts, computed once per fit: the margins and the
    reader's RSSI at the traced gain, which every parameter only shifts (:func:`_slopes`)."""

    antenna: np.ndarray
    read: np.ndarray
    tag_margin: np.ndarray  # P_tag(g) - S_tag
    rx: np.ndarray  # P_rx(g)
    slope_tag: float
    slope_rx: float
    weight: np.ndarray
    ok: np.ndarray  # rows of reads with an RSSI
    rssi: np.ndarray  # theirs
    total: float  # the weights' sum (at least 1)

    @classmethod
    def of(cls, gain, antenna, read, rssi, weight, budget) -> Attempts:
        ok = np.flatnonzero(read & np.isfinite(rssi))
        st, sr = _slopes(budget)
        tag = np.asarray(budget.tag_power_dbm(gain), np.float64) - budget.tag_sensitivity_dbm
        return cls(antenna, read, tag, np.asarray(budget.reader_rssi_dbm(gain), np.float64), st, sr,
                   weight, ok, rssi[ok], max(float(weight.sum()), 1.0))


_LOG_2PI = float(np.log(2.0 * np.pi))


def nll(x, a: Attempts, reader_sensitivity_dbm, n_ant, terms, robust):
    """The mean negative log-likelihood of the attempts (module doc) and its gradient in
    ``x`` (:meth:`CalibrationFit.from_vector`'s vector), analytic: one pass over the
    attempts per evaluation, where finite differences took one per parameter."""
    f = CalibrationFit.from_vector(x, n_ant, robust)
    k = n_ant - 1
    shift = f.antenna_offsets_db[a.antenna]
    if terms is not None:
        shift = shift + terms.delta_db(f.material_log_ratios)
    q, s = f.miss_probability, f.stray_read_probability
    tag = a.tag_margin + a.slope_tag * shift - f.tag_sensitivity_offset_db
    rx = a.rx + a.slope_rx * shift
    on_tag = tag <= rx - reader_sensitivity_dbm
    m = np.where(on_tag, tag, rx - reader_sensitivity_dbm)
    z = m / f.detection_spread_db
    log1q, log1s, log_q = np.log1p(-q), np.log1p(-s), np.log(q)
    # log((1 - q)(s + (1 - s) Phi(z))) and log(1 - that) = log(q + (1 - q)(1 - s) Phi(-z)),
    # each stable in both tails (log 0 = -inf where s = 0: logaddexp gives the other term)
    with np.errstate(divide="ignore"):
        log_s = np.log(s)
    lnd_p, lnd_m = log_ndtr(z), log_ndtr(-z)
    p_read = np.logaddexp(log_s, log1s + lnd_p)  # log(s + (1 - s) Phi(z))
    ll_read = log1q + p_read
    ll_miss = np.logaddexp(log_q, log1q + log1s + lnd_m)
    read = a.read
    ll = np.where(read, ll_read, ll_miss)
    # d ll / dz, d ll / d logit q, d ll / d logit s (each a ratio of the mixture's terms)
    phi = log1q + log1s - 0.5 * z * z - 0.5 * _LOG_2PI
    d_z = np.where(read, np.exp(phi - ll_read), -np.exp(phi - ll_miss))
    d_q = np.where(read, -q, np.exp(log_q + log1q + p_read - ll_miss))
    w = a.weight
    d_m = w * d_z / f.detection_spread_db  # weighted d ll / d margin
    d_shift = d_m * np.where(on_tag, a.slope_tag, a.slope_rx)
    grad = np.zeros(len(x))
    grad[k] = -(d_m @ on_tag)
    grad[k + 3] = -(w @ (d_z * z))
    grad[k + 4] = w @ d_q
    if robust:
        d_s = np.exp(log1q + log_s + log1s + lnd_m - np.where(read, ll_read, ll_miss))
        grad[k + 6] = w @ np.where(read, d_s, -d_s)
    # the reads' RSSI: e = rssi - P_rx(g') - r, Student-t (robust) or Gaussian
    ok, wr = a.ok, w[a.ok]
    sigma = f.rssi_noise_db
    e = a.rssi - rx[ok] - f.rssi_offset_db
    e2 = e * e
    if robust:
        nu = f.rssi_dof
        c = 0.5 * (nu + 1.0)
        u = e2 / (sigma * sigma)
        ll_rssi = (gammaln(c) - gammaln(0.5 * nu) - 0.5 * np.log(np.pi * nu) - np.log(sigma)
                   - c * np.log1p(u / nu))
        d_e = -(nu + 1.0) * e / (nu * sigma * sigma + e2)
        grad[k + 2] = wr @ (-1.0 + (nu + 1.0) * e2 / (nu * sigma * sigma + e2))
        grad[k + 5] = nu * (wr @ (0.5 * (digamma(c) - digamma(0.5 * nu)) - 0.5 / nu
                                  - 0.5 * np.log1p(u / nu) + c * u / (nu * (nu + u))))
    else:
        ll_rssi = -0.5 * _LOG_2PI - np.log(sigma) - 0.5 * e2 / (sigma * sigma)
        d_e = -e / (sigma * sigma)
        grad[k + 2] = wr @ (-1.0 + e2 / (sigma * sigma))
    grad[k + 1] = -(wr @ d_e)
    np.add.at(d_shift, ok, -a.slope_rx * wr * d_e)
    grad[:k] = np.bincount(a.antenna, weights=d_shift, minlength=n_ant)[1:n_ant]
    if terms is not None:
        grad[k + 7:] = d_shift @ terms.jac_db
    value = -(w @ ll + wr @ ll_rssi) / a.total
    return value, -grad / a.total
