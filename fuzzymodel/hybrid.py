"""The two numerical rules of ANFIS's hybrid learning (Jang 1993) outside the network.

- :func:`solve_least_squares`: the forward pass's least-squares estimate of the
  consequents, robust to rank deficiency;
- :func:`update_step_size`: Jang's step-size heuristic for the backward pass.
"""

from __future__ import annotations

import numpy as np
from scipy.linalg import cho_factor, cho_solve

__all__ = ["solve_least_squares", "update_step_size"]

#: Relative ridge of the normal equations (see :func:`solve_least_squares`).
_RIDGE = 1e-12


def solve_least_squares(A: np.ndarray, y: np.ndarray) -> np.ndarray:
    """Least-squares solution of ``A theta = y`` that survives rank deficiency.

    Solves the normal equations ``(A^T A + lambda I) theta = A^T y`` by
    Cholesky, with a tiny ridge ``lambda = _RIDGE * mean(diag(A^T A))``: for a
    full-rank A the bias is below the rounding of the data, and for a rank
    deficient A (duplicated or collinear inputs, rules that never fire) it
    gives the minimum-norm solution instead of blowing up, because ``A^T y``
    has no component in the null space. If Cholesky still fails, an
    eigen-decomposition pseudo-inverse is used. The normal equations cost one
    (P, n) x (n, P) product, several times cheaper than an SVD of A.
    """
    G = A.T @ A
    b = A.T @ y
    lam = _RIDGE * max(float(np.trace(G)) / G.shape[0], np.finfo(np.float64).tiny)
    G[np.diag_indices_from(G)] += lam
    try:
        return cho_solve(cho_factor(G, check_finite=False), b, check_finite=False)
    except np.linalg.LinAlgError:
        evals, evecs = np.linalg.eigh(G)
        keep = evals > lam
        return evecs[:, keep] @ ((evecs[:, keep].T @ b) / evals[keep])


def update_step_size(errors, step_size: float, increase: float = 1.1, decrease: float = 0.9):
    """Jang's step-size heuristic (Jang 1993, Sec. V, rules 1 and 2).

    Parameters
    ----------
    errors : sequence of float
        Training errors so far, oldest first.
    step_size : float
        Current :math:`\\kappa`.
    increase, decrease : float
        Factors for rule 1 (four consecutive reductions) and rule 2 (two
        consecutive combinations of one increase and one reduction, in either
        order).

    Returns
    -------
    float
        The new step size.
    """
    if len(errors) < 5:
        return step_size
    s = np.sign(np.diff(np.asarray(errors[-5:], dtype=np.float64)))
    if np.all(s < 0):
        return step_size * increase
    if np.all(s != 0) and np.all(s[1:] == -s[:-1]):
        return step_size * decrease
    return step_size
