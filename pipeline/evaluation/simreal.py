"""Simulation against reality: the ray tracer's prediction of a recorded tour, scored.

For a recording in a known building the recorded antenna poses and tag layout are traced
in the scene (:mod:`pipeline.stages.sim_vs_real`); every recorded attempt then has a
predicted read probability ``p`` (the noise-free link closes both thresholds, times one
minus the reader's miss probability: :func:`pipeline.evaluation.truth.true_detected`)
and a predicted RSSI (the noise-free backscatter power,
:func:`pipeline.evaluation.truth.true_rssi_dbm`). The quantities, on the held-out tags'
attempts within the traced range (module :func:`sim_vs_real`):

==================  =========================================================  ==========
key                 statistic                                                  over
==================  =========================================================  ==========
brier               mean (p - read)^2 (Brier 1950)                             attempts
read_rate_mae       mean over (tag, antenna) links of |predicted - measured|   links
                    read rate (predicted rate: mean p of the link's attempts)
rssi_bias_db        mean (predicted - measured) RSSI                           reads [1]
rssi_mae_db         mean |predicted - measured|                                reads [1]
rssi_rmse_db        sqrt(mean (predicted - measured)^2)                        reads [1]
==================  =========================================================  ==========

[1] the attempts that read the tag and whose traced link closes: RSSI exists in both;
their units are the tags with at least one such attempt.

Each is pooled over the held-out tags and gets a 95 % cluster-bootstrap interval over
them (:func:`~.intervals.unit_interval`); the bias is signed, and compared by its size.

**The baseline the tracer must beat** (:class:`LogDistanceBaseline`), fitted on the
*training* tags' attempts only: RSSI ``a + b 10 log10(d) + c_antenna`` by least squares
on the reads, and read probability ``sigmoid(a' + b' 10 log10(d) + c'_antenna)`` by
maximum likelihood (scipy.optimize, L-BFGS) on all attempts within range. Each
quantity of the tracer is compared with the baseline's on the same held-out tags
(:func:`~.intervals.paired_difference`): "better" / "worse" only where the 95 % interval
of the difference excludes 0.
"""

from __future__ import annotations

import zlib
from dataclasses import dataclass

import numpy as np
import pandas as pd

from pipeline.evaluation.intervals import paired_difference, unit_interval

__all__ = ["LogDistanceBaseline", "QUANTITIES", "fit_log_distance_baseline", "link_rates",
           "sim_vs_real"]

#: (key, label, lower is better).
QUANTITIES = (
    ("brier", "detection Brier score", True),
    ("read_rate_mae", "read rate MAE per link", True),
    ("rssi_bias_db", "RSSI bias, predicted - measured [dB]", True),
    ("rssi_mae_db", "RSSI MAE [dB]", True),
    ("rssi_rmse_db", "RSSI RMSE [dB]", True),
)


def _design(d_m, antenna, n_antennas: int) -> np.ndarray:
    d = np.maximum(np.asarray(d_m, np.float64), 1e-3)
    ant = np.asarray(antenna, np.int64)
    cols = [np.ones_like(d), 10.0 * np.log10(d)]
    cols += [(ant == k).astype(np.float64) for k in range(1, n_antennas)]
    return np.column_stack(cols)


@dataclass(frozen=True)
class LogDistanceBaseline:
    """Log-distance RSSI and logistic read probability with a per-antenna offset.

    Attributes
    ----------
    rssi_coef : numpy.ndarray
        [a (dBm), b (dB per 10 log10 m), c_1..c_{N-1} (dB, antenna k relative to 0)].
    detect_coef : numpy.ndarray
        The same design's logistic coefficients (log-odds).
    n_antennas : int
    """

    rssi_coef: np.ndarray
    detect_coef: np.ndarray
    n_antennas: int

    def rssi_dbm(self, d_m, antenna) -> np.ndarray:
        """Predicted RSSI [dBm]."""
        return _design(d_m, antenna, self.n_antennas) @ self.rssi_coef

    def p_read(self, d_m, antenna) -> np.ndarray:
        """Predicted read probability."""
        z = _design(d_m, antenna, self.n_antennas) @ self.detect_coef
        return 1.0 / (1.0 + np.exp(-z))

    def to_dict(self) -> dict:
        return {"rssi_coef": self.rssi_coef.tolist(), "detect_coef": self.detect_coef.tolist(),
                "n_antennas": self.n_antennas,
                "model": "rssi = a + b 10 log10(d) + c_antenna; logit p = a' + b' 10 log10(d) + c'_antenna"}


def fit_log_distance_baseline(d_m, antenna, read, rssi_dbm, n_antennas: int) -> LogDistanceBaseline:
    """Fit :class:`LogDistanceBaseline` on training attempts (module doc).

    Raises
    ------
    ValueError
        Fewer reads than coefficients.
    """
    from scipy.optimize import minimize

    X = _design(d_m, antenna, n_antennas)
    y = np.asarray(read, bool)
    s = np.asarray(rssi_dbm, np.float64)
    ok = y & np.isfinite(s)
    if ok.sum() < X.shape[1] + 1:
        raise ValueError(f"{int(ok.sum())} training reads: too few to fit the log-distance baseline")
    rssi_coef = np.linalg.lstsq(X[ok], s[ok], rcond=None)[0]
    ridge = 1e-6 * len(y)  # keeps the optimum finite where the reads separate perfectly

    def nll(beta):
        z = X @ beta
        # log(1 + e^z) - y z, stable for either sign of z
        val = np.logaddexp(0.0, z) - y * z
        p = 1.0 / (1.0 + np.exp(-z))
        return val.sum() + 0.5 * ridge * beta @ beta, X.T @ (p - y) + ridge * beta

    res = minimize(nll, np.zeros(X.shape[1]), jac=True, method="L-BFGS-B")
    return LogDistanceBaseline(rssi_coef, np.asarray(res.x), int(n_antennas))


def link_rates(att: pd.DataFrame) -> pd.DataFrame:
    """Per (tag, antenna) link: attempts, measured and predicted read rates, mean RSSIs.

    ``att`` holds one row per attempt: ``tag_id, antenna, read, rssi_dbm, p_sim, rssi_sim_dbm,
    p_base, rssi_base_dbm``. Mean RSSIs are over the link's reads (measured) and its reads
    whose traced link closes (predicted): NaN where there are none.
    """
    both = att["read"].to_numpy(bool) & np.isfinite(att["rssi_sim_dbm"].to_numpy(np.float64))
    a = att.assign(read=att["read"].astype(np.float64),
                   rssi_meas=np.where(att["read"].to_numpy(bool), att["rssi_dbm"], np.nan),
                   rssi_pred=np.where(both, att["rssi_sim_dbm"], np.nan))
    g = a.groupby(["tag_id", "antenna"], observed=True, sort=True)
    return pd.DataFrame({
        "n_attempts": g.size(), "measured_rate": g["read"].mean(), "predicted_rate": g["p_sim"].mean(),
        "baseline_rate": g["p_base"].mean(), "measured_rssi_dbm": g["rssi_meas"].mean(),
        "predicted_rssi_dbm": g["rssi_pred"].mean()}).reset_index()


def _rssi_rows(att: pd.DataFrame) -> np.ndarray:
    """Attempts with an RSSI in both: read, and a traced link that closes."""
    return att["read"].to_numpy(bool) & np.isfinite(att["rssi_sim_dbm"].to_numpy(np.float64))


def _statistics(att: pd.DataFrame, p_col: str, rssi_col: str, units: np.ndarray,
                rssi_units: np.ndarray) -> dict:
    """Weighted statistics ``w -> value`` of each quantity (w: multiplicity per unit; the
    RSSI quantities' units are ``rssi_units``, the tags with at least one RSSI in both)."""
    n = len(units)
    code = pd.Categorical(att["tag_id"].astype(str), categories=units).codes.astype(np.int64)

    def sums(values, codes=code, n=n):
        return np.bincount(codes, weights=np.asarray(values, np.float64), minlength=n)

    def ratio(num, den):
        def stat(w):
            with np.errstate(invalid="ignore", divide="ignore"):
                return (w @ num) / (w @ den)
        return stat

    read = att["read"].to_numpy(np.float64)
    p = att[p_col].to_numpy(np.float64)
    out = {"brier": ratio(sums((p - read) ** 2), sums(np.ones_like(p)))}
    links = att.assign(err=p - read).groupby(["tag_id", "antenna"], observed=True)["err"].mean()
    lcode = pd.Categorical(links.index.get_level_values(0).astype(str), categories=units).codes
    out["read_rate_mae"] = ratio(sums(np.abs(links.to_numpy()), lcode.astype(np.int64)),
                                 sums(np.ones(len(links)), lcode.astype(np.int64)))
    both = _rssi_rows(att)
    e = att[rssi_col].to_numpy(np.float64)[both] - att["rssi_dbm"].to_numpy(np.float64)[both]
    c = pd.Categorical(att["tag_id"].astype(str)[both], categories=rssi_units).codes.astype(np.int64)
    k = len(rssi_units)
    cnt = sums(np.ones_like(e), c, k)
    out["rssi_bias_db"] = ratio(sums(e, c, k), cnt)
    out["rssi_mae_db"] = ratio(sums(np.abs(e), c, k), cnt)
    mse = ratio(sums(e * e, c, k), cnt)
    out["rssi_rmse_db"] = lambda w: np.sqrt(mse(w))
    out["_n_rssi"] = int(both.sum())
    return out


def _absolute(stat):
    return lambda w: np.abs(stat(w))


def _rng(seed: int, *names: str) -> np.random.Generator:
    return np.random.default_rng([int(seed), *(zlib.crc32(s.encode()) for s in names)])


def sim_vs_real(att: pd.DataFrame, *, seed: int) -> dict:
    """Each quantity (:data:`QUANTITIES`) of the tracer and the baseline with intervals over
    the tags of ``att``, and their paired difference with its verdict.

    Parameters
    ----------
    att : pandas.DataFrame
        The held-out attempts within range, as :func:`link_rates` takes them.
    seed : int
        Seeds the resampling (one stream per quantity and model).

    Returns
    -------
    dict
        ``{key: {"label", "units", "n_tags", "ray_tracer": Interval dict, "baseline": Interval
        dict, "difference": Comparison dict (tracer - baseline)}}``, and ``n_attempts``,
        ``n_rssi_links`` (reads with a closing traced link).
    """
    units = np.unique(att["tag_id"].astype(str).to_numpy())
    rssi_units = np.unique(att["tag_id"].astype(str).to_numpy()[_rssi_rows(att)])
    stats = {"ray_tracer": _statistics(att, "p_sim", "rssi_sim_dbm", units, rssi_units),
             "baseline": _statistics(att, "p_base", "rssi_base_dbm", units, rssi_units)}
    out: dict = {"n_attempts": int(len(att)), "n_rssi_links": stats["ray_tracer"]["_n_rssi"],
                 "n_tags": len(units)}
    for key, label, lower in QUANTITIES:
        n = len(rssi_units) if key.startswith("rssi") else len(units)
        sec = {"label": label, "units": "tag", "n_tags": n}
        for model, st in stats.items():
            iv = unit_interval(st[key], n, _rng(seed, key, model))
            sec[model] = iv.to_dict()
        a, b = stats["ray_tracer"][key], stats["baseline"][key]
        if key == "rssi_bias_db":  # compare the size of the bias
            a, b = _absolute(a), _absolute(b)
        sec["difference"] = paired_difference(a, b, n, _rng(seed, key, "paired"),
                                              lower_is_better=lower).to_dict()
        if key == "rssi_bias_db":
            sec["difference"]["compares"] = "|bias|"
        out[key] = sec
    return out
