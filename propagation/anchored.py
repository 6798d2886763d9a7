"""Gains at many tag positions from the paths traced to a few: anchors and their neighbours.

Tracing costs ~ sources x rays x receivers (Sionna tests every receiver from every hit
of every ray), so a dense set of candidate tag positions (a localisation grid) cannot be
traced link by link. Within a few centimetres of a traced tag position (the *anchor*) the
paths stay the same chains of surfaces, and a chain of specular reflections and straight
transmissions is a straight line from an image of the antenna: the channel at a nearby
target follows from the anchor's paths by their unfolded geometry
(:func:`anchored_gains_db`).

Two sources of anchor paths:

- :func:`trace_anchor_paths`: the study's tracer (cached, every option of
  :func:`~propagation.trace_links`): the physics;
- :func:`specular_model_paths`: line of sight and every specular reflection of order
  <= ``max_order`` over the scene's large planes, solved exactly by Sionna's image
  method (:mod:`propagation.completion`): no ray sampling, ~0.1-0.2 ms per link on two
  cores, but without transmissions and small surfaces; a cheap physical model to search
  with, not the truth.

Measured on ``corridor_lab`` (80 evaluation-tour antenna positions x 16 held-out tags,
carried from the tag's true position to a traced position 5 / 10 / 20 cm along the
wall): |error| p50 0.15 / 0.36 / 0.96 dB and p95 4.0 / 5.6 / 8.2 dB over readable links
(taking the anchor's value unchanged: p50 0.98 / 2.1 / 2.1 dB); vertically 0.08 / 0.16 /
0.30 dB (p95 1.1 / 1.7 / 3.3 dB). The tail is paths that appear or vanish between the two
positions (edges of furniture, door frames). The specular model against the full trace at
the same links: p50 0.68 dB, p95 10 dB over readable links.
"""

from __future__ import annotations

import numpy as np
from scipy import sparse

from propagation.backend import ensure_variant
from propagation.completion import complete_specular, large_planes
from propagation.constants import SPEED_OF_LIGHT
from propagation.pathcache import PathCache, SourcePaths, settings_key
from propagation.pathsolve import COMPLETION_ALGORITHM, trace_paths
from propagation.patterns import dipole_rotation, pattern_field_world, pose_rotation
from propagation.sionna_scene import check_antenna_positions, load_sionna_scene
from propagation.tracing import tag_dipole_axes

#: Planes of the specular model (:func:`specular_model_paths`): at least this area, m^2.
#: The tracer's completion has a lower default of its own
#: (``TraceOptions.completion_min_area_m2``); the model keeps 1 m^2 (its cache key follows
#: ``COMPLETION_ALGORITHM``, so a change of the completion's plane rule re-traces it).
MODEL_MIN_AREA_M2 = 1.0


__all__ = ["anchor_groups", "anchored_gains_db", "moved_antenna_local_mean_db", "specular_model_paths",
           "trace_anchor_paths", "window_gains_db"]

_LINKS_PER_BATCH = 50_000  # ~20 paths per link: ~1 M paths of temporaries per batch
#: Links per call of the per-anchor-link evaluation (patterns, transfer matrices): every
#: distinct (position, anchor) link of a call is held with all its paths at once
#: (~150 B per path, ~20 paths per link: ~300 MB at 100 000 links).
_LINKS_PER_CALL = 100_000
#: Path x target pairs per block of :func:`window_gains_db` (float64 and float32
#: temporaries of this size: ~200 MB measured).
_PAIRS_PER_BLOCK = 1 << 22
#: Links per call of the specular model's solver (bounds its outputs before they are
#: sorted into path sets; the solver itself bounds its Dr.Jit temporaries).
_MODEL_LINKS_PER_CALL = 50_000


def anchor_groups(positions_m, normals, spacing_m: float) -> tuple[np.ndarray, np.ndarray]:
    """Group points on surfaces into cells of ``spacing_m`` per surface orientation.

    Parameters
    ----------
    positions_m : array_like (k, 3)
        Points (tag sites), metres.
    normals : array_like (k, 3)
        Their surface normals; points of different normals never share an anchor (a
        tag's pattern and the paths that reach it change across a corner).
    spacing_m : float
        Cell size, metres.

    Returns
    -------
    anchors : numpy.ndarray (a,), int64
        Index of each cell's anchor: the member closest to the cell's mean.
    member_anchor : numpy.ndarray (k,), int64
        Per point, the position of its anchor in ``anchors``.
    """
    pos = np.asarray(positions_m, float).reshape(-1, 3)
    nrm = np.asarray(normals, float).reshape(-1, 3)
    if not (np.isfinite(spacing_m) and spacing_m > 0):
        raise ValueError(f"spacing_m must be positive, got {spacing_m!r}")
    if len(pos) == 0:
        return np.zeros(0, np.int64), np.zeros(0, np.int64)
    key = np.hstack([np.round(nrm, 3), np.floor(pos / float(spacing_m))])
    _, cell = np.unique(key, axis=0, return_inverse=True)
    cell = cell.reshape(-1)
    n_cells = int(cell.max()) + 1 if len(cell) else 0
    count = np.bincount(cell, minlength=n_cells)[:, None]
    mean = np.stack([np.bincount(cell, weights=pos[:, i], minlength=n_cells) for i in range(3)], 1) / count
    dist = np.linalg.norm(pos - mean[cell], axis=1)
    order = np.lexsort((dist, cell))  # per cell, the closest member first
    first = order[np.r_[True, cell[order][1:] != cell[order][:-1]]]
    anchors = first[np.argsort(cell[first])]
    return anchors.astype(np.int64), cell.astype(np.int64)


def specular_model_paths(scene, positions_m, anchors_m, need, frequency_hz: float, max_order: int = 2,
                         cache_dir=None):
    """Line-of-sight and specular-reflection paths (order <= ``max_order``) over the large
    planes, per antenna position (list of :class:`~propagation.pathcache.SourcePaths`);
    cached under ``cache_dir`` like traced paths (its own settings key: the model is
    deterministic, so a cached set is exactly what would be recomputed)."""
    from pathlib import Path


    pos = np.asarray(positions_m, float).reshape(-1, 3)
    anchors = np.asarray(anchors_m, float).reshape(-1, 3)
    need = np.asarray(need, bool)
    if need.shape != (len(pos), len(anchors)):
        raise ValueError(f"need must have shape ({len(pos)}, {len(anchors)}), got {need.shape}")
    settings = {"model": "specular_image_method", "frequency_hz": float(frequency_hz),
                "max_order": int(max_order), "min_area_m2": MODEL_MIN_AREA_M2,
                "algorithm": COMPLETION_ALGORITHM}
    cache = PathCache(Path(cache_dir) / settings_key(scene.content_hash(), settings)) if cache_dir else None
    out = cache.load(pos) if cache is not None else [None] * len(pos)
    out = [sp if sp is not None else SourcePaths.empty(pos[u]) for u, sp in enumerate(out)]
    todo = np.zeros_like(need)
    for u, sp in enumerate(out):
        want = np.flatnonzero(need[u])
        todo[u, want[sp.index_of(anchors[want]) < 0]] = True
    rows = np.flatnonzero(todo.any(axis=1))
    if len(rows):
        ensure_variant()
        rt_scene = load_sionna_scene(scene, frequency_hz)
        planes = large_planes(rt_scene, MODEL_MIN_AREA_M2)
        # positions in groups of <= _MODEL_LINKS_PER_CALL links: the paths of a call are
        # held several times over while they are sorted into path sets (~1 KB per link)
        for grp in _groups(rows, todo[rows].sum(axis=1), _MODEL_LINKS_PER_CALL):
            cols = np.flatnonzero(todo[grp].any(axis=0))
            fresh = complete_specular(rt_scene, pos[grp], anchors[cols], int(max_order), planes,
                                      need=todo[np.ix_(grp, cols)], los=True)
            for u, sp in zip(grp, fresh, strict=True):
                out[u] = out[u].merged(sp)
            if cache is not None:
                cache.save([out[u] for u in grp])
    return out


def trace_anchor_paths(scene, positions_m, anchors_m, need, *, frequency_hz: float, cache_dir=None,
                       options=None):
    """The study tracer's paths (:func:`propagation.pathsolve.trace_paths`, cached) from
    distinct antenna positions to anchors; ``options`` a :class:`propagation.TraceOptions`
    (default the library's; its patterns are not used here)."""
    pos = np.asarray(positions_m, float).reshape(-1, 3)
    active = np.asarray(need, bool).any(axis=1)
    if active.any():
        check_antenna_positions(scene, pos[active])
    return trace_paths(scene, pos, anchors_m, need, options, frequency_hz=frequency_hz,
                       cache_dir=cache_dir).paths


def anchored_gains_db(paths, pos_index, anchors_m, anchor_index, targets_m, target_normals, poses,
                      frequency_hz: float, *, reader_pattern: str, reader_polarization: str,
                      tag_pattern: str, incoherent: bool = False) -> np.ndarray:
    """One-way gains [dB] of links (antenna pose, target) carried from anchor paths.

    Each anchor path is a straight line of length ``l = c tau`` from an image of the
    antenna (specular reflections and straight transmissions unfold), at
    ``anchor + l k_rx`` (``k_rx`` points from the tag toward the incoming wave). At a
    target the path has length ``l' = |image - target|``: its phase is that of ``l'`` and
    its amplitude scales by ``l / l'`` (free-space spreading). Both antenna patterns,
    the Fresnel coefficients and the polarisation bases stay those of the anchor path
    (the pattern of the target's own dipole axis, at the anchor's arrival direction):
    errors of order ``|target - anchor| / l`` in angle. Exact for the geometry of every
    path that stays valid (same surfaces hit, no new occluder); paths the anchor lacks
    are missing at the target: keep targets close to their anchors.

    Parameters
    ----------
    paths : list of SourcePaths
        Per distinct antenna position, its paths to the anchors it needs.
    pos_index : array_like (L,), int
        Per link, the path set (antenna position).
    anchors_m : array_like (a, 3)
        Anchor positions (as traced), metres.
    anchor_index : array_like (L,), int
        Per link, its anchor (row of ``anchors_m``).
    targets_m : array_like (L, 3)
        Per link, the tag position the gain is wanted at, metres (the anchor itself
        gives exactly the traced gain).
    target_normals : array_like (L, 3)
        Per link, the surface normal at the target (the tag dipole lies in the tag plane,
        :func:`~propagation.tracing.tag_dipole_axes`).
    poses : array_like (L, 6)
        Per link, the antenna pose (orientation used; position that of the path set).
    incoherent : bool
        The local mean (paths summed in power, phases ignored) instead of the coherent
        gain.

    Returns
    -------
    numpy.ndarray (L,), float64
        Gains in dB; -inf where no path reaches.
    """
    anchors = np.asarray(anchors_m, float).reshape(-1, 3)
    tgt = np.asarray(targets_m, float).reshape(-1, 3)
    n = len(tgt)
    if n == 0:
        return np.zeros(0)
    pos_index = np.asarray(pos_index, np.int64).reshape(n)
    anchor_index = np.asarray(anchor_index, np.int64).reshape(n)
    if n > _LINKS_PER_CALL:  # bound the per-path temporaries: chunks of links sharing anchors
        order = np.argsort(pos_index * len(anchors) + anchor_index, kind="stable")
        normals = np.asarray(target_normals, float).reshape(n, 3)
        pose_all = np.asarray(poses, float).reshape(n, -1)
        out = np.empty(n)
        for lo in range(0, n, _LINKS_PER_CALL):
            sel = order[lo:lo + _LINKS_PER_CALL]
            out[sel] = anchored_gains_db(paths, pos_index[sel], anchors, anchor_index[sel], tgt[sel],
                                         normals[sel], pose_all[sel], frequency_hz,
                                         reader_pattern=reader_pattern,
                                         reader_polarization=reader_polarization,
                                         tag_pattern=tag_pattern, incoherent=incoherent)
        return out
    axes = tag_dipole_axes(np.asarray(target_normals, float).reshape(n, 3), n)
    pose6 = np.asarray(poses, float).reshape(n, -1)
    # the patterns and transfer matrices are evaluated once per (position, anchor, tag
    # axis, antenna orientation): a window of targets shares them
    _, axis_id = np.unique(np.round(axes, 6), axis=0, return_inverse=True)
    _, turn_id = np.unique(np.round(pose6[:, 3:], 9), axis=0, return_inverse=True)
    axis_id, turn_id = axis_id.reshape(-1), turn_id.reshape(-1)
    key = np.ravel_multi_index((pos_index, anchor_index, axis_id, turn_id),
                               (len(paths), len(anchors), axis_id.max() + 1, turn_id.max() + 1))
    u_of, count, gathered, rep = _distinct_link_paths(paths, key, pos_index, anchors[anchor_index])
    c_tx = pattern_field_world(reader_pattern, reader_polarization, pose_rotation(pose6[rep]),
                               gathered["k_tx"])
    g_rx = pattern_field_world(tag_pattern, "V", dipole_rotation(axes[rep]), gathered["k_rx"])
    weight = np.einsum("pr,prt,pt->p", np.conj(g_rx), gathered["transfer"], c_tx)
    length = gathered["tau"] * SPEED_OF_LIGHT
    image = anchors[anchor_index[rep]] + gathered["k_rx"] * length[:, None]
    offset = np.concatenate([[0], np.cumsum(count)])
    k0 = 2.0 * np.pi * float(frequency_hz) / SPEED_OF_LIGHT
    power = np.zeros(n)
    for lo in range(0, n, _LINKS_PER_BATCH):
        sel = np.arange(lo, min(n, lo + _LINKS_PER_BATCH))
        link, p = _rows(offset[u_of[sel]], count[u_of[sel]])
        if len(p) == 0:
            continue
        new_length = np.linalg.norm(image[p] - tgt[sel[link]], axis=1)
        amp = weight[p] * (length[p] / new_length)
        if incoherent:
            power[sel] = np.bincount(link, weights=amp.real**2 + amp.imag**2, minlength=len(sel))
        else:
            amp = amp * np.exp(-1j * k0 * new_length)
            h = (np.bincount(link, weights=amp.real, minlength=len(sel))
                 + 1j * np.bincount(link, weights=amp.imag, minlength=len(sel)))
            power[sel] = h.real**2 + h.imag**2
    with np.errstate(divide="ignore"):
        return 10.0 * np.log10(power)


def window_gains_db(paths, pos_index, poses, anchor_m, targets_m, target_normal, frequency_hz: float, *,
                    reader_pattern: str, reader_polarization: str, tag_pattern: str) -> np.ndarray:
    """Coherent one-way gains [dB] of S antenna poses to M targets carried from one anchor.

    The same gains as :func:`anchored_gains_db` on every (pose, target) pair (test), for
    a window of targets that share the anchor and the surface normal (one tag dipole
    axis), computed as dense (paths x targets) blocks: the patterns once per pose and
    path, the carried lengths by ``|l k_rx - q|^2 = l^2 |k_rx|^2 - 2 l k_rx . q + |q|^2``
    with ``q = target - anchor`` (one matrix product), the paths of each pose summed with
    one sparse segment sum; phases reduced in float64, cos/sin in float32 (|h| to ~1e-7
    relative, 1e-4 dB). Several times faster than the per-link form for a window.

    Parameters
    ----------
    paths : list of SourcePaths
        Per distinct antenna position, its paths (the anchor among their tags).
    pos_index : array_like (S,), int
        Per pose, its path set.
    poses : array_like (S, 6)
        Antenna poses (orientation used; position that of the path set).
    anchor_m : array_like (3,)
        The anchor as traced, metres.
    targets_m : array_like (M, 3)
        Tag positions near the anchor, metres.
    target_normal : array_like (3,)
        Their common surface normal.
    frequency_hz : float
        Carrier frequency [Hz] of the phases.
    reader_pattern, reader_polarization, tag_pattern : str
        Antenna patterns, as for :func:`anchored_gains_db`.

    Returns
    -------
    numpy.ndarray (S, M), float64
        Gains in dB; -inf where no path reaches.
    """
    pos_index = np.asarray(pos_index, np.int64).reshape(-1)
    pose6 = np.asarray(poses, float).reshape(len(pos_index), -1)
    anchor = np.asarray(anchor_m, float).reshape(3)
    q = np.asarray(targets_m, float).reshape(-1, 3) - anchor
    out = np.full((len(pos_index), len(q)), -np.inf)
    if len(pos_index) == 0 or len(q) == 0:
        return out
    start, count = _path_slices(paths, pos_index, np.broadcast_to(anchor, (len(pos_index), 3)))
    link, row = _rows(start, count)
    if len(row) == 0:
        return out
    g = _gather(paths, pos_index[link], row)
    axis = tag_dipole_axes(np.asarray(target_normal, float).reshape(1, 3), 1)
    c_tx = pattern_field_world(reader_pattern, reader_polarization, pose_rotation(pose6[link]), g["k_tx"])
    g_rx = pattern_field_world(tag_pattern, "V", dipole_rotation(np.repeat(axis, len(row), axis=0)),
                               g["k_rx"])
    length = g["tau"] * SPEED_OF_LIGHT
    scaled = np.einsum("pr,prt,pt->p", np.conj(g_rx), g["transfer"], c_tx) * length  # weight * l
    w_re, w_im = (x.astype(np.float32)[:, None] for x in (scaled.real, scaled.imag))
    l2 = length**2 * np.sum(g["k_rx"] ** 2, axis=1)
    k0 = 2.0 * np.pi * float(frequency_hz) / SPEED_OF_LIGHT
    reached = np.flatnonzero(count > 0)
    # each reached pose sums its paths: a sparse (poses x paths) matrix of ones
    segments = sparse.csr_matrix((np.ones(len(row), np.float32), (np.repeat(np.arange(len(reached)),
                                                                             count[reached]),
                                                                   np.arange(len(row)))),
                                 shape=(len(reached), len(row)))
    step = max(1, _PAIRS_PER_BLOCK // len(row))
    for m0 in range(0, len(q), step):
        qb = q[m0:m0 + step]
        new_length = np.sqrt(np.maximum(
            l2[:, None] - 2.0 * length[:, None] * (g["k_rx"] @ qb.T) + np.sum(qb**2, axis=1)[None], 0.0))
        # the phase in float64, reduced to [-pi, pi], then cos/sin in float32 (SIMD: ~6x
        # faster than float64 here; |h| relative error ~1e-7, 1e-4 dB at most measured)
        phase = k0 * new_length
        phase -= 2.0 * np.pi * np.round(phase / (2.0 * np.pi))
        phase = phase.astype(np.float32)
        inv = (1.0 / new_length).astype(np.float32)
        cos, sin = np.cos(phase) * inv, np.sin(phase) * inv
        # sum_p w_p / l'_p exp(-j k0 l'_p) with w = w_re + j w_im
        h_re = segments @ (cos * w_re + sin * w_im)
        h_im = segments @ (cos * w_im - sin * w_re)
        power = h_re.astype(np.float64) ** 2 + h_im.astype(np.float64) ** 2
        with np.errstate(divide="ignore"):
            out[reached, m0:m0 + step] = 10.0 * np.log10(power)
    return out


def moved_antenna_local_mean_db(paths, pos_index, tags_m, tag_index, tag_normals, antenna_poses,
                                *, reader_pattern: str, reader_polarization: str,
                                tag_pattern: str) -> np.ndarray:
    """Local-mean one-way gains [dB] at antenna poses near traced antenna positions.

    The antenna-side twin of :func:`anchored_gains_db`: a path leaves the traced antenna
    position ``p`` along ``k_tx`` toward an image of the tag at ``p + l k_tx``; from a
    moved antenna at ``p'`` it has length ``l' = |image - p'|`` and leaves along
    ``(image - p') / l'``, where the reader pattern is evaluated with the pose's own
    orientation. Paths are summed in power (the local mean: no phases), each scaled by
    ``(l / l')^2``; the tag pattern, Fresnel coefficients and bases stay the traced ones.

    Parameters
    ----------
    paths : list of SourcePaths
        Per traced antenna position, its paths to the tags.
    pos_index : array_like (L,), int
        Per link, its traced antenna position (path set).
    tags_m : array_like (m, 3)
        Tag positions as traced, metres.
    tag_index : array_like (L,), int
        Per link, its tag.
    tag_normals : array_like (m, 3)
        Tag surface normals (the dipole lies in the tag plane).
    antenna_poses : array_like (L, 6)
        Per link, the moved antenna pose [x, y, z, yaw, pitch, roll] [m, rad].

    Returns
    -------
    numpy.ndarray (L,), float64
        Local-mean gains in dB; -inf where no path reaches.
    """
    tags = np.asarray(tags_m, float).reshape(-1, 3)
    pose6 = np.asarray(antenna_poses, float).reshape(-1, 6)
    n = len(pose6)
    pos_index = np.asarray(pos_index, np.int64).reshape(n)
    tag_index = np.asarray(tag_index, np.int64).reshape(n)
    if n == 0:
        return np.zeros(0)
    r_tag = dipole_rotation(tag_dipole_axes(np.asarray(tag_normals, float).reshape(-1, 3), len(tags)))
    # per (traced position, tag): its paths' tag-side vectors g^H T (the part that does
    # not move with the antenna), evaluated once
    key = pos_index * len(tags) + tag_index
    u_of, count, gathered, rep = _distinct_link_paths(paths, key, pos_index, tags[tag_index])
    g_rx = pattern_field_world(tag_pattern, "V", r_tag[tag_index[rep]], gathered["k_rx"])
    tag_side = np.einsum("pr,prt->pt", np.conj(g_rx), gathered["transfer"])  # (P, 2)
    length = gathered["tau"] * SPEED_OF_LIGHT
    source = np.stack([paths[i].source_m for i in range(len(paths))])
    image = source[pos_index[rep]] + gathered["k_tx"] * length[:, None]
    offset = np.concatenate([[0], np.cumsum(count)])
    r_reader = pose_rotation(pose6)
    power = np.zeros(n)
    for lo in range(0, n, _LINKS_PER_BATCH):
        sel = np.arange(lo, min(n, lo + _LINKS_PER_BATCH))
        link, p = _rows(offset[u_of[sel]], count[u_of[sel]])
        if len(p) == 0:
            continue
        to_image = image[p] - pose6[sel[link], :3]
        new_length = np.linalg.norm(to_image, axis=1)
        c_tx = pattern_field_world(reader_pattern, reader_polarization, r_reader[sel[link]],
                                   to_image / new_length[:, None])
        amp = np.einsum("pt,pt->p", tag_side[p], c_tx) * (length[p] / new_length)
        power[sel] = np.bincount(link, weights=amp.real**2 + amp.imag**2, minlength=len(sel))
    with np.errstate(divide="ignore"):
        return 10.0 * np.log10(power)


def _distinct_link_paths(paths, key, pos_index, end_m):
    """The paths of each distinct link (equal ``key``: evaluated once).

    Returns
    -------
    u_of : numpy.ndarray (L,)
        Per link, its distinct link.
    count : numpy.ndarray (u,)
        Paths per distinct link (its paths are contiguous, in distinct-link order).
    gathered : dict
        Path arrays (``transfer``, ``tau``, ``k_tx``, ``k_rx``), one row per path.
    rep : numpy.ndarray (P,)
        Per path, the first link of its distinct link (for per-link attributes).
    """
    _, first, u_of = np.unique(key, return_index=True, return_inverse=True)
    start, count = _path_slices(paths, pos_index[first], end_m[first])
    u_link, row = _rows(start, count)
    return u_of.reshape(-1), count, _gather(paths, pos_index[first][u_link], row), first[u_link]


def _groups(items, sizes, limit: int) -> list[np.ndarray]:
    """``items`` in consecutive groups whose ``sizes`` add up to at most ``limit`` (a
    single item larger than ``limit`` forms its own group)."""
    out, lo, acc = [], 0, 0
    for i, size in enumerate(np.asarray(sizes, np.int64)):
        if i > lo and acc + size > limit:
            out.append(items[lo:i])
            lo, acc = i, 0
        acc += int(size)
    if len(items) > lo:
        out.append(items[lo:])
    return out


def _rows(start, count) -> tuple[np.ndarray, np.ndarray]:
    """Rows ``start[i] .. start[i] + count[i] - 1`` of every item i, flattened:
    (item of each row, row)."""
    item = np.repeat(np.arange(len(count)), count)
    first = np.concatenate([[0], np.cumsum(count)[:-1]]).astype(np.int64)
    return item, np.repeat(start - first, count) + np.arange(int(np.sum(count)))


def _path_slices(paths, pos_index, anchor_pos) -> tuple[np.ndarray, np.ndarray]:
    """Per link: first path row and path count of its anchor in its path set."""
    start = np.zeros(len(pos_index), np.int64)
    count = np.zeros(len(pos_index), np.int64)
    order = np.argsort(pos_index, kind="stable")
    for grp in np.split(order, np.flatnonzero(np.diff(pos_index[order])) + 1):
        if len(grp) == 0:
            continue
        sp = paths[pos_index[grp[0]]]
        rows = sp.index_of(anchor_pos[grp])
        if np.any(rows < 0):
            raise ValueError("carried gains: an anchor was not traced from a link's antenna position")
        start[grp] = sp.offsets[rows]
        count[grp] = sp.offsets[rows + 1] - sp.offsets[rows]
    return start, count


def _gather(paths, src, row) -> dict:
    """Path arrays at (path set, row) pairs."""
    out = {k: np.empty((len(row),) + getattr(paths[0], f).shape[1:], getattr(paths[0], f).dtype)
           for k, f in (("transfer", "transfer"), ("tau", "tau_s"), ("k_tx", "k_tx"), ("k_rx", "k_rx"))}
    order = np.argsort(src, kind="stable")
    for grp in np.split(order, np.flatnonzero(np.diff(src[order])) + 1):
        if len(grp) == 0:
            continue
        sp = paths[src[grp[0]]]
        r = row[grp]
        out["transfer"][grp] = sp.transfer[r]
        out["tau"][grp] = sp.tau_s[r]
        out["k_tx"][grp] = sp.k_tx[r]
        out["k_rx"][grp] = sp.k_rx[r]
    return out
