"""Calibration of the simulated reader to a recording: link-budget offsets by maximum likelihood.

The ray tracer gives every recorded attempt its traced one-way gain ``g``
(:mod:`pipeline.stages.sim_vs_real`). The reader around it has parameters no drawing
of the building knows; this module fits them on the *training* tags' attempts and
scores the result on the held-out tags':

==========================  ===========================================================
parameter                   meaning
==========================  ===========================================================
antenna_offsets_db[a]       one-way gain of antenna a relative to antenna 0 [dB] (cable,
                            connectors, the panel's own gain); enters the tag's power
                            once and the backscatter RSSI twice
tag_sensitivity_offset_db   the tags' wake-up threshold relative to reader.tag_sensitivity_dbm
rssi_offset_db              the reader's reported RSSI relative to the received power
rssi_noise_db               spread of the reported RSSI about the prediction
detection_spread_db         spread of the read threshold (probit), fading the tracer
                            does not resolve
miss_probability            share of closing attempts the reader still misses (slot
                            collisions, a dwell too short for the tag population)
==========================  ===========================================================

The model of an attempt of antenna a with traced gain g: ``g' = g + delta_a``;
``P(read) = (1 - q) Phi(m / sigma_t)`` with the margin ``m = min(P_tag(g') - (S_tag +
delta_s), P_rx(g') - S_reader)`` (:class:`propagation.LinkBudget`) and q the reader's
miss probability (fitted: the simulated reader's own estimate missed 13 % of the
closing attempts of a simulated Gen2 log, which a threshold shift would otherwise
absorb); a read's RSSI ``~ N(P_rx(g') + r, sigma_r)``. The likelihood of every
attempt (read or not) and every read's RSSI is maximised with ``scipy.optimize.minimize``
(L-BFGS-B; a handful of parameters, so numerical gradients).

**What the data cannot tell apart** (and so what is fixed): where the tag's side limits
the link (the usual UHF case), a gain common to every antenna is the same, in the reads,
as a tag sensitivity offset plus twice that in the reader's RSSI offset (``delta_a + t``,
``delta_s + t``, ``r - 2t`` give the same likelihood), so antenna 0's offset is 0 and the
others are relative to it. Attempts the tracer found no path for have no gain to offset
and are left out (counted). Material
parameters (a wall's permittivity) would need the path geometry re-weighted per trial;
they are not fitted here.

Intervals: every parameter's 95 % percentile interval from refits on the training tags
resampled with replacement (the tag the unit, :data:`N_BOOT` resamples, each from the
point estimate; none below :data:`MIN_TAGS` tags). A percentile interval, not BCa: each
resample is a whole maximum-likelihood fit, so the jackknife's n more fits are not spent. The held-out comparison, before (the uncalibrated hard threshold of
:mod:`.simreal`) and after, is :func:`.simreal.sim_vs_real`'s on the same tags.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import pandas as pd
from scipy.optimize import minimize
from scipy.special import log_ndtr, ndtr

__all__ = ["N_BOOT", "CalibrationFit", "calibrate", "fit_calibration", "predict"]

#: Bootstrap resamples of the training tags behind each interval (5 per tail at 95 %).
N_BOOT = 200
#: Fewest training tags an interval is drawn from.
MIN_TAGS = 5
_LOG_2PI = float(np.log(2.0 * np.pi))


@dataclass(frozen=True)
class CalibrationFit:
    """Fitted reader parameters (module doc), SI-like units in dB."""

    antenna_offsets_db: np.ndarray
    tag_sensitivity_offset_db: float
    rssi_offset_db: float
    rssi_noise_db: float
    detection_spread_db: float
    miss_probability: float = 0.0

    @classmethod
    def from_vector(cls, x: np.ndarray, n_antennas: int) -> CalibrationFit:
        k = n_antennas - 1
        return cls(np.r_[0.0, x[:k]], float(x[k]), float(x[k + 1]), float(np.exp(x[k + 2])),
                   float(np.exp(x[k + 3])), float(1.0 / (1.0 + np.exp(-x[k + 4]))))

    def as_dict(self) -> dict:
        return {f"antenna_offset_db[{i}]": float(v) for i, v in enumerate(self.antenna_offsets_db)} | {
            "tag_sensitivity_offset_db": self.tag_sensitivity_offset_db,
            "rssi_offset_db": self.rssi_offset_db, "rssi_noise_db": self.rssi_noise_db,
            "detection_spread_db": self.detection_spread_db,
            "miss_probability": self.miss_probability}


def _margin(gain, antenna, offsets, dsens, budget):
    g = gain + offsets[antenna]
    tag = np.asarray(budget.tag_power_dbm(g), np.float64) - (budget.tag_sensitivity_dbm + dsens)
    rx = np.asarray(budget.reader_rssi_dbm(g), np.float64)
    return np.minimum(tag, rx - budget.reader_sensitivity_dbm), rx


def predict(fit: CalibrationFit, gain_db, antenna, budget):
    """Read probability and expected RSSI [dBm] of attempts under ``fit`` (module doc)."""
    m, rx = _margin(np.asarray(gain_db, np.float64), np.asarray(antenna, np.int64),
                    fit.antenna_offsets_db, fit.tag_sensitivity_offset_db, budget)
    return (1.0 - fit.miss_probability) * ndtr(m / fit.detection_spread_db), rx + fit.rssi_offset_db


def _nll(x, gain, antenna, read, rssi, weight, budget, n_ant):
    f = CalibrationFit.from_vector(x, n_ant)
    q = f.miss_probability
    m, rx = _margin(gain, antenna, f.antenna_offsets_db, f.tag_sensitivity_offset_db, budget)
    z = m / f.detection_spread_db
    log1q = np.log1p(-q)
    ll_read = log1q + log_ndtr(z)
    # log(1 - (1 - q) Phi(z)) = log(q + (1 - q) Phi(-z)), stable in both tails
    ll_miss = np.logaddexp(np.log(q), log1q + log_ndtr(-z))
    ll = np.where(read, ll_read, ll_miss)
    ok = read & np.isfinite(rssi)
    e = (rssi[ok] - rx[ok] - f.rssi_offset_db) / f.rssi_noise_db
    ll_rssi = -0.5 * (e * e + _LOG_2PI) - np.log(f.rssi_noise_db)
    return -(weight @ ll + weight[ok] @ ll_rssi) / max(float(weight.sum()), 1.0)


def fit_calibration(att: pd.DataFrame, budget, n_antennas: int, *, miss_probability=0.05,
                    weight=None, start=None, strict: bool = True) -> CalibrationFit:
    """Maximum-likelihood :class:`CalibrationFit` on attempts ``att`` (``gain_db`` finite,
    ``antenna``, ``read``, ``rssi_dbm``); ``weight`` per row (a bootstrap's multiplicities);
    ``miss_probability`` the start of its fit.

    Raises
    ------
    ValueError
        (``strict``) The optimiser did not converge, or an offset or spread ended on the
        edge of its range (+-30 dB; 30 dB): a failed fit, not a calibration.
    """
    if not np.all(np.isfinite(att["gain_db"].to_numpy(np.float64))):
        raise ValueError("calibration: attempts without a traced gain cannot be fitted "
                         "(drop them first: calibrate() does)")
    gain = att["gain_db"].to_numpy(np.float64)
    antenna = att["antenna"].to_numpy(np.int64)
    read = att["read"].to_numpy(bool)
    rssi = att["rssi_dbm"].to_numpy(np.float64)
    w = np.ones(len(att)) if weight is None else np.asarray(weight, np.float64)
    q0 = float(np.clip(miss_probability, 0.01, 0.5))
    x0 = (np.r_[np.zeros(n_antennas - 1), 0.0, 0.0, np.log(2.0), np.log(2.0), np.log(q0 / (1 - q0))]
          if start is None else start)
    k = n_antennas - 1
    # offsets within +-30 dB, spreads within [0.05, 30] dB, misses within [1e-4, 0.9]: a
    # value on such a bound is a failed fit
    bounds = ([(-30.0, 30.0)] * (k + 2) + [(np.log(0.05), np.log(30.0))] * 2
              + [(np.log(1e-4 / (1 - 1e-4)), np.log(0.9 / 0.1))])
    res = minimize(_nll, x0, args=(gain, antenna, read, rssi, w, budget, n_antennas),
                   method="L-BFGS-B", bounds=bounds)
    fit = CalibrationFit.from_vector(res.x, n_antennas)
    if strict:
        if not res.success or not np.isfinite(res.fun):
            raise ValueError(f"calibration: the maximum-likelihood fit did not converge "
                             f"({str(res.message)[:80]}); the recording may hold too few reads")
        edge = [name for name, v, hi in
                [(f"antenna_offset_db[{i + 1}]", abs(x), 30.0) for i, x in enumerate(res.x[:k])]
                + [("tag_sensitivity_offset_db", abs(res.x[k]), 30.0),
                   ("rssi_offset_db", abs(res.x[k + 1]), 30.0),
                   ("rssi_noise_db", float(np.exp(res.x[k + 2])), 30.0),
                   ("detection_spread_db", float(np.exp(res.x[k + 3])), 30.0)]
                if v >= hi * (1 - 1e-6)]
        if edge:
            raise ValueError(f"calibration: {', '.join(edge)} ended on the edge of its range "
                             "(30 dB): the traced building and the recording disagree beyond "
                             "what the reader's parameters can explain (check the mounts, "
                             "the poses' frame, recording.antenna_ports)")
    object.__setattr__(fit, "_x", res.x)
    return fit


def _bootstrap(att, budget, n_ant, point, rng, n_boot):
    tags = att["tag_id"].astype(str).to_numpy()
    units, code = np.unique(tags, return_inverse=True)
    rows = []
    for _ in range(n_boot):
        mult = np.bincount(rng.integers(0, len(units), len(units)), minlength=len(units))
        f = fit_calibration(att, budget, n_ant, weight=mult[code], strict=False,
                            start=point._x)  # noqa: SLF001 - our own start vector
        rows.append(f.as_dict())
    return pd.DataFrame(rows)


def calibrate(att: pd.DataFrame, budget, n_antennas: int, *, miss_probability=0.0,
              seed: int, n_boot: int = N_BOOT) -> tuple[CalibrationFit, dict]:
    """Fit on the training attempts, intervals by resampling training tags, and the held-out
    residual before and after (module doc).

    Parameters
    ----------
    att : pandas.DataFrame
        Attempts within the traced range: ``split`` ("train"/"eval"), ``tag_id``,
        ``antenna``, ``read``, ``rssi_dbm``, ``gain_db`` (finite), ``p_sim`` and
        ``rssi_sim_dbm`` (the uncalibrated prediction).
    miss_probability : array_like
        The simulated reader's miss probability of each attempt: its mean starts the fit.
    seed : int

    Returns
    -------
    fit : CalibrationFit
    report : dict
        ``parameters`` (each: value, low, high, unit), ``fixed`` (what the data cannot
        separate), ``heldout`` (:func:`.simreal.sim_vs_real` with ``after`` the calibrated
        and ``before`` the uncalibrated prediction), ``n_train_tags``, ``n_boot``.
    """
    from .simreal import sim_vs_real

    q = float(np.mean(miss_probability))
    traced = np.isfinite(att["gain_db"].to_numpy(np.float64))
    # an attempt the tracer found no path for has no gain to offset: left out, counted
    n_untraced = int((~traced).sum())
    n_untraced_reads = int((~traced & att["read"].to_numpy(bool)).sum())
    att = att[traced]
    train = att[att["split"] == "train"].reset_index(drop=True)
    held = att[att["split"] == "eval"].reset_index(drop=True)
    fit = fit_calibration(train, budget, n_antennas, miss_probability=max(q, 0.05))
    n_tags = int(train["tag_id"].nunique())
    boot = (_bootstrap(train, budget, n_antennas, fit, np.random.default_rng([int(seed), 53]),
                       int(n_boot)) if n_tags >= MIN_TAGS else None)
    params = {}
    for key, value in fit.as_dict().items():
        lo, hi = (np.percentile(boot[key].to_numpy(np.float64), [2.5, 97.5]) if boot is not None
                  else (None, None))
        params[key] = {"value": value, "low": None if lo is None else float(lo),
                       "high": None if hi is None else float(hi),
                       "unit": "" if key == "miss_probability" else "dB"}
        if boot is None:
            params[key]["note"] = f"{n_tags} training tags: an interval needs at least {MIN_TAGS}"
    params["antenna_offset_db[0]"].update(low=0.0, high=0.0, note="fixed: the reference antenna")
    p_after, rssi_after = predict(fit, held["gain_db"], held["antenna"], budget)
    rx_before = np.asarray(budget.reader_rssi_dbm(held["gain_db"].to_numpy(np.float64)), np.float64)
    cmp_att = held.assign(p_base=held["p_sim"], rssi_base_dbm=rx_before,
                          p_sim=p_after, rssi_sim_dbm=rssi_after)
    heldout = sim_vs_real(cmp_att, seed=seed)
    for sec in heldout.values():
        if isinstance(sec, dict) and "ray_tracer" in sec:
            sec["after"], sec["before"] = sec.pop("ray_tracer"), sec.pop("baseline")
            sec["difference"]["compares"] = "after - before" + (
                " (|bias|)" if sec["difference"].get("compares") == "|bias|" else "")
    return fit, {
        "parameters": params,
        "fixed": "antenna 0's offset is 0: a gain common to all antennas equals a tag "
                 "sensitivity offset plus twice that in the RSSI offset",
        "heldout": heldout, "n_train_tags": n_tags, "n_boot": int(n_boot) if boot is not None else 0,
        "n_attempts_untraced": n_untraced, "n_reads_untraced": n_untraced_reads,
        "simulated_miss_probability": q,
    }
