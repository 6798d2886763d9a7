"""Collected paths to the project's path sets: one per antenna position, copies removed.

Shared by direct tracing (:mod:`propagation.pathsolve`), :mod:`propagation.shared`
(chains shared between neighbouring positions) and :mod:`propagation.completion`
(specular chains over the large planes): each collects its valid paths (unrotated iso
``VH`` transfer matrices, delays, directions) as NumPy arrays (direct tracing from
Sionna's ``Paths``, the others through
:func:`propagation.sionna_internals.collect_paths`), and :func:`to_source_paths` turns
them into one :class:`~propagation.pathcache.SourcePaths` per antenna position.
"""

from __future__ import annotations

import numpy as np

from propagation.constants import SPEED_OF_LIGHT
from propagation.jitarrays import jit_points
from propagation.pathcache import SourcePaths

__all__ = ["path_copies", "points", "to_source_paths"]


def points(a) -> object:
    """A Mitsuba ``Point3f`` of positions (n, 3) [m] (float32, as Sionna uses them)."""
    import mitsuba as mi

    return jit_points(mi.Point3f, a)


def to_source_paths(out: dict, pos, tgt, need=None) -> list[SourcePaths]:
    """The collected paths as one :class:`SourcePaths` per position of ``pos`` (n, 3),
    to the targets ``tgt`` (m, 3) it ``need`` s ((n, m) bool; default every pair), sorted
    by length, copies removed."""
    need = np.ones((len(pos), len(tgt)), bool) if need is None else np.asarray(need, bool)
    if out["src"]:
        src = np.concatenate(out["src"])
        tg = np.concatenate(out["tgt"])
        a = np.concatenate(out["a"])
        tau = np.concatenate(out["tau"])
        k_tx = np.concatenate(out["k_tx"])
        k_rx = np.concatenate(out["k_rx"])
    else:
        src = tg = np.zeros(0, np.int64)
        a, tau = np.zeros((0, 2, 2), complex), np.zeros(0)
        k_tx = k_rx = np.zeros((0, 3))
    keep = need[src, tg]  # line-of-sight rows were solved for every pair
    src, tg, a, tau, k_tx, k_rx = src[keep], tg[keep], a[keep], tau[keep], k_tx[keep], k_rx[keep]
    order = np.lexsort((tau, tg, src))
    src, tg, a, tau, k_tx, k_rx = src[order], tg[order], a[order], tau[order], k_tx[order], k_rx[order]
    # The image method accepts a chain on any triangle of the reflecting plane, so the
    # same physical path can come from two candidates (a wall's two triangles seen
    # from two lattice points). A copy is a path of the same position and tag whose
    # length (0.1 mm), departure and arrival directions (1e-4) and transfer matrix (1e-3
    # relative) all agree: far above the solver's float32 noise (~1e-6 m at 20 m), far
    # below any real path separation. Tolerances, not rounding to a grid (a grid line
    # splits float32 copies), and all four quantities (Sionna returns distinct paths with
    # equal length and departure, e.g. a bounce inside a wall slab in either order).
    keep = ~path_copies(src, tg, tau * SPEED_OF_LIGHT, k_tx, k_rx, a)
    src, tg, a, tau, k_tx, k_rx = src[keep], tg[keep], a[keep], tau[keep], k_tx[keep], k_rx[keep]
    result = []
    bounds = np.searchsorted(src, np.arange(len(pos) + 1))
    for i in range(len(pos)):
        s0, s1 = bounds[i], bounds[i + 1]
        cols = np.flatnonzero(need[i])
        # tg is sorted within a position and holds only needed tags
        counts = np.diff(np.searchsorted(tg[s0:s1], np.append(cols, len(tgt))))
        result.append(SourcePaths(
            source_m=pos[i].copy(),
            tag_positions_m=tgt[cols].copy(),
            offsets=np.concatenate([[0], np.cumsum(counts)]).astype(np.int64),
            transfer=a[s0:s1], tau_s=tau[s0:s1], k_tx=k_tx[s0:s1], k_rx=k_rx[s0:s1],
        ))
    return result


def path_copies(src, tg, length_m, k_tx, k_rx, transfer, droppable=None, length_tol_m: float = 1e-4,
            direction_tol: float = 1e-4, transfer_rtol: float = 1e-3) -> np.ndarray:
    """Rows that repeat another row's path, (P,) bool; rows sorted by (src, tg, length).

    Of two copies the later row is dropped, or, with ``droppable`` ((P,) bool), the
    droppable one (a pair of two rows not droppable is kept: both are distinct paths a
    solver returned). ``transfer_rtol`` None: transfer matrices are not compared.
    """
    droppable = np.ones(len(length_m), bool) if droppable is None else np.asarray(droppable, bool)
    drop = np.zeros(len(length_m), bool)
    scale = np.abs(transfer).reshape(len(length_m), -1).max(axis=1) if len(length_m) else np.zeros(0)
    for w in range(1, len(length_m)):  # rows w apart; stops past the widest near-tie
        i = np.arange(w, len(length_m))
        j = i - w
        near = (src[i] == src[j]) & (tg[i] == tg[j]) & (length_m[i] - length_m[j] <= length_tol_m)
        if not near.any():
            break
        near &= droppable[i] | droppable[j]
        i, j = i[near], j[near]
        same = ((np.abs(k_tx[i] - k_tx[j]).max(axis=1) <= direction_tol)
                & (np.abs(k_rx[i] - k_rx[j]).max(axis=1) <= direction_tol))
        if transfer_rtol is not None:
            same &= (np.abs(transfer[i] - transfer[j]).reshape(len(i), 4).max(axis=1, initial=0.0)
                     <= transfer_rtol * np.maximum(scale[i], scale[j]))
        i, j = i[same], j[same]
        drop[np.where(droppable[i], i, j)] = True
    return drop
