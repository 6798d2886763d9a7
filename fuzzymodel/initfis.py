"""Initial fuzzy inference systems for ANFIS: grid partition and FCM clusters.

Both builders work on inputs already normalised to the unit box (see
:class:`fuzzymodel.ANFIS`), and return a :class:`Premise`: the membership
functions of every input, stored as one flat list, and the rule table that
indexes into it.

* :func:`grid_premise` follows MATLAB's ``genfis1``: `n` membership functions
  per input evenly spaced over the input range, every combination a rule.
  Bell MFs get ``a`` = half the spacing, ``b = 2``, ``c`` = the centres (so
  neighbours cross at membership 0.5, Jang 1993, Sec. VI, Example 1);
  Gaussian MFs get the same 0.5 crossover,
  ``sigma = spacing / (2 sqrt(2 ln 2))``.
* :func:`fcm_premise` follows ``genfis3`` (``genfis`` with FCM clustering):
  one rule per cluster, each input's Gaussian centred on the cluster centre's
  coordinate. The width is the cluster's membership-weighted spread along that
  input, :math:`\\sigma_{ki} = \\sqrt{\\sum_n u_{nk}^m (x_{ni} - v_{ki})^2 /
  \\sum_n u_{nk}^m}` (the diagonal of the fuzzy covariance matrix, Gustafson &
  Kessel 1979), floored at `min_sigma`. This is our documented choice: MATLAB's
  source was not consulted, its documentation only says the widths come from
  the memberships.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .errors import FuzzyModelError
from .membership import MF_PARAM_NAMES

__all__ = ["Premise", "fcm_premise", "grid_premise"]

_SQRT_8_LN2 = float(np.sqrt(8.0 * np.log(2.0)))


@dataclass(frozen=True)
class Premise:
    """Antecedent part of a Takagi-Sugeno system.

    Attributes
    ----------
    mf_type : str
        Membership-function family, ``"gauss"`` or ``"bell"``.
    mf_input : numpy.ndarray, shape (n_mfs_total,), int64
        Input index each membership function belongs to.
    mf_params : numpy.ndarray, shape (n_mfs_total, n_params), float64
        Parameters in ``MF_PARAM_NAMES[mf_type]`` order, normalised input units.
    rules : numpy.ndarray, shape (n_rules, n_inputs), int64
        ``rules[r, i]`` is the index (into `mf_params`) of the membership
        function of input ``i`` in rule ``r``.
    """

    mf_type: str
    mf_input: np.ndarray
    mf_params: np.ndarray
    rules: np.ndarray


def grid_premise(n_inputs: int, n_mfs, mf: str = "bell") -> Premise:
    """genfis1-style grid partition of the unit box [0, 1]^n_inputs.

    Parameters
    ----------
    n_inputs : int
        Number of inputs.
    n_mfs : int or sequence of int
        Membership functions per input (>= 1); an int applies to all inputs.
    mf : {"bell", "gauss"}
        Membership-function family.

    Returns
    -------
    Premise
        ``prod(n_mfs)`` rules; the first input varies slowest.
    """
    if mf not in MF_PARAM_NAMES:
        raise FuzzyModelError(f"unknown mf {mf!r}; expected one of {sorted(MF_PARAM_NAMES)}")
    counts = np.broadcast_to(np.asarray(n_mfs), (n_inputs,)).astype(int)
    if np.any(counts < 1):
        raise FuzzyModelError(f"n_mfs must be >= 1 for every input, got {np.asarray(n_mfs)}")
    params = []
    for n in counts:
        centres = np.linspace(0.0, 1.0, n) if n > 1 else np.array([0.5])
        half = 0.5 / (n - 1) if n > 1 else 0.5
        if mf == "bell":
            params.append(np.column_stack([np.full(n, half), np.full(n, 2.0), centres]))
        else:
            params.append(np.column_stack([np.full(n, 2.0 * half / _SQRT_8_LN2), centres]))
    offsets = np.concatenate([[0], np.cumsum(counts)[:-1]])
    local = np.indices(counts).reshape(n_inputs, -1).T
    return Premise(
        mf_type=mf,
        mf_input=np.repeat(np.arange(n_inputs), counts),
        mf_params=np.vstack(params),
        rules=local + offsets[None, :],
    )


def fcm_premise(
    U: np.ndarray,
    centers: np.ndarray,
    memberships: np.ndarray,
    m: float,
    min_sigma: float = 1e-3,
    sample_weight: np.ndarray | None = None,
) -> Premise:
    """genfis3-style premise: one rule per FCM cluster, Gaussian MFs.

    Parameters
    ----------
    U : numpy.ndarray, shape (n_samples, n_inputs)
        Normalised inputs that were clustered (with the output appended or not).
    centers : numpy.ndarray, shape (n_clusters, >= n_inputs)
        FCM centres; the first `n_inputs` columns are the input coordinates.
    memberships : numpy.ndarray, shape (n_samples, n_clusters)
        FCM memberships.
    m : float
        Fuzzifier used by the clustering.
    min_sigma : float
        Floor on the widths (normalised input units).
    sample_weight : numpy.ndarray, shape (n_samples,), optional
        Non-negative sample weights :math:`w_n`, as given to the weighted
        :func:`~fuzzymodel.fcm`; the widths then use :math:`w_n u_{nk}^m` in
        place of :math:`u_{nk}^m`. None: unweighted.

    Returns
    -------
    Premise
        MF ``i * n_clusters + k`` is input ``i`` of cluster ``k``; rule ``k``
        uses MF ``k`` of every input.
    """
    n_inputs = U.shape[1]
    c = centers.shape[0]
    um = memberships**m  # (n, c)
    if sample_weight is not None:
        um = um * np.asarray(sample_weight, dtype=np.float64)[:, None]
    v = centers[:, :n_inputs]  # (c, I)
    dev2 = (U[:, None, :] - v[None, :, :]) ** 2  # (n, c, I)
    sigma = np.sqrt(np.einsum("nk,nki->ki", um, dev2) / um.sum(axis=0)[:, None])
    sigma = np.fmax(sigma, min_sigma)
    # order: input-major so that MF index = i * c + k
    params = np.stack([sigma.T.ravel(), v.T.ravel()], axis=1)
    rules = np.arange(n_inputs)[None, :] * c + np.arange(c)[:, None]
    return Premise(
        mf_type="gauss",
        mf_input=np.repeat(np.arange(n_inputs), c),
        mf_params=params,
        rules=rules,
    )
