"""Fuzzy C-Means clustering (Bezdek 1981) on (n_samples, n_features) data.

The iteration is implemented here rather than delegated to
``skfuzzy.cluster.cmeans`` because scikit-fuzzy draws its initial partition
from NumPy's *global* generator (it reseeds the legacy global state, then
draws from it), which would break the project rule that randomness comes
only from a caller's :class:`numpy.random.Generator`. The update equations,
the distance floor and the stopping rule are the same as scikit-fuzzy 0.5's,
so both give the same result from the same initial partition (tested).

References
----------
J. C. Bezdek, *Pattern Recognition with Fuzzy Objective Function Algorithms*.
Plenum, 1981.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass

import numpy as np

from .errors import FuzzyModelError, check_matrix, check_weights

__all__ = ["FCMResult", "fcm"]

_log = logging.getLogger(__name__)


@dataclass(frozen=True)
class FCMResult:
    """Outcome of :func:`fcm`.

    Attributes
    ----------
    centers : numpy.ndarray, shape (n_clusters, n_features), float64
        Cluster prototypes :math:`v_k`, in the units of the data.
    memberships : numpy.ndarray, shape (n_samples, n_clusters), float64
        Fuzzy partition :math:`u_{ik}` in [0, 1]; each row sums to 1.
    objective : numpy.ndarray, shape (n_iter,), float64
        Objective :math:`J_m = \\sum_i \\sum_k u_{ik}^m \\|x_i - v_k\\|^2` at each
        iteration (data units squared); non-increasing. With sample weights
        :math:`w_i`, each sample's term is multiplied by :math:`w_i`.
    partition_coefficient : float
        Bezdek's fuzzy partition coefficient :math:`\\sum u_{ik}^2 / n` in
        [1/c, 1]; 1 means a crisp partition. With sample weights,
        :math:`\\sum_i w_i \\sum_k u_{ik}^2 / \\sum_i w_i`.
    n_iter : int
        Number of iterations run.
    converged : bool
        True if the membership change fell below `tol` before `max_iter`.
    """

    centers: np.ndarray
    memberships: np.ndarray
    objective: np.ndarray
    partition_coefficient: float
    n_iter: int
    converged: bool


def _distances(X: np.ndarray, centers: np.ndarray) -> np.ndarray:
    # Euclidean distances (n_samples, n_clusters), floored like scikit-fuzzy
    # so a sample sitting on a centre does not divide by zero.
    d2 = ((X[:, None, :] - centers[None, :, :]) ** 2).sum(axis=2)
    return np.fmax(np.sqrt(d2), np.finfo(np.float64).eps)


def _memberships(d: np.ndarray, m: float) -> np.ndarray:
    # u_ik = 1 / sum_j (d_ik / d_ij)^(2/(m-1))  (Bezdek 1981, eq. 11.3b);
    # written as d^(-2/(m-1)) normalised over clusters.
    p = d ** (-2.0 / (m - 1.0))
    return p / p.sum(axis=1, keepdims=True)


def fcm(
    X,
    n_clusters: int = 3,
    m: float = 2.0,
    tol: float = 1e-5,
    max_iter: int = 300,
    rng: np.random.Generator | None = None,
    initial_memberships=None,
    sample_weight=None,
) -> FCMResult:
    """Fuzzy C-Means clustering.

    Alternates the centre update :math:`v_k = \\sum_i u_{ik}^m x_i / \\sum_i u_{ik}^m`
    and the membership update :math:`u_{ik} = 1/\\sum_j (d_{ik}/d_{ij})^{2/(m-1)}`
    (Bezdek 1981) until the Frobenius norm of the membership change is below `tol`.

    Parameters
    ----------
    X : array_like, shape (n_samples, n_features)
        Data, one sample per row; finite.
    n_clusters : int
        Number of clusters c, 1 <= c <= n_samples.
    m : float
        Fuzzifier exponent, > 1.
    tol : float
        Stopping tolerance on ``||U_new - U_old||_F``.
    max_iter : int
        Maximum number of iterations (>= 1).
    rng : numpy.random.Generator
        Source of the random initial partition (rows drawn uniform, then
        normalised to sum 1). Required unless `initial_memberships` is given.
    initial_memberships : array_like, shape (n_samples, n_clusters), optional
        Explicit initial partition (rows are normalised to sum 1).
    sample_weight : array_like, shape (n_samples,), optional
        Non-negative sample weights :math:`w_i` (not all zero). They enter
        Bezdek's objective as :math:`J_m = \\sum_i w_i \\sum_k u_{ik}^m
        \\|x_i - v_k\\|^2`, which is what FCM minimises on data where sample
        i is repeated :math:`w_i` times: the centre update becomes
        :math:`v_k = \\sum_i w_i u_{ik}^m x_i / \\sum_i w_i u_{ik}^m`; the
        membership update (per sample) is unchanged. The partition coefficient
        is weighted the same way. None: every weight 1 (plain FCM).

    Returns
    -------
    FCMResult

    Raises
    ------
    FuzzyModelError
        On NaN/inf in `X`, more clusters than samples, ``m <= 1``, or a bad
        initial partition.
    """
    X = check_matrix(X, "X")
    n = X.shape[0]
    c = int(n_clusters)
    if c < 1:
        raise FuzzyModelError(f"n_clusters must be >= 1, got {n_clusters}")
    if c > n:
        raise FuzzyModelError(f"n_clusters={c} is more than the {n} samples in X")
    if not (np.isfinite(m) and m > 1.0):
        raise FuzzyModelError(f"fuzzifier m must be > 1, got {m}")
    if max_iter < 1:
        raise FuzzyModelError(f"max_iter must be >= 1, got {max_iter}")
    if initial_memberships is None:
        if rng is None:
            raise FuzzyModelError("fcm needs rng (a numpy.random.Generator) or initial_memberships")
        u = rng.random((n, c))
    else:
        u = np.asarray(initial_memberships, dtype=np.float64)
        if u.shape != (n, c):
            raise FuzzyModelError(
                f"initial_memberships has shape {u.shape}, expected ({n}, {c})"
            )
        if not np.all(np.isfinite(u)) or np.any(u < 0) or np.any(u.sum(axis=1) <= 0):
            raise FuzzyModelError("initial_memberships must be finite, >= 0, rows summing > 0")
    u = u / u.sum(axis=1, keepdims=True)
    sw = None if sample_weight is None else check_weights(sample_weight, n)

    objective = []
    converged = False
    centers = np.empty((c, X.shape[1]))
    for _ in range(int(max_iter)):
        um = u**m if sw is None else (u**m) * sw[:, None]
        centers = (um.T @ X) / um.sum(axis=0)[:, None]
        d = _distances(X, centers)
        objective.append(float((um * d * d).sum()))
        u_new = _memberships(d, m)
        change = float(np.linalg.norm(u_new - u))
        u = u_new
        if change < tol:
            converged = True
            break
    if not converged:
        _log.warning("fcm did not converge in %d iterations (tol=%g)", max_iter, tol)
    return FCMResult(
        centers=centers,
        memberships=u,
        objective=np.asarray(objective),
        partition_coefficient=(float((u * u).sum() / n) if sw is None
                               else float((sw @ (u * u).sum(axis=1)) / sw.sum())),
        n_iter=len(objective),
        converged=converged,
    )
