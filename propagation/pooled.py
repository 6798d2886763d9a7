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

from propagation.jitarrays import jit_array
from propagation.pathcache import SourcePaths
from propagation.sionna_paths import (
    candidate_keys,
    collect_paths,
    points,
    solve_fields,
    to_source_paths,
)

__all__ = ["POOL_RADIUS_FACTOR", "PoolChunk", "lattice_points", "pooled_supported", "pooling_plan", "trace_pooled"]

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
    tgt_mi = points(tgt)
    lat_mi = points(lat)

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
    keys = candidate_keys(cand) if len(c_src) else np.zeros((0, 1), np.int64)
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
        probe = cand.gather(jit_array(mi.UInt, probed, np.uint32))
        probe = ImageMethod()(mi_scene, probe, False, True, lat_mi, tgt_mi)
        solve_fields(probe, rt_scene, lat_mi, tgt_mi, len(lat), m, FieldCalculator, discard=False)
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
    pos_mi = points(pos)
    if rows:
        rows = np.concatenate(rows)
        new_src = np.concatenate(new_src)
        buf = cand.gather(jit_array(mi.UInt, rows, np.uint32))
        buf._src_indices = jit_array(mi.UInt, new_src, np.uint32)  # noqa: SLF001 - re-targeted
        buf = ImageMethod()(mi_scene, buf, False, True, pos_mi, tgt_mi)
        solve_fields(buf, rt_scene, pos_mi, tgt_mi, n, m, FieldCalculator)
        collect_paths(buf, out_paths)
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
        solve_fields(los, rt_scene, pos_mi, tgt_mi, n, m, FieldCalculator)
        collect_paths(los, out_paths)
    clear_devices(rt_scene)
    return to_source_paths(out_paths, pos, tgt, need)
