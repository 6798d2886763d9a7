"""Error statistics shared by every comparison: MAE, RMSE, bias, Brier score.

Conventions: the error is ``e = predicted - reference`` (so a model that reads
3 dB high has bias +3 dB); statistics ignore pairs where either side is NaN and
report how many pairs they used. Empty inputs give NaN statistics, never an
exception, so a study on a sparse scene still writes its metrics file.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass

import numpy as np

__all__ = [
    "ErrorStats",
    "brier_score",
    "error_stats",
    "nan_to_none",
    "pearson_correlation",
    "percentile_summary",
    "PercentileSummary",
]


@dataclass(frozen=True)
class ErrorStats:
    """Summary of ``e = predicted - reference`` over paired samples.

    Attributes
    ----------
    n : int
        Number of finite pairs used.
    mae : float
        Mean absolute error, ``mean(|e|)`` (units of the inputs).
    rmse : float
        Root-mean-square error, ``sqrt(mean(e**2))``.
    bias : float
        Mean signed error, ``mean(e)``; positive means the prediction is high.
    median_abs : float
        Median of ``|e|``.
    p90_abs : float
        90th percentile of ``|e|`` (linear interpolation, NumPy default).
    max_abs : float
        Largest ``|e|``.
    correlation : float
        Pearson correlation of predicted and reference; NaN with fewer than two
        pairs or a constant side.
    """

    n: int
    mae: float
    rmse: float
    bias: float
    median_abs: float
    p90_abs: float
    max_abs: float
    correlation: float

    def to_dict(self) -> dict:
        """JSON-able dict; NaN becomes None."""
        return nan_to_none(asdict(self))


@dataclass(frozen=True)
class PercentileSummary:
    """Mean, median and 90th percentile of a non-negative error sample.

    Attributes
    ----------
    n : int
        Number of finite values used.
    mean, median, p90, max : float
        Statistics of the values (their unit); NaN when ``n == 0``.
    """

    n: int
    mean: float
    median: float
    p90: float
    max: float

    def to_dict(self) -> dict:
        """JSON-able dict; NaN becomes None."""
        return nan_to_none(asdict(self))


def _pair(predicted, reference) -> tuple[np.ndarray, np.ndarray]:
    p = np.asarray(predicted, dtype=np.float64)
    r = np.asarray(reference, dtype=np.float64)
    try:
        p, r = np.broadcast_arrays(p, r)
    except ValueError as exc:
        raise ValueError(
            f"predicted {p.shape} and reference {r.shape} do not broadcast together"
        ) from exc
    p = p.ravel()
    r = r.ravel()
    ok = np.isfinite(p) & np.isfinite(r)
    return p[ok], r[ok]


def pearson_correlation(x, y) -> float:
    """Pearson correlation of finite pairs; NaN if undefined (n < 2 or a constant side)."""
    a, b = _pair(x, y)
    if a.size < 2:
        return float("nan")
    a = a - a.mean()
    b = b - b.mean()
    den = math.sqrt(float(a @ a) * float(b @ b))
    if den == 0.0:
        return float("nan")
    return float(a @ b) / den


def error_stats(predicted, reference) -> ErrorStats:
    """Error statistics of `predicted` against `reference`.

    Parameters
    ----------
    predicted, reference : array_like, float
        Broadcastable arrays in the same unit (dB, probability, ...). Pairs with
        NaN or inf on either side are dropped.

    Returns
    -------
    ErrorStats
    """
    p, r = _pair(predicted, reference)
    if p.size == 0:
        nan = float("nan")
        return ErrorStats(0, nan, nan, nan, nan, nan, nan, nan)
    e = p - r
    ae = np.abs(e)
    return ErrorStats(
        n=int(e.size),
        mae=float(ae.mean()),
        rmse=float(np.sqrt(np.mean(e * e))),
        bias=float(e.mean()),
        median_abs=float(np.median(ae)),
        p90_abs=float(np.percentile(ae, 90)),
        max_abs=float(ae.max()),
        correlation=pearson_correlation(p, r),
    )


def percentile_summary(values) -> PercentileSummary:
    """Mean, median, p90 and max of the finite entries of `values`."""
    v = np.asarray(values, dtype=np.float64).ravel()
    v = v[np.isfinite(v)]
    if v.size == 0:
        nan = float("nan")
        return PercentileSummary(0, nan, nan, nan, nan)
    return PercentileSummary(
        n=int(v.size),
        mean=float(v.mean()),
        median=float(np.median(v)),
        p90=float(np.percentile(v, 90)),
        max=float(v.max()),
    )


def brier_score(probability, outcome) -> float:
    """Brier score ``mean((p - o)**2)`` of forecasts `p` on binary outcomes `o`.

    Brier (1950), Mon. Weather Rev. 78(1):1-3. 0 is a perfect forecast; a
    constant forecast equal to the base rate ``b`` scores ``b (1 - b)``.

    Parameters
    ----------
    probability : array_like, float in [0, 1]
    outcome : array_like, bool or {0, 1}, same shape

    Returns
    -------
    float
        NaN when there is no finite pair.
    """
    p = np.asarray(probability, dtype=np.float64).ravel()
    o = np.asarray(outcome).ravel()
    if p.shape != o.shape:
        raise ValueError(f"probability {p.shape} and outcome {o.shape} differ in shape")
    o = o.astype(np.float64)
    ok = np.isfinite(p) & np.isfinite(o)
    if not ok.any():
        return float("nan")
    if np.any((o[ok] != 0.0) & (o[ok] != 1.0)):
        raise ValueError("outcome must be boolean (0 or 1)")
    return float(np.mean((p[ok] - o[ok]) ** 2))


def nan_to_none(obj):
    """Recursively convert NaN/inf floats to None and NumPy scalars to Python (JSON-able)."""
    if isinstance(obj, dict):
        return {str(k): nan_to_none(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [nan_to_none(v) for v in obj]
    if isinstance(obj, np.ndarray):
        return [nan_to_none(v) for v in obj.tolist()]
    if isinstance(obj, (bool, np.bool_)):
        return bool(obj)
    if isinstance(obj, (int, np.integer)):
        return int(obj)
    if isinstance(obj, (float, np.floating)):
        f = float(obj)
        return f if math.isfinite(f) else None
    return obj
