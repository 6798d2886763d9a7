"""Carry traced paths from one antenna position to a nearby one, by their geometry.

Every path the tracer keeps (line of sight, specular reflections on planar surfaces,
transmission through thin slabs, which Sionna RT lets continue without bending) is a
straight line in its *unfolded* frame: reflecting the receiver in each surface of the
chain, in turn, gives an image ``R*`` at distance ``l = c tau`` from the source along the
departure direction ``k``. Moving the source by ``delta`` moves nothing else, so while
the chain stays valid (its interaction points stay on their surfaces and unoccluded) the
new path is exactly::

    l'  = |l k - delta| = sqrt(l^2 - 2 l (k . delta) + |delta|^2)
    k'  = (l k - delta) / l'                       (new departure direction)
    a'  = a l / l'                                 (spherical spreading of the chain)

The arrival direction is updated exactly for straight chains (``k_rx = -k``: line of
sight, transmissions only) and kept for reflected ones (its change is of order
``|delta| / l``, and the tag's dipole pattern varies slowly). The 2x2 transfer matrix is
carried into the spherical bases of the new directions (a rotation of the transverse
plane, so that directions near the poles stay right). Reflection and transmission
coefficients keep the incidence angles of the traced position (their change is also of
order ``|delta| / l``).

What this cannot know: a chain that becomes invalid (a reflection point slides off its
wall, a box starts to occlude it) or a chain valid only at the new position. Those are
the geometric-optics shadow boundaries; ``bench/trace.py`` measures the resulting error
against direct tracing, and :func:`propagation.trace_links` keeps the shift below half a
lattice diagonal (``lattice_spacing_m``).
"""

from __future__ import annotations

import numpy as np

from propagation.pathcache import SourcePaths
from propagation.patterns import spherical_basis, theta_phi_from_unit_vec

__all__ = ["lattice_points", "shift_source", "subset_tags"]

_SPEED_OF_LIGHT = 299_792_458.0
#: k_rx . k_tx below this marks a straight chain (LOS or transmissions only); float32
#: angles from the solver leave ~1e-7 of slack.
_STRAIGHT_DOT = -1.0 + 1e-6


def lattice_points(positions_m, spacing_m: float) -> tuple[np.ndarray, np.ndarray]:
    """Snap positions to a cubic lattice of the given spacing.

    Parameters
    ----------
    positions_m : array_like
        Positions (n, 3), metres.
    spacing_m : float
        Lattice spacing, metres (> 0).

    Returns
    -------
    points : numpy.ndarray
        The distinct lattice points used, (k, 3), float64, metres.
    index : numpy.ndarray
        Lattice point of each position, (n,), int64; ``|positions - points[index]|`` is at
        most ``spacing_m * sqrt(3) / 2``.
    """
    s = float(spacing_m)
    if not (np.isfinite(s) and s > 0):
        raise ValueError(f"lattice spacing must be positive, got {spacing_m!r}")
    p = np.asarray(positions_m, dtype=float).reshape(-1, 3)
    cells = np.round(p / s).astype(np.int64)
    uniq, index = np.unique(cells, axis=0, return_inverse=True)
    return uniq.astype(float) * s, index.reshape(-1).astype(np.int64)


def subset_tags(sp: SourcePaths, rows) -> SourcePaths:
    """The path set restricted to tag rows ``rows`` (in that order)."""
    rows = np.asarray(rows, dtype=np.int64)
    counts = sp.offsets[rows + 1] - sp.offsets[rows]
    idx = (np.concatenate([np.arange(sp.offsets[r], sp.offsets[r + 1]) for r in rows])
           if len(rows) else np.zeros(0, np.int64)).astype(np.int64)
    return SourcePaths(
        source_m=sp.source_m,
        tag_positions_m=sp.tag_positions_m[rows],
        offsets=np.concatenate([[0], np.cumsum(counts)]).astype(np.int64),
        transfer=sp.transfer[idx],
        tau_s=sp.tau_s[idx],
        k_tx=sp.k_tx[idx],
        k_rx=sp.k_rx[idx],
    )


def _basis(k: np.ndarray) -> np.ndarray:
    """World spherical basis (theta-hat, phi-hat) at directions k, shape (P, 3, 2)."""
    th, ph = theta_phi_from_unit_vec(k)
    t_hat, p_hat = spherical_basis(th, ph)
    return np.stack([t_hat, p_hat], axis=-1)


def shift_source(sp: SourcePaths, new_source_m) -> SourcePaths:
    """The paths of ``sp`` carried to the antenna position ``new_source_m``.

    Parameters
    ----------
    sp : SourcePaths
        Paths traced from ``sp.source_m``.
    new_source_m : array_like
        The new antenna position, shape (3,), metres.

    Returns
    -------
    SourcePaths
        Same tags and path count; delays, departure directions, transfer matrices (and
        arrival directions of straight chains) of the new position (module docstring).
    """
    new = np.asarray(new_source_m, dtype=float).reshape(3)
    delta = new - np.asarray(sp.source_m, dtype=float)
    if not np.any(delta) or len(sp.tau_s) == 0:
        return SourcePaths(new, sp.tag_positions_m, sp.offsets, sp.transfer, sp.tau_s,
                           sp.k_tx, sp.k_rx)
    length = sp.tau_s * _SPEED_OF_LIGHT
    k = sp.k_tx
    image = length[:, None] * k - delta  # unfolded receiver image seen from the new source
    new_length = np.linalg.norm(image, axis=1)
    k_new = image / new_length[:, None]
    straight = np.einsum("pi,pi->p", k, sp.k_rx) < _STRAIGHT_DOT
    k_rx_new = sp.k_rx.copy()
    k_rx_new[straight] = -k_new[straight]
    b_tx_old, b_tx_new = _basis(k), _basis(k_new)
    m_tx = np.einsum("pia,pib->pab", b_tx_old, b_tx_new)  # new-basis -> old-basis components
    transfer = np.einsum("prt,pts->prs", sp.transfer, m_tx)
    if np.any(straight):
        b_rx_old, b_rx_new = _basis(sp.k_rx[straight]), _basis(k_rx_new[straight])
        m_rx = np.einsum("pia,pib->pab", b_rx_new, b_rx_old)  # old-basis -> new-basis
        transfer[straight] = np.einsum("pab,pbt->pat", m_rx, transfer[straight])
    transfer = transfer * (length / new_length)[:, None, None]
    return SourcePaths(
        source_m=new,
        tag_positions_m=sp.tag_positions_m,
        offsets=sp.offsets,
        transfer=transfer,
        tau_s=new_length / _SPEED_OF_LIGHT,
        k_tx=k_new,
        k_rx=k_rx_new,
    )
