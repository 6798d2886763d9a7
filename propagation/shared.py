"""Every antenna position shoots its own rays; the chains it missed come from its neighbours.

Sionna RT's ``PathSolver`` finds paths in two steps: shoot-and-bounce rays from each
source to collect *candidate* chains (the surfaces a ray reflected on or crossed), then
the image method turns each candidate into the exact path for that source and target
and re-traces every segment. Every source shoots the same Fibonacci lattice of
directions; at each hit the seed decides whether the ray reflects or crosses the
surface (by their Fresnel weights), so which chains a source's rays find changes with
the seed and from one position to the next: a chain of weak reflections, or one valid
only in a small region, is found by some and missed by others. That is most of the
truth's seed-to-seed noise.

Positions of a tour within a metre of each other (the default study's antenna slots are
~0.3 m apart) see largely the same chains: 85 % of the chains valid at one position
are valid at its neighbours within 0.5 m on ``corridor_lab``. :func:`trace_shared`
traces every position as ``PathSolver`` does (its own rays, LOS, image method and field
calculator at the exact position) and then hands every position the chains that were
*valid paths* at the other positions within ``radius_m``, solved again by Sionna's image
method at the exact position (a chain that is not a path there is dropped by the
image method's own visibility tests). No path is moved or extrapolated: the result is
the paths of the union of the chains the neighbourhood's rays found. That union is what
lets each position shoot fewer rays (docs/physics.md, "Sharing chains between
positions"). Neighbours are the positions of the same solver call (a chunk of at most
128 positions in lexicographic order, fewer under a small memory budget): a position
at a chunk's edge has fewer, and a position's cached paths are those of the call that
traced it. It is no cure for every scene: with the large planes already completed
(:mod:`propagation.completion`) the chains left are weak ones, and a position that
gets a random half of them instead of a random tenth is no steadier (measured on the
tests' small corridor); on ``corridor_lab`` at 3,000 rays and 1 m its p95 distance to a
3e5-ray reference is that of direct tracing at 30,000 rays (1.21 dB; 57 flipped read
decisions against 49-51) and it is steadier between seeds, at half the time.

Sionna's stages are reached through :mod:`propagation.sionna_internals` (its version
guard refuses untested versions).
"""

from __future__ import annotations

import numpy as np
import pandas as pd

from propagation.pathcache import SourcePaths
from propagation.sionna_internals import collect_paths, shoot_candidates, solve_paths
from propagation.sionna_paths import points, to_source_paths
from propagation.sionna_scene import clear_devices, place_devices

__all__ = ["chain_ids", "own_ray_levels", "shared_rows", "sharing_neighbours", "trace_shared"]


def sharing_neighbours(positions_m, radius_m: float) -> list[np.ndarray]:
    """The other positions within ``radius_m`` of each position.

    Parameters
    ----------
    positions_m : array_like
        Antenna positions (n, 3), metres.
    radius_m : float
        Sharing radius, metres (>= 0).

    Returns
    -------
    list of numpy.ndarray
        Per position the rows of the others within the radius, int64, ascending.
    """
    from scipy.spatial import cKDTree

    r = float(radius_m)
    if not (np.isfinite(r) and r >= 0):
        raise ValueError(f"sharing radius must be >= 0, got {radius_m!r}")
    pos = np.asarray(positions_m, dtype=float).reshape(-1, 3)
    near = cKDTree(pos).query_ball_point(pos, r=r) if len(pos) else []
    return [np.asarray(sorted(k for k in nb if k != i), np.int64) for i, nb in enumerate(near)]


def own_ray_levels(neighbours, shared_samples: int, min_samples: int) -> np.ndarray:
    """Rays each sharing position must shoot alone so that its chains come from at least
    ``min_samples`` rays: 0 where its own and its neighbours' rays reach it.

    A position of the shared tracer gets the chains of its own ``shared_samples`` rays and
    of each neighbour's (:func:`trace_shared`): ``shared_samples * (1 + len(nb))`` rays. A
    position short of ``min_samples`` shoots ``min_samples - shared_samples * len(nb)``
    rays of its own in a call of their own (its share of the sharing is shot anyway, for
    its neighbours), rounded up to ``shared_samples`` times a power of two (at least 2,
    so that its lattice of directions is never the one its shared rays already shot) and
    capped at ``min_samples``: a handful of ray counts, each compiling its own shooting
    kernel once, instead of one per neighbour count.

    Parameters
    ----------
    neighbours : list of array_like
        Per position its neighbours' rows (:func:`sharing_neighbours`); a position with
        none is traced alone and gets 0 here.
    shared_samples : int
        Rays each sharing position shoots (``TraceOptions.shared_samples_per_src``), >= 1.
    min_samples : int
        Least rays a position's chains come from; 0 turns the guarantee off.

    Returns
    -------
    numpy.ndarray
        (n,) int64, rays to shoot alone per position (0 or a level above).
    """
    s, lo = int(shared_samples), int(min_samples)
    if s < 1 or lo < 0:
        raise ValueError(f"need shared_samples >= 1 and min_samples >= 0, got {shared_samples}, {min_samples}")
    n_nb = np.array([len(nb) for nb in neighbours], np.int64)
    short = (n_nb > 0) & (s * (1 + n_nb) < lo)
    need = np.where(short, lo - s * n_nb, 0)
    k = np.ceil(np.log2(np.maximum(need, 1) / s)).astype(np.int64)
    level = np.minimum(s * np.left_shift(1, np.maximum(k, 1)), max(lo, 2 * s))
    return np.where(short, level, 0).astype(np.int64)


#: Largest (positions x chains) for which :func:`shared_rows` tests membership in a table
#: (one byte each: at most 128 MiB for a moment, far below the tracing's memory budget;
#: a 128-position chunk of the default study needs ~9 MiB).
_DENSE_KEYS = 1 << 27

#: Rows hashed per block in :func:`chain_ids` (a block's columns stay in cache).
_HASH_BLOCK_ROWS = 1 << 15


def chain_ids(key: np.ndarray) -> np.ndarray:
    """Per row of ``key`` ((R, k) int64) an integer id, equal for equal rows only.

    A 64-bit polynomial hash of each row, numbered in the hashes' sorted order
    (``pandas.factorize``: a hash table, where ``np.unique`` sorts every row's hash); rows
    that share a hash are compared with one row of their group, and a collision falls back
    to the exact row-wise ``np.unique`` (which sorts k columns lexicographically: ~10x
    slower on a candidate buffer). Hashed in blocks of rows that fit in cache: converting
    the whole buffer's columns at once took ~45 % of the time.
    """
    key = np.ascontiguousarray(key, dtype=np.int64)
    n_rows = len(key)
    if n_rows == 0:
        return np.zeros(0, np.int64)
    h = np.empty(n_rows, np.uint64)
    mult, shift = np.uint64(0x100000001B3), np.uint64(29)
    with np.errstate(over="ignore"):
        for b0 in range(0, n_rows, _HASH_BLOCK_ROWS):
            hb = np.zeros(min(_HASH_BLOCK_ROWS, n_rows - b0), np.uint64)
            for col in key[b0:b0 + _HASH_BLOCK_ROWS].T.astype(np.uint64):
                hb ^= col
                hb *= mult
                hb ^= hb >> shift
            h[b0:b0 + _HASH_BLOCK_ROWS] = hb
    ids, uniq = pd.factorize(h, sort=True)
    rep = np.empty(len(uniq), np.int64)
    rep[ids] = np.arange(n_rows)  # one row of each hash
    rep = rep[ids]
    if not all(np.array_equal(key[b0:b0 + _HASH_BLOCK_ROWS], key[rep[b0:b0 + _HASH_BLOCK_ROWS]])
               for b0 in range(0, n_rows, _HASH_BLOCK_ROWS)):  # a hash collision
        ids = np.unique(key, axis=0, return_inverse=True)[1].reshape(-1)
    return ids.astype(np.int64)


def _chain_ids(keys: np.ndarray, tgt: np.ndarray) -> np.ndarray:
    """Per buffer row an integer naming its (target, chain) (``keys``: :func:`candidate_keys`)."""
    if len(tgt) == 0:
        return np.zeros(0, np.int64)
    return chain_ids(np.concatenate([tgt[:, None], keys], axis=1))


def shared_rows(src: np.ndarray, chain: np.ndarray, valid: np.ndarray, neighbours) -> tuple[np.ndarray, np.ndarray]:
    """Which candidate rows to solve again at which position.

    Parameters
    ----------
    src : numpy.ndarray
        Source (position) of each candidate row, (R,), int64, in ``[0, len(neighbours))``.
    chain : numpy.ndarray
        (target, chain) id of each row, (R,), int64, >= 0 (:func:`chain_ids`).
    valid : numpy.ndarray
        Whether the row is a valid path at its own source, (R,), bool.
    neighbours : list of numpy.ndarray
        Per position the positions it takes chains from.

    Returns
    -------
    rows, dest : numpy.ndarray
        Row of the candidate buffer to solve and the position to solve it at, (K,) each,
        int64: per position every chain valid at one of its neighbours and not among its
        own candidates (a chain it has already been solved), once.
    """
    n = len(neighbours)
    src = np.asarray(src, np.int64)
    chain = np.asarray(chain, np.int64)
    if len(src) and (src.min() < 0 or src.max() >= n or chain.min() < 0):
        raise ValueError(f"shared_rows: sources must lie in [0, {n}) and chain ids be >= 0")
    n_chains = int(chain.max()) + 1 if len(chain) else 1
    # the first valid row of each (position, chain)
    vr = np.flatnonzero(valid)
    _, first = np.unique(src[vr] * n_chains + chain[vr], return_index=True)
    vr = vr[first]
    vr = vr[np.argsort(src[vr], kind="stable")]
    starts = np.searchsorted(src[vr], np.arange(n + 1))
    # (position, neighbour) pairs, then every valid row of the neighbour for the position
    dest_nb = np.repeat(np.arange(n), [len(nb) for nb in neighbours])
    nb = np.concatenate([np.asarray(x, np.int64) for x in neighbours]) if n else np.zeros(0, np.int64)
    counts = starts[nb + 1] - starts[nb]
    dest = np.repeat(dest_nb, counts)
    offs = np.arange(counts.sum()) - np.repeat(np.cumsum(counts) - counts, counts)
    rows = vr[np.repeat(starts[nb], counts) + offs]
    # not among the position's own candidates, and each (position, chain) once; the
    # row of the first neighbour listed that has it
    key = dest * n_chains + chain[rows]
    own = src * n_chains + chain
    if n * n_chains <= _DENSE_KEYS:
        # a table of every (position, chain) key: 4-10x faster than a hash table on a
        # default chunk's 1.2e6 keys
        table = np.zeros(n * n_chains, bool)
        table[own] = True
        fresh = ~table[key]
    else:
        # a hash-table membership test (pandas): np.isin sorts both arrays, ~10x slower
        # on the millions of rows of a 128-position chunk (2.7 s on 2e6 x 1.5e6 keys)
        fresh = ~pd.Series(key, copy=False).isin(own).to_numpy()
    rows, dest, key = rows[fresh], dest[fresh], key[fresh]
    first = np.flatnonzero(~pd.Series(key, copy=False).duplicated().to_numpy())  # ascending
    return rows[first].astype(np.int64), dest[first].astype(np.int64)


def trace_shared(rt_scene, positions_m, targets_m, neighbours, max_depth: int, samples_per_src: int,
                 seed: int, refraction: bool = True, completion=None,
                 plane_ids=None) -> list[SourcePaths]:
    """Paths at every position from its own rays and its neighbours' valid chains.

    Parameters
    ----------
    rt_scene : sionna.rt.Scene
        The loaded scene (:func:`propagation.sionna_scene.load_sionna_scene`).
    positions_m : array_like
        Antenna positions (n, 3), metres; every one shoots ``samples_per_src`` rays.
    targets_m : array_like
        Tag positions (m, 3), metres; every position is solved against all of them.
    neighbours : list of array_like
        Per position the rows of the positions whose valid chains it takes
        (:func:`sharing_neighbours`).
    max_depth, samples_per_src, seed, refraction
        As for Sionna's ``PathSolver``.
    completion : (PlaneLookup, int), optional
        The large planes and order of the :func:`propagation.completion.complete_specular`
        that will complete these positions: candidates it enumerates
        (:meth:`~propagation.completion.PlaneLookup.covered`) are neither solved nor
        shared here (the completion solves them at every position). Without it the
        result is what ``PathSolver`` plus sharing gives.
    plane_ids : PlaneLookup, optional
        :func:`propagation.completion.triangle_planes`: chains are then named by their
        interaction types and *planes*, as Sionna's candidate generator and image method
        treat them, so a chain a neighbour found on other triangles of the same planes is
        not solved again when the position has it (or has it from another neighbour):
        solved, it would be a copy of a path the position already has. Default: named by
        the exact triangles.

    Returns
    -------
    list of SourcePaths
        Per position its paths to every target, sorted by length,
        copies removed.
    """
    from sionna.rt.constants import InteractionType


    pos = np.asarray(positions_m, float).reshape(-1, 3)
    tgt = np.asarray(targets_m, float).reshape(-1, 3)
    n, m = len(pos), len(tgt)
    if len(neighbours) != n:
        raise ValueError(f"need one neighbour list per position: {len(neighbours)} for {n}")
    place_devices(rt_scene)
    pos_mi, tgt_mi = points(pos), points(tgt)
    out = {"src": [], "tgt": [], "a": [], "tau": [], "k_tx": [], "k_rx": []}

    # 1. what PathSolver does: own rays (and LOS), image method and fields at each position
    # (Sionna's candidate generator, its shooting kernel compiled once for any target count)
    cand = shoot_candidates(rt_scene.mi_scene, pos_mi, tgt_mi, samples_per_src=samples_per_src,
                            max_depth=max_depth, refraction=refraction, seed=seed)
    n_rows = cand.n_rows
    if n_rows:
        src = cand.source
        keys = cand.keys
        d = keys.shape[1] // 3
        named = keys
        if plane_ids is not None:
            types = keys[:, :d]
            on = plane_ids.planes_of(keys[:, d:2 * d], keys[:, 2 * d:])
            none = types == int(InteractionType.NONE)
            # a triangle the lookup does not know keeps its own name (never merged)
            unknown = (on < 0) & ~none
            named = np.concatenate([types, np.where(none, -1, on),
                                    np.where(unknown, keys[:, d:2 * d], -1),
                                    np.where(unknown, keys[:, 2 * d:], -1)], axis=1)
        chain = _chain_ids(named, cand.target)
        los_row = cand.valid  # final already: line of sight
        solve = np.ones(n_rows, bool)
        if completion is not None:
            lookup, order = completion
            solve = ~lookup.covered(keys[:, :d], keys[:, d:2 * d], keys[:, 2 * d:], order)
        own_rows = np.flatnonzero(solve)
        valid = np.zeros(n_rows, bool)
        if len(own_rows):
            # in memory of its own, as the shared rows' and the completion's buffers: one
            # image-method and one field kernel serve all three
            own = cand.take(own_rows)
            if not any(len(nb) for nb in neighbours):
                # nothing to share: the candidates go before their copy is solved (lone
                # positions' chunks are sized for one buffer, not two)
                cand.release()
            own, valid[own_rows] = solve_paths(rt_scene, own, pos_mi, tgt_mi, n, m, validity=True)
            collect_paths(own, out)
            del own
        # 2. the chains valid at a neighbour, solved again at each position
        rows, dest = shared_rows(src, chain, valid & ~los_row, neighbours)
        if len(rows):
            buf = solve_paths(rt_scene, cand.take(rows, sources=dest), pos_mi, tgt_mi, n, m)
            collect_paths(buf, out)
    clear_devices(rt_scene)
    return to_source_paths(out, pos, tgt)
