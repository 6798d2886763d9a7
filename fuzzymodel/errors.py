"""Exceptions and input validation shared by the fuzzy-model modules.

Every bad input raises :class:`FuzzyModelError` (a :class:`ValueError`) whose
message names the offending argument, key, file or value.
"""

from __future__ import annotations

import numpy as np

__all__ = [
    "FuzzyModelError",
    "FuzzyModelFileError",
    "check_matrix",
    "check_target",
    "check_weights",
]


class FuzzyModelError(ValueError):
    """Bad input to a fuzzy-model function: NaN/inf, wrong shape, too few samples."""


class FuzzyModelFileError(FuzzyModelError):
    """A saved model file is malformed; the message names the file and the key."""


def check_matrix(X, name: str = "X", n_features: int | None = None) -> np.ndarray:
    """Return `X` as a finite float64 array of shape (n_samples, n_features).

    Parameters
    ----------
    X : array_like, shape (n_samples, n_features)
        Data matrix, one sample per row.
    name : str
        Argument name used in error messages.
    n_features : int, optional
        Required number of columns.

    Raises
    ------
    FuzzyModelError
        If `X` is not 2-D, is empty, has the wrong number of columns, or holds
        NaN or inf (the message gives the first offending row and column).
    """
    try:
        arr = np.asarray(X, dtype=np.float64)
    except (TypeError, ValueError) as exc:
        raise FuzzyModelError(f"{name} is not numeric: {exc}") from exc
    if arr.ndim != 2:
        raise FuzzyModelError(
            f"{name} must be 2-D (n_samples, n_features), got shape {arr.shape}"
        )
    if arr.shape[0] == 0 or arr.shape[1] == 0:
        raise FuzzyModelError(f"{name} is empty (shape {arr.shape})")
    if n_features is not None and arr.shape[1] != n_features:
        raise FuzzyModelError(
            f"{name} has {arr.shape[1]} features (columns), the model expects {n_features}"
        )
    bad = ~np.isfinite(arr)
    if bad.any():
        row, col = np.argwhere(bad)[0]
        raise FuzzyModelError(
            f"{name} holds {int(bad.sum())} non-finite value(s) (NaN or inf); "
            f"first at row {row}, column {col}: {arr[row, col]}"
        )
    return arr


def check_target(y, n_samples: int, name: str = "y") -> np.ndarray:
    """Return `y` as a finite float64 vector of length `n_samples`.

    Parameters
    ----------
    y : array_like, shape (n_samples,) or (n_samples, 1)
        Target values.
    n_samples : int
        Number of rows of the matching input matrix.
    name : str
        Argument name used in error messages.

    Raises
    ------
    FuzzyModelError
        On a length mismatch, more than one output column, or NaN/inf.
    """
    return _finite_vector(y, n_samples, name, "samples", allow_column=True)


def _finite_vector(v, n_samples: int, name: str, unit: str, allow_column: bool) -> np.ndarray:
    """`v` as a finite float64 vector of length `n_samples` (errors name `name`)."""
    try:
        arr = np.asarray(v, dtype=np.float64)
    except (TypeError, ValueError) as exc:
        raise FuzzyModelError(f"{name} is not numeric: {exc}") from exc
    if allow_column and arr.ndim == 2 and arr.shape[1] == 1:
        arr = arr[:, 0]
    if arr.ndim != 1:
        raise FuzzyModelError(f"{name} must be 1-D (n_samples,), got shape {arr.shape}")
    if arr.shape[0] != n_samples:
        raise FuzzyModelError(
            f"{name} has {arr.shape[0]} {unit} but the inputs have {n_samples} rows"
        )
    bad = ~np.isfinite(arr)
    if bad.any():
        idx = int(np.flatnonzero(bad)[0])
        raise FuzzyModelError(
            f"{name} holds {int(bad.sum())} non-finite value(s) (NaN or inf); "
            f"first at index {idx}: {arr[idx]}"
        )
    return arr


def check_weights(w, n_samples: int, name: str = "sample_weight") -> np.ndarray:
    """Return sample weights `w` as a finite, non-negative float64 vector.

    Parameters
    ----------
    w : array_like, shape (n_samples,)
        Non-negative weight of each sample (e.g. the read attempts n+ + n- behind
        a detection-ratio cell); only their ratios matter.
    n_samples : int
        Number of rows of the matching input matrix.
    name : str
        Argument name used in error messages.

    Returns
    -------
    numpy.ndarray, shape (n_samples,), float64

    Raises
    ------
    FuzzyModelError
        If `w` is not 1-D of length `n_samples`, holds NaN, inf or a negative
        value (the message gives the first), or is all zero.
    """
    arr = _finite_vector(w, n_samples, name, "weights", allow_column=False)
    neg = arr < 0
    if neg.any():
        idx = int(np.flatnonzero(neg)[0])
        raise FuzzyModelError(
            f"{name} must be >= 0; {int(neg.sum())} negative value(s), first at index "
            f"{idx}: {arr[idx]}"
        )
    if not np.any(arr > 0):
        raise FuzzyModelError(f"{name} is all zero: no sample carries any weight")
    return arr
