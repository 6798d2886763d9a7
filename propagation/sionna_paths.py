"""Sionna RT path-solver buffers to the project's path sets, and back.

Shared by :mod:`propagation.pooled` (candidates pooled over lattice points),
:mod:`propagation.shared` (chains shared between neighbouring positions) and
:mod:`propagation.completion` (specular chains over the large planes): all three hand
candidate chains to Sionna's own image method and field calculator, then collect the
valid paths (unrotated iso ``VH`` transfer matrices, delays, directions) into one
:class:`~propagation.pathcache.SourcePaths` per antenna position, copies removed.
Uses the internals of the pinned sionna-rt 2.2.0 (``PathsBuffer`` attributes).
"""

from __future__ import annotations

import numpy as np

from propagation.jitarrays import jit_points
from propagation.pathcache import SourcePaths

__all__ = ["candidate_keys", "collect_paths", "opaque_buffer", "path_copies", "points", "solve_fields",
           "to_source_paths"]

_SPEED_OF_LIGHT = 299_792_458.0


def points(a) -> object:
    """A Mitsuba ``Point3f`` of positions (n, 3) [m] (float32, as Sionna uses them)."""
    import mitsuba as mi

    return jit_points(mi.Point3f, a)


def candidate_keys(buf) -> np.ndarray:
    """Per row of a paths buffer its chain as one key: interaction types, shapes and
    primitives at every depth, (R, 3 * depth) int64."""
    types = buf.interaction_types.numpy().astype(np.int64)
    shapes = buf.shapes.numpy().astype(np.int64)
    prims = buf.primitives.numpy().astype(np.int64)
    return np.concatenate([types, shapes, prims], axis=1)


def solve_fields(buf, rt_scene, pos_mi, tgt_mi, n, m, field_calculator,
                 discard: bool = True) -> None:
    """Sionna's field calculator on a paths buffer of ``n`` sources and ``m`` targets, then
    (``discard``) the invalid candidates dropped, else the whole buffer scheduled; in place.

    Its ``samples_per_src`` is 1 for every buffer: it scales only diffuse ray tubes (the
    buffers here never hold a diffuse path) and is a literal of the kernel, so another
    value would be another kernel. Scheduled whole, a buffer whose validity is read next
    is evaluated in one kernel: the validity evaluated alone leaves the image method's
    points unevaluated, and the fields' kernel after it computes them again.
    """
    # unrotated antennas at both ends (orientations are applied later, in NumPy)
    field_calculator()(rt_scene.wavelength, buf, 1, False, pos_mi, tgt_mi,
                       points(np.zeros((n, 3))), points(np.zeros((m, 3))), rt_scene.tx_array.antenna_pattern.patterns,
                       rt_scene.rx_array.antenna_pattern.patterns)
    if discard:
        buf.discard_invalid()
    else:
        buf.schedule()


def opaque_buffer(buf) -> None:
    """Every candidate array of a paths buffer evaluated into memory of its own; in place.

    Sionna's image method and field calculator then see the same kind of inputs whatever
    made the buffer (rows gathered from the candidate generator's buffer, or a chain
    enumeration's arrays with constant fields): one kernel of each serves all of them,
    where a gather fused into the kernel or a constant folded into it makes another one
    (~2 s of LLVM build each). The values are unchanged. Buffers with diffraction (never
    made here) keep their wedges as they are.
    """
    import drjit as dr

    dr.make_opaque(buf._valid, buf._src_indices, buf._tgt_indices,  # noqa: SLF001
                   buf._k_tx_x, buf._k_tx_y, buf._k_tx_z,  # noqa: SLF001
                   buf._k_rx_x, buf._k_rx_y, buf._k_rx_z,  # noqa: SLF001
                   buf._interaction_types, buf._vertices_x, buf._vertices_y,  # noqa: SLF001
                   buf._vertices_z, buf._shapes, buf._primitives, buf._probs)  # noqa: SLF001


def collect_paths(buf, out: dict) -> None:
    """Append a solved buffer's paths to ``out``'s lists (``a``, ``src``, ``tgt``, ``tau``,
    ``k_tx``, ``k_rx``) as NumPy float64 / complex128 arrays."""
    import drjit as dr

    if buf.buffer_size == 0:
        return
    fields = (buf.a, buf.source_indices, buf.target_indices, buf.tau, buf.k_tx, buf.k_rx)
    # one kernel for every field (they are gathers of the valid rows), then copies: a
    # Vector3f converted whole is a kernel with its length as a literal, compiled again
    # for every buffer length
    dr.eval(*fields)
    a_, src, tgt, tau, k_tx, k_rx = fields
    a = np.empty((buf.buffer_size, 2, 2), complex)
    for r in range(2):
        for t in range(2):
            z = a_[r][t]
            a[:, r, t] = np.asarray(z.real, np.float64) + 1j * np.asarray(z.imag, np.float64)
    out["a"].append(a)
    out["src"].append(src.numpy().astype(np.int64))
    out["tgt"].append(tgt.numpy().astype(np.int64))
    out["tau"].append(tau.numpy().astype(np.float64))
    for name, v in (("k_tx", k_tx), ("k_rx", k_rx)):
        out[name].append(np.stack([np.asarray(c.numpy(), np.float64) for c in (v.x, v.y, v.z)],
                                  axis=1))


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
    # same physical path can come from two pooled candidates (a wall's two triangles seen
    # from two lattice points). A copy is a path of the same position and tag whose
    # length (0.1 mm), departure and arrival directions (1e-4) and transfer matrix (1e-3
    # relative) all agree: far above the solver's float32 noise (~1e-6 m at 20 m), far
    # below any real path separation. Tolerances, not rounding to a grid (a grid line
    # splits float32 copies), and all four quantities (Sionna returns distinct paths with
    # equal length and departure, e.g. a bounce inside a wall slab in either order).
    keep = ~path_copies(src, tg, tau * _SPEED_OF_LIGHT, k_tx, k_rx, a)
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
            same &= (np.abs(transfer[i] - transfer[j]).reshape(len(i), -1).max(axis=1)
                     <= transfer_rtol * np.maximum(scale[i], scale[j]))
        i, j = i[same], j[same]
        drop[np.where(droppable[i], i, j)] = True
    return drop
