"""Gaussian and generalised-bell membership functions with their derivatives.

Parameter order follows MATLAB's Fuzzy Logic Toolbox and Jang (1993):

* Gaussian ``gauss``: ``(sigma, c)``, :math:`\\mu(x) = \\exp(-(x - c)^2 / (2\\sigma^2))`.
* Generalised bell ``bell``: ``(a, b, c)``,
  :math:`\\mu(x) = 1 / (1 + |(x - c)/a|^{2b})` (Jang 1993, eq. 18).

ANFIS works with :math:`\\log\\mu`: the rule firing strengths are products of
memberships, so their logarithms add, and the normalised firing strengths are
a soft-max of those sums, which never divides by zero even where every
membership underflows. :func:`log_membership` and :func:`log_membership_grad`
evaluate a batch of membership functions in that form; :func:`gaussmf`,
:func:`gbellmf` and their ``_grad`` companions give the plain values and
derivatives.

References
----------
J.-S. R. Jang, "ANFIS: Adaptive-Network-Based Fuzzy Inference System,"
IEEE Trans. Syst., Man, Cybern., vol. 23, no. 3, pp. 665-685, 1993.
"""

from __future__ import annotations

import numpy as np

from .errors import FuzzyModelError

__all__ = [
    "MF_PARAM_NAMES",
    "gaussmf",
    "gaussmf_grad",
    "gbellmf",
    "gbellmf_grad",
    "log_membership",
    "log_membership_grad",
    "membership",
    "membership_grad",
]

#: Parameter names of each membership-function family, in storage order.
MF_PARAM_NAMES: dict[str, tuple[str, ...]] = {
    "gauss": ("sigma", "c"),
    "bell": ("a", "b", "c"),
}


def _family(kind: str) -> tuple[str, ...]:
    try:
        return MF_PARAM_NAMES[kind]
    except KeyError:
        raise FuzzyModelError(
            f"unknown membership function {kind!r}; expected one of {sorted(MF_PARAM_NAMES)}"
        ) from None


def _split(params, kind: str) -> list[np.ndarray]:
    names = _family(kind)
    p = np.asarray(params, dtype=np.float64)
    if p.shape[-1:] != (len(names),):
        raise FuzzyModelError(
            f"{kind} parameters must have last axis {len(names)} {names}, got shape {p.shape}"
        )
    return [p[..., k] for k in range(len(names))]


def _gauss_log(x, sigma, c):
    return -0.5 * ((x - c) / sigma) ** 2


def _gauss_log_grad(x, sigma, c):
    # d log mu / d sigma = (x - c)^2 / sigma^3 ; d log mu / d c = (x - c) / sigma^2
    dx = x - c
    s2 = sigma * sigma
    return np.stack(np.broadcast_arrays(dx * dx / (s2 * sigma), dx / s2), axis=-1)


def _bell_parts(x, a, b, c):
    dx = x - c
    z = np.abs(dx / a)
    u = z ** (2.0 * b)
    return dx, z, u


def _bell_log(x, a, b, c):
    _, _, u = _bell_parts(x, a, b, c)
    return -np.log1p(u)


def _bell_log_grad(x, a, b, c):
    # log mu = -log(1 + u), u = z^(2b), z = |x - c| / a.
    # d/da = 2 b u / (a (1 + u)); d/db = -2 u ln z / (1 + u);
    # d/dc = 2 b z^(2b-1) sign(x - c) / (a (1 + u)).  At z = 0 the b- and c-
    # derivatives are 0 (limits for b > 1/2; taken as 0 otherwise).
    dx, z, u = _bell_parts(x, a, b, c)
    inv = 1.0 / (1.0 + u)
    zero = z == 0.0
    z_safe = np.where(zero, 1.0, z)
    d_a = 2.0 * b * u * inv / a
    d_b = np.where(zero, 0.0, -2.0 * u * np.log(z_safe) * inv)
    d_c = np.where(zero, 0.0, 2.0 * b * z_safe ** (2.0 * b - 1.0) * np.sign(dx) * inv / np.abs(a))
    return np.stack(np.broadcast_arrays(d_a, d_b, d_c), axis=-1)


_LOG = {"gauss": _gauss_log, "bell": _bell_log}
_LOG_GRAD = {"gauss": _gauss_log_grad, "bell": _bell_log_grad}


def log_membership(kind: str, x, params) -> np.ndarray:
    """Logarithm of the membership grade, vectorised.

    Parameters
    ----------
    kind : {"gauss", "bell"}
        Membership-function family.
    x : array_like
        Input values; broadcast against ``params[..., 0]``.
    params : array_like, shape (..., n_params)
        Parameters in the order of ``MF_PARAM_NAMES[kind]``.

    Returns
    -------
    numpy.ndarray of float64
        :math:`\\log\\mu(x)` (dimensionless, <= 0), broadcast shape.
    """
    parts = _split(params, kind)
    return _LOG[kind](np.asarray(x, dtype=np.float64), *parts)


def log_membership_grad(kind: str, x, params) -> np.ndarray:
    """Derivatives of :math:`\\log\\mu` with respect to each parameter.

    Returns
    -------
    numpy.ndarray of float64, shape (broadcast shape, n_params)
        :math:`\\partial\\log\\mu/\\partial p_k`; multiply by :func:`membership`
        to get :math:`\\partial\\mu/\\partial p_k`.
    """
    parts = _split(params, kind)
    return _LOG_GRAD[kind](np.asarray(x, dtype=np.float64), *parts)


def membership(kind: str, x, params) -> np.ndarray:
    """Membership grade :math:`\\mu(x)` in [0, 1] for family `kind` (see module doc)."""
    return np.exp(log_membership(kind, x, params))


def membership_grad(kind: str, x, params) -> np.ndarray:
    """:math:`\\partial\\mu/\\partial p_k`, shape (broadcast shape, n_params)."""
    return membership(kind, x, params)[..., None] * log_membership_grad(kind, x, params)


def gaussmf(x, sigma, c) -> np.ndarray:
    """Gaussian membership :math:`\\exp(-(x - c)^2 / (2\\sigma^2))`.

    Parameters
    ----------
    x : array_like
        Input, any shape; broadcast with `sigma` and `c` (same unit as `x`).
    sigma : array_like
        Width (> 0), unit of `x`.
    c : array_like
        Centre, unit of `x`.

    Returns
    -------
    numpy.ndarray of float64
        Membership grade in (0, 1], broadcast shape.
    """
    return np.exp(_gauss_log(np.asarray(x, dtype=np.float64), sigma, c))


def gaussmf_grad(x, sigma, c) -> np.ndarray:
    """Derivatives of :func:`gaussmf`: last axis ``(d mu/d sigma, d mu/d c)``."""
    x = np.asarray(x, dtype=np.float64)
    return gaussmf(x, sigma, c)[..., None] * _gauss_log_grad(x, sigma, c)


def gbellmf(x, a, b, c) -> np.ndarray:
    """Generalised bell :math:`1 / (1 + |(x - c)/a|^{2b})` (Jang 1993, eq. 18).

    Parameters
    ----------
    x : array_like
        Input, any shape; broadcast with the parameters.
    a : array_like
        Half width at membership 0.5 (> 0), unit of `x`.
    b : array_like
        Slope exponent (> 0), dimensionless; the slope at the crossover is -b/(2a).
    c : array_like
        Centre, unit of `x`.

    Returns
    -------
    numpy.ndarray of float64
        Membership grade in (0, 1], broadcast shape.
    """
    return np.exp(_bell_log(np.asarray(x, dtype=np.float64), a, b, c))


def gbellmf_grad(x, a, b, c) -> np.ndarray:
    """Derivatives of :func:`gbellmf`: last axis ``(d mu/d a, d mu/d b, d mu/d c)``."""
    x = np.asarray(x, dtype=np.float64)
    return gbellmf(x, a, b, c)[..., None] * _bell_log_grad(x, a, b, c)
