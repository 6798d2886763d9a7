"""Confidence intervals by resampling independent units, and paired comparisons.

Every headline number of a study is a statistic of observations that come in
*units* which are independent of each other while the observations inside one unit
are not: the read attempts and links of one held-out tag (correlated along the tour),
the steps of one particle-filter run. The intervals here resample units, never the
observations inside them (a cluster bootstrap; Davison & Hinkley, *Bootstrap Methods
and their Application*, 1997, Sec. 3.8: resampling the top-level units only is
consistent for the variance of a statistic of clustered data).

The resampling itself is :func:`scipy.stats.bootstrap` (BCa by default: Efron,
"Better bootstrap confidence intervals", JASA 82, 1987): it draws the units' indices,
and the statistic is evaluated from each unit's *multiplicity* in the resample, shape
(n_resamples, n_units), so that a statistic of pooled observations (an RMSE over every
link of the drawn tags, a median over every step of the drawn runs) is one vectorised
weighted computation (:func:`weighted_quantile`, :func:`weighted_mean`). Nothing here
draws a resample by hand.

Paired comparisons (:func:`paired_difference`) evaluate two statistics on the *same*
resampled units and give the interval of their difference and a verdict: "better",
"worse" or "not distinguishable at 95 %".

Bootstrap intervals over few units are too narrow: on clustered data with a known
RMSE (tests/pipeline/evaluation/test_intervals.py, 1,000 data sets) a plain 95 % BCa
interval covered 85 % with 16 units, 89 % with 40. The resampling is therefore asked
for Hesterberg's *expanded* level (T. Hesterberg, "What teachers should know about the
bootstrap", The American Statistician 69(4), 2015, Sec. 5.2: the level whose normal
quantile is sqrt(n / (n - 1)) t_{n-1} at the nominal level, :func:`expanded_level`),
which gave 91 % with 16 units, 92 % with 30 and 94 % with 80 on the same data: a
single run's 16 held-out tags give intervals a little short of 95 %, a replicated
study's pooled units close to it.

Pooled replicates are two-stage data: a replicate's tags share its tour, its reads and
its fitted models, so (replicate, tag) units are not independent. With ``clusters``
(the replicate of each unit, :func:`clusters_of` reads it from ``r<k>/<id>`` names)
the intervals resample in two stages, as Davison & Hinkley (Sec. 3.8, "strategy 2")
describe: replicates with replacement, then units with replacement inside each drawn
replicate (:func:`two_stage_multiplicity`), so the model-fit variance between
replicates is in the interval. scipy.stats.bootstrap resamples one level only, so this
resampling is our own; the interval is the percentile interval of that distribution at
the level expanded for the number of *replicates* (BCa's jackknife has no two-stage
form in scipy). Coverage was checked by simulation for each statistic kind the tool
reports (tests/pipeline/evaluation/test_two_stage.py).

Where the bootstrap distribution is degenerate (every resample gives the same value,
e.g. two models with identical errors on every unit) the interval is that value, with
``method = "degenerate"``; with fewer than :data:`MIN_UNITS` units no interval is
given (``low``/``high`` None and a ``note`` saying why): a bootstrap over three units
says nothing.
"""

from __future__ import annotations

import warnings
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
from scipy import stats

from pipeline.evaluation.metrics import nan_to_none

__all__ = [
    "CONFIDENCE",
    "MIN_REPLICATES",
    "MIN_UNITS",
    "N_RESAMPLES",
    "Comparison",
    "Interval",
    "clusters_of",
    "expanded_level",
    "fold_interval",
    "multiplicity",
    "two_stage_multiplicity",
    "paired_difference",
    "unit_interval",
    "verdict",
    "weighted_mean",
    "weighted_quantile",
]

#: Confidence level of every interval.
CONFIDENCE = 0.95
#: Bootstrap resamples; 2,000 puts the Monte-Carlo error of a 95 % BCa endpoint well
#: below the interval's width for 16-100 units (Efron & Tibshirani 1993, Sec. 19.3).
N_RESAMPLES = 2000
#: Fewer independent units than this: no interval (a bootstrap needs units to resample).
MIN_UNITS = 5

#: Fewest replicates a two-stage interval is given for (two: the between-replicate
#: variance rests on one difference).
MIN_REPLICATES = 3

#: Highest resampling level of a two-stage interval (:func:`expanded_level` of 3 or 4
#: replicates exceeds it).
MAX_LEVEL = 0.999

#: Resamples evaluated at once (bounds the memory of a statistic over many observations).
_BATCH = 250
#: Two-stage multiplicities drawn at once, in entries (resamples x units: 32 MB as
#: float64, about 130 MB at the draw's peak with its index arrays): the draw's Python
#: loop runs per call, the statistic still per :data:`_BATCH`.
_DRAW_ENTRIES = 4_000_000

#: A weighted statistic: unit multiplicities, shape (..., n_units) -> value, shape (...).
WeightedStatistic = Callable[[np.ndarray], np.ndarray]


@dataclass(frozen=True)
class Interval:
    """A statistic with its 95 % confidence interval over independent units.

    Attributes
    ----------
    estimate : float
        The statistic on the data as observed (every unit once).
    low, high : float or None
        Interval endpoints (same unit as the estimate); None when there are fewer than
        :data:`MIN_UNITS` units or the statistic is undefined.
    n_units : int
        Independent units resampled.
    unit : str
        What a unit is ("tag", "filter run", "replicate x tag", ...).
    method : str
        "BCa", "percentile" (asked for, or BCa undefined on this sample), "two-stage
        percentile" (pooled replicates), "degenerate" (every resample equal) or "none";
        " (folded)" appended where the interval is the image of a signed one under |.|
        (:func:`fold_interval`).
    confidence : float
        Nominal coverage.
    note : str or None
        Why there is no interval, where there is none.
    """

    estimate: float
    low: float | None
    high: float | None
    n_units: int
    unit: str
    method: str
    confidence: float = CONFIDENCE
    note: str | None = None

    def to_dict(self) -> dict:
        """JSON-able dict; NaN becomes None."""
        return nan_to_none({"estimate": self.estimate, "low": self.low, "high": self.high,
                            "n_units": self.n_units, "unit": self.unit, "method": self.method,
                            "confidence": self.confidence, "note": self.note})


@dataclass(frozen=True)
class Comparison:
    """A model's metric minus the reference model's on the same units.

    Attributes
    ----------
    difference : Interval
        ``metric(model) - metric(reference)`` with its interval.
    verdict : str
        "better", "worse" or "not distinguishable at 95 %" (:func:`verdict`).
    lower_is_better : bool
        Direction of the metric (errors: True; shares within a bound: False).
    """

    difference: Interval
    verdict: str
    lower_is_better: bool

    def to_dict(self) -> dict:
        """JSON-able dict."""
        return {**self.difference.to_dict(), "verdict": self.verdict,
                "lower_is_better": self.lower_is_better}


def multiplicity(indices: np.ndarray, n_units: int) -> np.ndarray:
    """How often each unit occurs in each resample.

    Parameters
    ----------
    indices : ndarray, shape (..., m), int
        Unit indices in ``[0, n_units)`` (one resample per row; m = n_units for a
        bootstrap resample, n_units - 1 for a jackknife sample).
    n_units : int

    Returns
    -------
    ndarray, shape (..., n_units), float64
    """
    idx = np.asarray(indices).astype(np.intp)
    flat = idx.reshape(-1, idx.shape[-1])
    return _row_counts(flat, int(n_units)).reshape(*idx.shape[:-1], int(n_units))


def _row_counts(flat: np.ndarray, n: int) -> np.ndarray:
    """Counts of each of ``0 .. n-1`` in each row of ``flat`` (r, m), float64 (r, n):
    one :func:`numpy.bincount` over row-offset indices (``np.add.at`` took ten times as
    long on the two-stage resampling's many small draws)."""
    r = flat.shape[0]
    keys = (np.arange(r, dtype=np.intp)[:, None] * n + flat).ravel()
    return np.bincount(keys, minlength=r * n).astype(np.float64).reshape(r, n)


def weighted_mean(values: np.ndarray, weights: np.ndarray) -> np.ndarray:
    """Mean of ``values`` (n,) with weights (..., n) per resample; NaN where they sum to 0."""
    w = np.asarray(weights, dtype=np.float64)
    tot = w.sum(axis=-1)
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.where(tot > 0, (w * np.asarray(values, np.float64)).sum(axis=-1) / tot, np.nan)


def weighted_quantile(values: np.ndarray, weights: np.ndarray, q: float) -> np.ndarray:
    """The ``q`` quantile of ``values`` (n,) under integer-like weights (..., n).

    With every weight 1 it equals ``numpy.quantile(values, q)`` (linear interpolation,
    NumPy's default): a resample is the sample with each observation repeated by its
    weight, and the quantile is interpolated between the order statistics at positions
    ``q (N - 1)`` of the repeated sample, N the total weight. NaN where N = 0.
    """
    v = np.asarray(values, dtype=np.float64)
    order = np.argsort(v, kind="stable")
    vs = v[order]
    w = np.asarray(weights, dtype=np.float64)[..., order]
    cum = np.cumsum(w, axis=-1)  # cum[k]: repeated-sample positions covered by vs[:k+1]
    total = cum[..., -1:]
    pos = q * (total - 1.0)  # 0-based position in the repeated sample
    lo = np.floor(pos)
    frac = pos - lo
    # the order statistic at 0-based position p is vs[first k with cum[k] > p]
    k_lo = np.minimum((cum <= lo).sum(axis=-1, keepdims=True), len(v) - 1)
    k_hi = np.minimum((cum <= lo + 1.0).sum(axis=-1, keepdims=True), len(v) - 1)
    v_lo, v_hi = vs[k_lo], vs[k_hi]
    with np.errstate(invalid="ignore"):  # inf - inf where both order statistics are inf
        out = np.where((frac > 0) & (v_hi != v_lo), v_lo + frac * (v_hi - v_lo), v_lo)
    return np.where(total > 0, out, np.nan)[..., 0]


def expanded_level(n_units: int, confidence: float = CONFIDENCE) -> float:
    """Hesterberg's (2015, Sec. 5.2) expanded confidence level for ``n_units`` units:
    ``1 - 2 Phi(-sqrt(n / (n - 1)) t_{n-1, 1 - a/2})`` with ``a = 1 - confidence``
    (0.972 for 16 units, 0.955 for 80, the nominal level as n grows)."""
    n = int(n_units)
    a = (1.0 - float(confidence)) / 2.0
    z = np.sqrt(n / (n - 1.0)) * stats.t.ppf(1.0 - a, n - 1)
    return float(1.0 - 2.0 * stats.norm.sf(z))


def clusters_of(units) -> np.ndarray | None:
    """The replicate of each pooled unit name ``r<k>/<id>`` as an int array, or None
    when the names are not all pooled (one run's units are independent)."""
    names = [str(u) for u in np.asarray(units).ravel()]
    heads = [n.split("/", 1)[0] for n in names]
    if not names or not all("/" in n and h[:1] == "r" and h[1:].isdigit()
                            for n, h in zip(names, heads, strict=True)):
        return None
    return np.array([int(h[1:]) for h in heads], dtype=np.int64)


def two_stage_multiplicity(clusters, rng: np.random.Generator, n_resamples: int) -> np.ndarray:
    """Multiplicities of a two-stage bootstrap: replicates with replacement, then each
    drawn replicate's units with replacement (Davison & Hinkley, Sec. 3.8, strategy 2).

    Parameters
    ----------
    clusters : array_like, int, (n_units,)
        The replicate of each unit.
    rng : numpy.random.Generator
    n_resamples : int

    Returns
    -------
    numpy.ndarray, float64, (n_resamples, n_units)
        How often each unit occurs in each resample.
    """
    c = np.asarray(clusters)
    ids, inv = np.unique(c, return_inverse=True)
    n_r, n, b = len(ids), len(c), int(n_resamples)
    times = multiplicity(rng.integers(0, n_r, size=(b, n_r)), n_r).astype(np.intp)
    # every unit draw as one index (resample * n + unit) into the flat (b, n) counts, so
    # that the loop below only draws (one call per replicate and number of times drawn,
    # in the order the stream has always been consumed in) and one bincount counts
    keys = []
    for g in range(n_r):
        members = np.flatnonzero(inv == g)
        by_times = np.argsort(times[:, g], kind="stable")  # rows ascending within each m
        n_with = np.bincount(times[:, g], minlength=2)
        start = int(n_with[0])
        for m in range(1, len(n_with)):  # resamples that drew replicate g m times
            n_m = int(n_with[m])
            if n_m == 0:
                continue
            rows = by_times[start:start + n_m]
            start += n_m
            draws = rng.integers(0, members.size, size=(n_m, m * members.size))
            keys.append((rows[:, None] * n + members[draws]).ravel())
    if not keys:
        return np.zeros((b, n))
    return np.bincount(np.concatenate(keys), minlength=b * n).astype(np.float64).reshape(b, n)


def _two_stage_interval(statistic, n: int, clusters, rng, unit: str, n_resamples: int,
                        est: float) -> Interval:
    n_r = len(np.unique(clusters))
    if n_r < MIN_REPLICATES:
        return _no_interval(est, n, unit, f"{n_r} replicates: a two-stage interval needs at "
                                          f"least {MIN_REPLICATES}")
    # Hesterberg's expansion for 3-4 replicates asks for more than 99.9 %; capped there
    # (the tails would rest on a handful of distinct replicate draws)
    level = min(expanded_level(n_r), MAX_LEVEL)
    n_res = max(int(n_resamples), int(np.ceil(50.0 / (1.0 - level))))
    # drawn in large chunks (the draw loops over replicates and draw counts per call: 100
    # calls of 250 for the 25,000 resamples of a 5-replicate interval), evaluated per _BATCH
    parts = []
    for b in _batches(n_res, max(_BATCH, _DRAW_ENTRIES // max(n, 1))):
        w = two_stage_multiplicity(clusters, rng, b)
        parts += [np.asarray(statistic(w[i:i + _BATCH]), float) for i in range(0, b, _BATCH)]
    dist = np.concatenate(parts)
    if np.all(dist == est):
        return Interval(est, est, est, n, unit, "degenerate")
    dist = dist[np.isfinite(dist)]
    if dist.size < 0.9 * n_res:  # resamples without observations: no honest interval
        return _no_interval(est, n, unit, "the two-stage bootstrap distribution is undefined "
                                          "(resamples without observations)")
    a = (1.0 - level) / 2.0
    lo, hi = np.quantile(dist, [a, 1.0 - a])
    return Interval(est, float(lo), float(hi), n, unit, "two-stage percentile")


def _batches(total: int, size: int = 2000):
    while total > 0:
        yield min(size, total)
        total -= size


def _no_interval(estimate: float, n: int, unit: str, note: str) -> Interval:
    return Interval(float(estimate), None, None, int(n), unit, "none", CONFIDENCE, note)


def fold_interval(signed: Interval) -> Interval:
    """The interval of ``|x|`` from the interval of a signed ``x`` (an |bias| from the
    bias): its image under the absolute value, ``[0, max(|low|, |high|)]`` when it holds
    0, else ``[min, max]`` of the endpoints' magnitudes. A bootstrap of ``|x|`` itself
    can never reach 0 (every resample's |x| > 0), so it could not say "no bias"."""
    import dataclasses

    est = abs(signed.estimate)
    if signed.low is None or signed.high is None:
        return dataclasses.replace(signed, estimate=est)
    lo, hi = float(signed.low), float(signed.high)
    a, b = (0.0, max(-lo, hi)) if lo <= 0.0 <= hi else sorted((abs(lo), abs(hi)))
    return dataclasses.replace(signed, estimate=est, low=a, high=b,
                               method=f"{signed.method} (folded)")


def unit_interval(statistic: WeightedStatistic, n_units: int, rng: np.random.Generator, *,
                  unit: str = "tag", n_resamples: int = N_RESAMPLES,
                  clusters=None, method: str = "BCa") -> Interval:
    """95 % interval of a statistic of independent units (:func:`scipy.stats.bootstrap`).

    Parameters
    ----------
    statistic : callable
        ``statistic(w)`` with ``w`` the units' multiplicities, shape (..., n_units),
        returning shape (...): the statistic of the sample in which unit i occurs
        ``w[..., i]`` times. Every weight 1 is the observed sample.
    n_units : int
    rng : numpy.random.Generator
        The resampling stream.
    unit : str
        What a unit is (for the record).
    n_resamples : int
        At least; raised so that each tail holds about 25 resamples at the expanded level.
    clusters : array_like of int, (n_units,), optional
        The replicate of each unit: two-stage resampling (module doc) when they hold at
        least two replicates.
    method : {"BCa", "percentile"}
        "percentile" for quantile statistics (a median, a p90) of few units: BCa's
        acceleration comes from the jackknife, which is inconsistent for quantiles, and
        its interval then moves with the bootstrap seed.

    Returns
    -------
    Interval
        With ``clusters``: the two-stage percentile interval. Else BCa at the expanded level (:func:`expanded_level`; the nominal coverage is
        :data:`CONFIDENCE`) where it is defined, else the percentile interval; "degenerate" when every
        resample gives the estimate; none below :data:`MIN_UNITS` units or when the
        statistic of the observed sample is not finite.
    """
    if method not in ("BCa", "percentile"):
        raise ValueError(f"method must be 'BCa' or 'percentile', got {method!r}")
    n = int(n_units)
    est = float(statistic(np.ones(n))) if n else float("nan")
    if n < MIN_UNITS:
        return _no_interval(est, n, unit, f"{n} {unit}s: an interval needs at least {MIN_UNITS}")
    if not np.isfinite(est):
        return _no_interval(est, n, unit, "the statistic is undefined on this sample")
    if clusters is not None and len(np.unique(clusters)) >= 2:
        if len(clusters) != n:
            raise ValueError(f"clusters has {len(clusters)} entries for {n} units")
        return _two_stage_interval(statistic, n, np.asarray(clusters), rng, unit, n_resamples,
                                   est)

    def stat(idx, axis=-1):
        return statistic(multiplicity(np.moveaxis(idx, axis, -1), n))

    level = expanded_level(n)
    # each tail of the expanded level rests on >= ~25 resamples (5 units: 0.998, 25,000)
    n_res = max(int(n_resamples), int(np.ceil(50.0 / (1.0 - level))))
    tries = ("BCa", "percentile") if method == "BCa" else ("percentile",)
    for method in tries:  # noqa: B020 - the one asked for, then the fallback
        with warnings.catch_warnings():
            warnings.simplefilter("error", stats.DegenerateDataWarning)
            warnings.simplefilter("ignore", RuntimeWarning)
            try:
                res = stats.bootstrap((np.arange(n),), stat, n_resamples=n_res,
                                      vectorized=True, method=method, rng=rng,
                                      confidence_level=level, batch=_BATCH)
            except stats.DegenerateDataWarning:
                dist = stat(rng.integers(0, n, size=(200, n)))
                if np.all(dist == est):
                    return Interval(est, est, est, n, unit, "degenerate")
                continue
        lo, hi = float(res.confidence_interval.low), float(res.confidence_interval.high)
        if np.all(res.bootstrap_distribution == est):
            return Interval(est, est, est, n, unit, "degenerate")
        if np.isfinite(lo) and np.isfinite(hi):
            return Interval(est, lo, hi, n, unit, method)
    return _no_interval(est, n, unit, "the bootstrap distribution is undefined "
                                      "(a resample without observations)")


def verdict(difference: Interval, lower_is_better: bool) -> str:
    """"better" / "worse" when the interval of (model - reference) excludes 0, else
    "not distinguishable at 95 %" (also when there is no interval)."""
    lo, hi = difference.low, difference.high
    if lo is None or hi is None:
        return "not distinguishable at 95 %"
    if hi < 0 or lo > 0:
        lower = hi < 0
        return "better" if lower == lower_is_better else "worse"
    return "not distinguishable at 95 %"


def paired_difference(model: WeightedStatistic, reference: WeightedStatistic, n_units: int,
                      rng: np.random.Generator, *, lower_is_better: bool = True,
                      unit: str = "tag", n_resamples: int = N_RESAMPLES,
                      clusters=None, method: str = "BCa") -> Comparison:
    """``model - reference`` of one metric on the same resampled units, with a verdict.

    Parameters
    ----------
    model, reference : callable
        Weighted statistics (:func:`unit_interval`) of the two models over the SAME
        units (index i is the same tag / run for both).
    n_units : int
    rng : numpy.random.Generator
    lower_is_better : bool
        True for errors, False for shares within a bound.
    unit : str
    n_resamples : int
    clusters : array_like of int, optional
        The replicate of each unit (two-stage resampling, :func:`unit_interval`).
    method : {"BCa", "percentile"}
        As :func:`unit_interval`'s.

    Returns
    -------
    Comparison
    """
    diff = unit_interval(lambda w: model(w) - reference(w), n_units, rng, unit=unit,
                         n_resamples=n_resamples, clusters=clusters, method=method)
    return Comparison(diff, verdict(diff, lower_is_better), bool(lower_is_better))
