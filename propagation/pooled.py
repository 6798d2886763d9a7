"""Shoot rays from a few lattice points, solve exact paths at every antenna position.

Sionna RT's ``PathSolver`` works in two steps: shoot-and-bounce rays from each source to
collect *candidate* chains (the sequence of surfaces a ray reflected on or crossed, per
source and target), then the image method turns each candidate into the exact path for
that source and target and tests it with the scene's own visibility (every segment is
re-traced; a chain whose reflection point leaves its triangle, or that something
occludes, is dropped). The shooting is what costs; the image method is cheap.

The antenna moves millimetres to centimetres between reads, so neighbouring positions
see the same chains. :func:`trace_pooled` therefore shoots rays only from lattice points
and gives every exact antenna position the union of the candidates found at its nearest
lattice points (duplicates removed), then runs Sionna's image method and field
calculator at the exact position. The paths are exact (the image method's, not an
extrapolation), and a chain that one lattice point's ray sampling missed is recovered
from a neighbour's: pooling lowers the seed-to-seed noise of the truth instead of
raising it. Line-of-sight paths are solved directly at the exact positions.

This uses Sionna RT's path-solver internals (``SBCandidateGenerator``, ``ImageMethod``,
``FieldCalculator``, ``PathsBuffer``) of the pinned sionna-rt 2.2.0 (``constraints.txt``);
:func:`pooled_supported` says whether the installed version provides them.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from propagation.pathcache import SourcePaths

__all__ = ["POOL_RADIUS_FACTOR", "PoolChunk", "lattice_points", "pooled_supported", "pooling_plan", "trace_pooled"]

_SPEED_OF_LIGHT = 299_792_458.0
#: Pooling radius over lattice spacing: at 1.2 a position on a tour pools its ~3
#: nearest lattice points (measured, docs/pooled_tracing.md); wider adds candidates,
#: not accuracy.
POOL_RADIUS_FACTOR = 1.2


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
        The distinct lattice points used, (k, 3), float64, metres, in lexicographic order.
    index : numpy.ndarray
        Nearest lattice point of each position, (n,), int64.
    """
    s = float(spacing_m)
    if not (np.isfinite(s) and s > 0):
        raise ValueError(f"lattice spacing must be positive, got {spacing_m!r}")
    p = np.asarray(positions_m, dtype=float).reshape(-1, 3)
    cells = np.round(p / s).astype(np.int64)
    uniq, index = np.unique(cells, axis=0, return_inverse=True)
    return uniq.astype(float) * s, index.reshape(-1).astype(np.int64)


@dataclass(frozen=True)
class PoolChunk:
    """One solver call of pooled tracing.

    Attributes
    ----------
    positions : numpy.ndarray
        Rows of the antenna positions solved in this call, (p,), int64.
    shoot_m : numpy.ndarray
        Points rays are shot from, (k, 3), float64, metres.
    neighbours : list of numpy.ndarray
        Per solved position, the rows of ``shoot_m`` whose candidates it pools.
    """

    positions: np.ndarray
    shoot_m: np.ndarray
    neighbours: list


def pooling_plan(scene, positions_m, spacing_m: float, max_shoot_per_call: int,
                 radius_factor: float = POOL_RADIUS_FACTOR) -> list[PoolChunk]:
    """Which lattice points each antenna position pools, split into solver calls.

    A position pools the lattice points (nearest points of the positions) within
    ``radius_factor * spacing_m``; lattice points outside the scene's bounds or inside
    a solid are not shot from, and a position whose nearest lattice point is such a
    point shoots its own rays as well. Calls hold whole lattice cells in lexicographic
    order and at most ``max_shoot_per_call`` shooting points (a cell's neighbours from
    the previous call are shot again). A lone position, whose lattice point no other
    position pools and which has no other lattice neighbour, shoots its own rays: a
    lattice point would save nothing there and its candidates would come from up to
    ``sqrt(3) / 2 * spacing_m`` away.
    """
    from scipy.spatial import cKDTree

    from scenes.geometry import solid_material_at

    pos = np.asarray(positions_m, dtype=float).reshape(-1, 3)
    lat, nearest = lattice_points(pos, spacing_m)
    lo, hi = scene.bounds_m
    usable = ~(np.any((lat[:, :2] <= lo[:2]) | (lat[:, :2] >= hi[:2]), axis=1) | (lat[:, 2] <= lo[2])
               | (solid_material_at(scene, lat) != ""))
    tree = cKDTree(lat)
    near = tree.query_ball_point(pos, r=radius_factor * float(spacing_m))
    # A lattice point that only one position would pool saves no shooting: that
    # position shoots its own rays (its candidates are then its own, as in direct tracing).
    users = np.zeros(len(lat), np.int64)
    for i in range(len(pos)):
        users[[k for k in near[i] if usable[k]] or [nearest[i]]] += 1
    lone = np.array([users[nearest[i]] == 1 and all(not usable[k] or k == nearest[i] for k in near[i])
                     for i in range(len(pos))], bool)
    chunks: list[PoolChunk] = []
    cur_pos: list[int] = []
    cur_shoot: dict = {}

    def flush():
        if not cur_pos:
            return
        keys = list(cur_shoot)
        shoot = np.array([lat[k] if isinstance(k, (int, np.integer)) else pos[k[1]] for k in keys])
        slot = {k: i for i, k in enumerate(keys)}
        nbs = []
        for i in cur_pos:
            own = [slot[k] for k in _sources_of(i, near, usable, nearest, lone)]
            nbs.append(np.asarray(own, np.int64))
        chunks.append(PoolChunk(np.asarray(cur_pos, np.int64), shoot, nbs))
        cur_pos.clear()
        cur_shoot.clear()

    for cell in range(len(lat)):  # lattice_points returns them in lexicographic order
        members = np.flatnonzero(nearest == cell)
        new = {k for i in members for k in _sources_of(i, near, usable, nearest, lone)} - set(cur_shoot)
        if cur_pos and len(cur_shoot) + len(new) > max(1, int(max_shoot_per_call)):
            flush()
            new = {k for i in members for k in _sources_of(i, near, usable, nearest, lone)}
        for k in sorted(new, key=str):
            cur_shoot[k] = True
        cur_pos.extend(int(i) for i in members)
    flush()
    return chunks


def _sources_of(i, near, usable, nearest, lone) -> list:
    """Shooting points of position i: usable lattice neighbours, or itself ("own", i)."""
    if lone[i]:
        return [("own", int(i))]
    srcs = [int(k) for k in near[i] if usable[k] and k != nearest[i]]
    first = [int(nearest[i])] if usable[nearest[i]] else [("own", int(i))]
    return first + srcs


def pooled_supported() -> bool:
    """Whether the installed Sionna RT has the internals :func:`trace_pooled` uses."""
    try:
        from sionna.rt.path_solvers.field_calculator import FieldCalculator  # noqa: F401
        from sionna.rt.path_solvers.image_method import ImageMethod  # noqa: F401
        from sionna.rt.path_solvers.paths_buffer import PathsBuffer  # noqa: F401
        from sionna.rt.path_solvers.sb_candidate_generator import SBCandidateGenerator  # noqa: F401
    except ImportError:
        return False
    return True


def _points(a) -> object:
    import mitsuba as mi

    a = np.asarray(a, dtype=np.float32).reshape(-1, 3)
    return mi.Point3f(a[:, 0], a[:, 1], a[:, 2])


def _candidate_keys(buf) -> np.ndarray:
    """Per candidate row: its chain (interaction types, shapes, primitives) as one key."""
    types = buf.interaction_types.numpy().astype(np.int64)
    shapes = buf.shapes.numpy().astype(np.int64)
    prims = buf.primitives.numpy().astype(np.int64)
    return np.concatenate([types, shapes, prims], axis=1)


def trace_pooled(rt_scene, lattice_m, positions_m, neighbours, targets_m, need, max_depth: int,
                 samples_per_src: int, seed: int, refraction: bool = True) -> list[SourcePaths]:
    """Exact paths at ``positions_m`` from candidates shot at ``lattice_m``.

    Parameters
    ----------
    rt_scene : sionna.rt.Scene
        The loaded scene (:func:`propagation.sionna_scene.load_sionna_scene`).
    lattice_m : array_like
        Shooting positions (k, 3), metres.
    positions_m : array_like
        Antenna positions (n, 3), metres, where paths are solved.
    neighbours : list of array_like
        Per position the lattice rows whose candidates it pools.
    targets_m : array_like
        Tag positions (m, 3), metres.
    need : array_like of bool
        (n, m): the tags each position needs (other links are not solved).
    max_depth, samples_per_src, seed, refraction
        As for Sionna's ``PathSolver``.

    Returns
    -------
    list of SourcePaths
        Per position, paths to every tag it needs (``tag_positions_m`` in target order).
    """
    import drjit as dr
    import mitsuba as mi
    from sionna.rt.path_solvers.field_calculator import FieldCalculator
    from sionna.rt.path_solvers.image_method import ImageMethod
    from sionna.rt.path_solvers.sb_candidate_generator import SBCandidateGenerator

    from propagation.sionna_scene import clear_devices, place_devices

    lat = np.asarray(lattice_m, float).reshape(-1, 3)
    pos = np.asarray(positions_m, float).reshape(-1, 3)
    tgt = np.asarray(targets_m, float).reshape(-1, 3)
    need = np.asarray(need, bool)
    n, m = len(pos), len(tgt)
    place_devices(rt_scene)
    mi_scene = rt_scene.mi_scene
    tgt_mi = _points(tgt)
    lat_mi = _points(lat)

    # 1. candidates from the lattice points
    gen = SBCandidateGenerator()
    cand = gen(mi_scene, lat_mi, tgt_mi, samples_per_src=int(samples_per_src),
               max_num_paths_per_src=int(samples_per_src) * (int(max_depth) + 1),
               max_depth=int(max_depth), los=False, specular_reflection=True,
               diffuse_reflection=False, refraction=bool(refraction), diffraction=False,
               edge_diffraction=False, seed=int(seed))
    cand.schedule()
    dr.eval()
    cand.shrink()
    cand.detach_geometry()
    c_src = cand.source_indices.numpy().astype(np.int64)
    c_tgt = cand.target_indices.numpy().astype(np.int64)
    c_ok = ~cand.valid.numpy().astype(bool)  # candidates (not already-final paths)
    keys = _candidate_keys(cand) if len(c_src) else np.zeros((0, 1), np.int64)
    # Keep the chains that are valid paths at their own lattice point: ~7 % of the
    # candidates on corridor_lab, so pooling several neighbours stays cheap. A chain valid
    # at an antenna position but at none of its lattice neighbours is lost. Only lattice
    # points some position pools as a further neighbour need this test.
    further = np.zeros(len(lat), bool)
    for nb in neighbours:
        further[np.asarray(nb, np.int64)[1:]] = True
    c_valid = np.zeros(len(c_src), bool)
    probed = np.flatnonzero(c_ok & further[c_src]) if len(c_src) else np.zeros(0, np.int64)
    if len(probed):
        probe = cand.gather(mi.UInt(probed.astype(np.uint32)))
        probe = ImageMethod()(mi_scene, probe, False, True, lat_mi, tgt_mi)
        _field(probe, rt_scene, lat_mi, tgt_mi, len(lat), m, samples_per_src, FieldCalculator,
               discard=False)
        c_valid[probed] = probe.valid.numpy().astype(bool)
        del probe
    # the first neighbour (the nearest lattice point) gives all its candidates, the
    # others only the chains valid where they were shot
    all_of = [np.flatnonzero(c_ok & (c_src == k)) for k in range(len(lat))]
    by_lat = [np.flatnonzero(c_valid & (c_src == k)) for k in range(len(lat))]

    # 2. per exact position: the union of its neighbours' candidates for the tags it needs
    rows, new_src = [], []
    for i in range(n):
        nb = np.asarray(neighbours[i], np.int64)
        r = np.concatenate([all_of[nb[0]]] + [by_lat[k] for k in nb[1:]]) \
            if len(nb) else np.zeros(0, np.int64)
        r = r[need[i, c_tgt[r]]]
        if len(r) == 0:
            continue
        key = np.concatenate([c_tgt[r, None], keys[r]], axis=1)
        _, first = np.unique(key, axis=0, return_index=True)
        r = r[np.sort(first)]
        rows.append(r)
        new_src.append(np.full(len(r), i, np.int64))
    out_paths = {"src": [], "tgt": [], "a": [], "tau": [], "k_tx": [], "k_rx": []}
    pos_mi = _points(pos)
    if rows:
        rows = np.concatenate(rows)
        new_src = np.concatenate(new_src)
        buf = cand.gather(mi.UInt(rows.astype(np.uint32)))
        buf._src_indices = mi.UInt(new_src.astype(np.uint32))  # noqa: SLF001 - re-targeted
        buf = ImageMethod()(mi_scene, buf, False, True, pos_mi, tgt_mi)
        _field(buf, rt_scene, pos_mi, tgt_mi, n, m, samples_per_src, FieldCalculator)
        _collect(buf, out_paths)
    # 3. line of sight, directly at the exact positions
    los = SBCandidateGenerator()(mi_scene, pos_mi, tgt_mi, samples_per_src=1,
                                 max_num_paths_per_src=m, max_depth=0, los=True,
                                 specular_reflection=False, diffuse_reflection=False,
                                 refraction=False, diffraction=False, edge_diffraction=False,
                                 seed=int(seed))
    los.schedule()
    dr.eval()
    los.shrink()
    if los.buffer_size:
        _field(los, rt_scene, pos_mi, tgt_mi, n, m, samples_per_src, FieldCalculator)
        _collect(los, out_paths)
    clear_devices(rt_scene)
    return _to_source_paths(out_paths, pos, tgt, need)


def _field(buf, rt_scene, pos_mi, tgt_mi, n, m, samples_per_src, field_calculator,
           discard: bool = True) -> None:

    # unrotated antennas at both ends (orientations are applied later, in NumPy)
    field_calculator()(rt_scene.wavelength, buf, int(samples_per_src), False, pos_mi, tgt_mi,
                       _points(np.zeros((n, 3))), _points(np.zeros((m, 3))), rt_scene.tx_array.antenna_pattern.patterns,
                       rt_scene.rx_array.antenna_pattern.patterns)
    if discard:
        buf.discard_invalid()


def _collect(buf, out: dict) -> None:
    if buf.buffer_size == 0:
        return
    a = np.empty((buf.buffer_size, 2, 2), complex)
    for r in range(2):
        for t in range(2):
            z = buf.a[r][t]
            a[:, r, t] = np.asarray(z.real, np.float64) + 1j * np.asarray(z.imag, np.float64)
    out["a"].append(a)
    out["src"].append(buf.source_indices.numpy().astype(np.int64))
    out["tgt"].append(buf.target_indices.numpy().astype(np.int64))
    out["tau"].append(buf.tau.numpy().astype(np.float64))
    # Dr.Jit's Vector3f.numpy() is (3, P)
    out["k_tx"].append(np.asarray(buf.k_tx.numpy(), np.float64).T)
    out["k_rx"].append(np.asarray(buf.k_rx.numpy(), np.float64).T)


def _to_source_paths(out: dict, pos, tgt, need) -> list[SourcePaths]:
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
    keep = ~_copies(src, tg, tau * _SPEED_OF_LIGHT, k_tx, k_rx, a)
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


def _copies(src, tg, length_m, k_tx, k_rx, transfer, droppable=None, length_tol_m: float = 1e-4,
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
