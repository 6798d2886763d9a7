"""Image-method completion: every low-order specular reflection off the scene's large planes.

Sionna's ``PathSolver`` finds specular chains by shoot-and-bounce, then validates them
with its image method. At each hit the shoot-and-bounce *samples* reflection or
refraction (in proportion to their energy), so a chain of weak reflections is rarely
shot: on ``corridor_lab`` (40 positions x 24 tags, 3e4 rays, depth 5) the trace misses
1 % of the first-order, 26 % of the second-order and 69 % of the third-order reflections
over large planes (with refraction off, 2 % of the second order). Over large planes
(walls, floor, ceiling) the image method alone can *enumerate* the low-order chains:

1. :func:`large_planes` groups the triangles of the loaded scene into planes and keeps
   those of at least ``min_area_m2``.
2. :func:`complete_specular` enumerates every chain of 1..``max_order`` reflections over
   these planes (no plane twice in a row), drops in NumPy the (link, chain)
   pairs that cannot be paths even on the unbounded planes (each backtracked segment must
   cross its plane, each reflection point must lie in the plane's bounding box and in a
   cell of it its triangles cover: :mod:`propagation.chain_pretest`,
   :mod:`propagation.plane_cover`), and gives the rest to Sionna's own ``ImageMethod``
   (exact triangles, occlusion, float32) and ``FieldCalculator`` (materials), reached
   through :mod:`propagation.sionna_internals`.
3. :func:`merge_paths` adds the completion to a ``PathSolver`` trace without counting a
   path twice.

Planes span shapes: Sionna's image method accepts a hit on any triangle coplanar with the
expected one, on any shape (``ImageMethod._backtrack`` compares the two images, not the
shapes), and then stores the shape and primitive actually hit, so the field calculator
evaluates the material that was hit. One representative triangle per geometric plane is
therefore enough, whatever the materials of its coplanar shapes.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass

import numpy as np

from propagation.chain_pretest import BOX_SLACK_M, iter_candidate_chains
from propagation.constants import SPEED_OF_LIGHT
from propagation.pathcache import SourcePaths
from propagation.plane_cover import plane_cover
from propagation.planes import Planes
from propagation.sionna_internals import (
    collect_paths,
    image_method,
    line_of_sight_candidates,
    shape_pointers,
    solve_paths,
    specular_chain_buffer,
)
from propagation.sionna_paths import path_copies, points, to_source_paths
from propagation.sionna_scene import clear_devices, place_devices

logger = logging.getLogger(__name__)

__all__ = ["Planes", "PlaneLookup", "complete_specular", "large_planes", "merge_paths", "plane_lookup",
           "triangle_planes"]

#: Largest offset of a parallel triangle whose hit Sionna's image method takes for the
#: expected plane's, m: ``ImageMethod._backtrack`` accepts another triangle where the two
#: images of the image differ by under 1 cm (squared norm < 1e-4), i.e. twice the offset.
SAME_IMAGE_OFFSET_M = 5e-3
#: Candidate chains per call of Sionna's image method and field calculator: they hold
#: ~330 B of Dr.Jit temporaries per candidate in buffers of depth 2-3 (measured on
#: corridor_lab: 7.0 M order-2 candidates peaked at 2.3 GB, 2.9 M order-3 ones at
#: 1.0 GB), ~350 MB per call; more in the sharing tracer's depth-5 buffers
#: (``buffer_depth``; not measured alone: the paper-scale study's peak with them and
#: the reads' own buffers evaluated into memory of their own is in CHANGELOG.md, 2026-11-29).
_CANDIDATES_PER_CALL = 1 << 20
#: (source, target) pairs per line-of-sight call (every pair of the call is solved).
_LOS_PAIRS_PER_CALL = 1 << 18


def large_planes(rt_scene, min_area_m2: float = 1.0, normal_tol: float = 1e-4,
                 offset_tol_m: float = 1e-3, max_planes: int = 0) -> Planes:
    """Group the scene's triangles into planes and keep the large ones.

    Parameters
    ----------
    rt_scene : sionna.rt.Scene
        The loaded scene (:func:`propagation.sionna_scene.load_sionna_scene`).
    min_area_m2 : float
        Smallest area of a plane that is kept, m^2: its total triangle area and its
        largest connected patch (triangles joined by shared vertices) must both reach it.
        A plane of many small disjoint pieces (the uprights of shelving racks, coplanar
        along a rack and across racks: on a 30 m x 50 m warehouse map 79 of 116 planes,
        0.18 m^2 pieces summing to 5.5 m^2, their boxes spanning the building) does not
        reflect like a plane, and enumerating chains over it multiplied the completion's
        candidates ~30x; the shoot-and-bounce still traces its pieces.
    normal_tol : float
        Largest per-component difference of two unit normals (up to sign) in one plane.
    offset_tol_m : float
        Largest distance of a triangle's vertices from the plane of its group, metres.
    max_planes : int
        Keep at most this many planes, the largest; 0: all. The completion enumerates
        chains over pairs and triples of planes, so its cost grows with their square or
        cube: a real SLAM map's jagged walls gave 609 planes of 0.1 m^2 and up against 115
        on the bundled 30 m x 50 m warehouse, and about 7x its time per position.

    Returns
    -------
    Planes
        Sorted by decreasing area.
    """
    shapes = list(rt_scene.mi_scene.shapes())
    tris, sid, prim = [], [], []
    for k, s in enumerate(shapes):
        if not hasattr(s, "faces_buffer") or s.face_count() == 0:
            continue
        v = np.asarray(s.vertex_positions_buffer(), np.float64).reshape(-1, 3)
        f = np.asarray(s.faces_buffer(), np.int64).reshape(-1, 3)
        tris.append(v[f])
        sid.append(np.full(len(f), k, np.int64))
        prim.append(np.arange(len(f), dtype=np.int64))
    empty = np.zeros((0, 3))
    if not tris:
        z = np.zeros(0)
        return Planes(empty, z, z, empty, empty, z.astype(np.int64), z.astype(np.int64), empty, ())
    tri, sid, prim = np.concatenate(tris), np.concatenate(sid), np.concatenate(prim)
    cr = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    twice_area = np.linalg.norm(cr, axis=1)
    ok = twice_area > 1e-12  # degenerate triangles have no plane
    tri, sid, prim, cr, twice_area = tri[ok], sid[ok], prim[ok], cr[ok], twice_area[ok]
    nrm = cr / twice_area[:, None]
    area = 0.5 * twice_area
    free = np.ones(len(tri), bool)
    rows = []
    while free.any():  # one pass per distinct plane, vectorised over triangles
        i = int(np.argmax(free))
        n0 = nrm[i]
        d0 = float(n0 @ tri[i, 0])
        sign = np.sign(nrm @ n0)
        same = free & (np.abs(nrm * sign[:, None] - n0).max(axis=1) <= normal_tol) \
            & (np.abs(tri @ n0 - d0).max(axis=1) <= offset_tol_m)
        same[i] = True
        free &= ~same
        members = np.flatnonzero(same)
        if area[members].sum() < min_area_m2 or _largest_patch_m2(tri[members], area[members]) < min_area_m2:
            continue
        rep = members[np.argmax(area[members])]
        pts = tri[members].reshape(-1, 3)
        rows.append((nrm[rep], float(nrm[rep] @ tri[rep, 0]), float(area[members].sum()), pts.min(0),
                     pts.max(0), sid[rep], prim[rep], tri[rep, 0],
                     tuple(sorted({str(shapes[k].id()) for k in sid[members]})), members))
    rows.sort(key=lambda r: -r[2])
    if max_planes and len(rows) > max_planes:
        logger.info("completion: %d planes of %g m^2 and up, the %d largest kept (%.2f m^2 and up)",
                    len(rows), min_area_m2, max_planes, rows[max_planes - 1][2])
        rows = rows[:max_planes]
    if not rows:
        z = np.zeros(0)
        return Planes(empty, z, z, empty, empty, z.astype(np.int64), z.astype(np.int64), empty, ())
    cols = list(zip(*rows, strict=True))
    normal, offset, lo, hi = np.array(cols[0]), np.array(cols[1]), np.array(cols[3]), np.array(cols[4])
    # the cover holds the plane's own triangles and every triangle in its box a reflection
    # off it may hit: parallel within Sionna's image test (which plane_lookup's labels are
    # within too), so the raster never drops a point the box test kept and Sionna accepts
    members, on = cols[9], []
    for p in range(len(rows)):
        mask = _on_plane(tri, nrm, normal[p], offset[p], lo[p] - SAME_IMAGE_OFFSET_M,
                         hi[p] + SAME_IMAGE_OFFSET_M, normal_tol, max(offset_tol_m, SAME_IMAGE_OFFSET_M))
        mask[members[p]] = True
        on.append(tri[mask])
    return Planes(normal, offset, np.array(cols[2]), lo, hi, np.array(cols[5], np.int64),
                  np.array(cols[6], np.int64), np.array(cols[7]), tuple(cols[8]),
                  plane_cover(on, normal, lo, hi, BOX_SLACK_M))


def _on_plane(tri, nrm, normal, offset_m, lo_m, hi_m, normal_tol: float, offset_tol_m: float) -> np.ndarray:
    """Triangles (t, 3, 3) of unit normals ``nrm`` (t, 3) that lie on the plane
    (``normal``, ``offset_m``) within the tolerances and inside its box (with the
    pre-test's slack), (t,) bool."""
    sign = np.sign(nrm @ normal)
    return ((np.abs(nrm * sign[:, None] - normal).max(axis=1) <= normal_tol)
            & (np.abs(tri @ normal - offset_m).max(axis=1) <= offset_tol_m)
            & np.all(tri >= lo_m - BOX_SLACK_M, axis=(1, 2))
            & np.all(tri <= hi_m + BOX_SLACK_M, axis=(1, 2)))


def _largest_patch_m2(tri: np.ndarray, area: np.ndarray) -> float:
    """Area of the largest set of triangles (k, 3, 3) joined by shared vertices (equal
    after rounding to 0.1 mm), m^2 (scipy.sparse.csgraph's connected components of
    triangles and vertices). Pieces meeting only at a T-junction count apart: that can
    only leave out a plane whose pieces are each under the area."""
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components

    if len(tri) == 1:
        return float(area[0])
    _, vid = np.unique(np.round(tri.reshape(-1, 3) * 1e4).astype(np.int64), axis=0, return_inverse=True)
    k, n_v = len(tri), int(vid.max()) + 1
    rows = np.repeat(np.arange(k), 3)  # triangle -> its vertices, a bipartite graph
    g = coo_matrix((np.ones(3 * k), (rows, vid.reshape(-1) + k)), shape=(k + n_v, k + n_v))
    _, label = connected_components(g, directed=False)
    return float(np.bincount(label[:k], weights=area).max())


#: :meth:`PlaneLookup.planes_of` uses a dense table when every shape pointer is below this
#: (8 MiB of int64 per table at most).
_DENSE_POINTERS = 1 << 20


@dataclass(frozen=True)
class PlaneLookup:
    """Which large plane each triangle of a loaded scene lies on (:func:`plane_lookup`).

    Attributes
    ----------
    shape_ptr : numpy.ndarray
        Shape pointers as Sionna's candidate buffers hold them (s,), uint32, sorted,
        unique (Dr.Jit registry ids: one per shape).
    offset : numpy.ndarray
        Start of each shape's triangles in ``plane`` (s + 1,), int64.
    plane : numpy.ndarray
        Per triangle the index of its plane in the :class:`Planes`, or -1
        (:func:`plane_lookup`); or the id of its geometric plane (:func:`triangle_planes`)
        (t,), int64.
    """

    shape_ptr: np.ndarray
    offset: np.ndarray
    plane: np.ndarray

    def planes_of(self, shapes, primitives) -> np.ndarray:
        """Plane index of each (shape pointer, primitive), -1 where none (same shape)."""
        shapes = np.asarray(shapes, np.int64)
        prims = np.asarray(primitives, np.int64)
        if len(self.shape_ptr) == 0 or len(self.plane) == 0:
            return np.full(shapes.shape, -1, np.int64)
        top = int(self.shape_ptr[-1]) + 1
        if top <= _DENSE_POINTERS:
            # pointers are Dr.Jit registry ids (small integers): a table indexed by the
            # pointer is ~3x faster than searching the sorted pointers
            start = np.zeros(top + 1, np.int64)
            count = np.zeros(top + 1, np.int64)  # 0: not a shape of the lookup
            start[self.shape_ptr] = self.offset[:-1]
            count[self.shape_ptr] = np.diff(self.offset)
            s = np.where((shapes >= 0) & (shapes < top), shapes, top)
            known = (prims >= 0) & (prims < count[s])
            idx = start[s] + prims
        else:
            k = np.minimum(np.searchsorted(self.shape_ptr, shapes), len(self.shape_ptr) - 1)
            idx = self.offset[k] + prims
            known = (self.shape_ptr[k] == shapes) & (prims >= 0) & (idx < self.offset[k + 1])
        return np.where(known, np.take(self.plane, idx, mode="clip"), -1).astype(np.int64, copy=False)

    def covered(self, interaction_types, shapes, primitives, max_order: int) -> np.ndarray:
        """Candidate rows the completion enumerates: 1..``max_order`` specular
        reflections, every one on a large plane and no plane twice in a row (as
        :func:`complete_specular` enumerates them), (R,) bool.

        Parameters
        ----------
        interaction_types, shapes, primitives : numpy.ndarray
            A candidate buffer's (R, depth) columns (``candidate_keys``' parts).
        max_order : int
            The completion's order (0: nothing is covered).
        """
        from sionna.rt.constants import InteractionType

        types = np.asarray(interaction_types, np.int64)
        none, spec = int(InteractionType.NONE), int(InteractionType.SPECULAR)
        order = (types != none).sum(axis=1)
        plane = self.planes_of(shapes, primitives)
        ok = (order >= 1) & (order <= int(max_order)) & np.all(
            (types == none) | ((types == spec) & (plane >= 0)), axis=1)
        if types.shape[1] > 1:
            repeat = (plane[:, 1:] == plane[:, :-1]) & (types[:, 1:] != none)
            ok &= ~repeat.any(axis=1)
        return ok


def plane_lookup(rt_scene, planes: Planes, normal_tol: float = 1e-4,
                 offset_tol_m: float = 1e-3) -> PlaneLookup:
    """Per triangle of the loaded scene the large plane it lies on (tolerances of
    :func:`large_planes`).

    A ray-traced candidate made only of reflections on these planes, of order up to the
    completion's, is a chain :func:`complete_specular` enumerates for every link: the
    image method reflects through the plane, whichever of its triangles the chain named,
    and accepts a hit on any coplanar triangle (module doc). Solving it from the rays too
    is work done twice (and a copy that ``merge_paths`` drops).

    A triangle gets a plane's label only when it also lies inside that plane's bounding
    box (with the pre-test's slack): the completion's pre-test drops reflection points
    outside the box (and off the plane's raster, which holds every triangle labelled
    here), so a chain labelled here is one the completion does not drop for lying off
    its plane (a triangle coplanar with a large plane but grouped elsewhere,
    as may happen in an imported mesh, stays unlabelled and its chains are traced).
    """
    shapes = list(rt_scene.mi_scene.shapes())
    if not shapes:
        return PlaneLookup(np.zeros(0, np.uint32), np.zeros(1, np.int64), np.zeros(0, np.int64))
    ptr = shape_pointers(rt_scene.mi_scene)
    labels = []
    for s in shapes:
        if not hasattr(s, "faces_buffer") or s.face_count() == 0:
            labels.append(np.zeros(0, np.int64))
            continue
        v = np.asarray(s.vertex_positions_buffer(), np.float64).reshape(-1, 3)
        tri = v[np.asarray(s.faces_buffer(), np.int64).reshape(-1, 3)]
        cr = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
        nrm = cr / np.maximum(np.linalg.norm(cr, axis=1), 1e-300)[:, None]
        lab = np.full(len(tri), -1, np.int64)
        for p in range(len(planes)):
            on = _on_plane(tri, nrm, planes.normal[p], planes.offset_m[p], planes.lo_m[p], planes.hi_m[p],
                           normal_tol, offset_tol_m)
            lab[on & (lab < 0)] = p
        labels.append(lab)
    order = np.argsort(ptr, kind="stable")
    counts = np.array([len(labels[k]) for k in order], np.int64)
    return PlaneLookup(ptr[order], np.concatenate([[0], np.cumsum(counts)]).astype(np.int64),
                       np.concatenate([labels[k] for k in order]) if len(order) else np.zeros(0, np.int64))


def triangle_planes(rt_scene, normal_step: float = 1e-4, offset_step_m: float = 1e-3) -> PlaneLookup:
    """Per triangle of the loaded scene an id of its geometric plane (all triangles).

    Sionna's image method reflects through the plane of the triangle a candidate names and
    accepts a hit on any coplanar triangle; a refraction does not bend the path. So two
    candidates of one (source, target) whose interactions lie on the same planes, in the
    same order and of the same types, are the same path once solved. The id is the
    plane's unit normal (sign fixed by its largest component) rounded to ``normal_step``
    and its offset rounded to ``offset_step_m``: a plane split by a rounding boundary
    gets two ids (its candidates are solved twice, and the copy is dropped later), two
    planes share an id only when they agree to these steps, far below what Sionna's image
    test (1 cm between images) tells apart. Degenerate triangles get ids of their own.
    """
    shapes = list(rt_scene.mi_scene.shapes())
    if not shapes:
        return PlaneLookup(np.zeros(0, np.int64), np.zeros(1, np.int64), np.zeros(0, np.int64))
    ptr = shape_pointers(rt_scene.mi_scene)
    tris = []
    for s in shapes:
        if not hasattr(s, "faces_buffer") or s.face_count() == 0:
            tris.append(np.zeros((0, 3, 3)))
            continue
        v = np.asarray(s.vertex_positions_buffer(), np.float64).reshape(-1, 3)
        tris.append(v[np.asarray(s.faces_buffer(), np.int64).reshape(-1, 3)])
    order = np.argsort(ptr, kind="stable")
    tri = np.concatenate([tris[k] for k in order]) if len(order) else np.zeros((0, 3, 3))
    cr = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    norm = np.linalg.norm(cr, axis=1)
    ok = norm > 1e-12
    nrm = cr / np.where(ok, norm, 1.0)[:, None]
    big = np.argmax(np.abs(nrm), axis=1)
    nrm *= np.where(nrm[np.arange(len(nrm)), big] < 0, -1.0, 1.0)[:, None]
    off = np.einsum("tx,tx->t", nrm, tri[:, 0])
    key = np.column_stack([np.round(nrm / normal_step), np.round(off / offset_step_m)]).astype(np.int64)
    key[~ok] = np.column_stack([np.full((int((~ok).sum()), 3), np.iinfo(np.int64).min),
                                np.flatnonzero(~ok)])  # each degenerate triangle alone
    ids = np.unique(key, axis=0, return_inverse=True)[1].reshape(-1).astype(np.int64)
    counts = np.array([len(tris[k]) for k in order], np.int64)
    return PlaneLookup(ptr[order], np.concatenate([[0], np.cumsum(counts)]).astype(np.int64), ids)


def complete_specular(rt_scene, sources_m, targets_m, max_order: int = 2, planes: Planes | None = None,
                      *, need=None, los: bool = False,
                      buffer_depth: int | None = None) -> list[SourcePaths]:
    """Every specular-reflection path of order 1..``max_order`` over the large planes.

    Parameters
    ----------
    rt_scene : sionna.rt.Scene
        The loaded scene (:func:`propagation.sionna_scene.load_sionna_scene`).
    sources_m : array_like
        Antenna positions (n, 3), metres.
    targets_m : array_like
        Tag positions (m, 3), metres.
    max_order : int
        Highest number of reflections. The chains enumerated grow as ``p (p - 1)^(k-1)``
        with ``p = len(planes)``; order 3 is the practical limit.
    planes : Planes, optional
        Reflecting planes; default :func:`large_planes` of ``rt_scene`` (1 m^2 and up).
    need : array_like of bool, optional
        (n, m): the tags each position needs; default all.
    los : bool
        Also return the line-of-sight paths (Sionna's own visibility test).
    buffer_depth : int, optional
        Solve the chains in paths buffers of this depth (>= ``max_order``; the chains
        padded with no interaction), default ``max_order``: a tracer's ``max_depth``
        gives the image method and field kernels of its own buffers, compiled once for
        both (Sionna bakes the depth into them). The paths are the same.

    Returns
    -------
    list of SourcePaths
        Per position, its valid paths (unrotated iso ``VH`` transfer matrices, delays,
        directions as in :mod:`propagation.sionna_paths`) to every tag it needs, in target
        order. Reflections are found on any triangle coplanar with a large plane.
    """
    src = np.asarray(sources_m, float).reshape(-1, 3)
    tgt = np.asarray(targets_m, float).reshape(-1, 3)
    n, m = len(src), len(tgt)
    need = np.ones((n, m), bool) if need is None else np.asarray(need, bool)
    if need.shape != (n, m):
        raise ValueError(f"need must have shape ({n}, {m}), got {need.shape}")
    if int(max_order) < 1:
        raise ValueError(f"need max_order >= 1, got {max_order}")
    depth = int(max_order) if buffer_depth is None else int(buffer_depth)
    if depth < int(max_order):
        raise ValueError(f"buffer_depth ({buffer_depth}) must be >= max_order ({max_order})")
    planes = large_planes(rt_scene) if planes is None else planes
    link_src, link_tgt = np.nonzero(need)

    place_devices(rt_scene)
    mi_scene = rt_scene.mi_scene
    src_mi, tgt_mi = points(src), points(tgt)
    out = {"src": [], "tgt": [], "a": [], "tau": [], "k_tx": [], "k_rx": []}
    ptr = shape_pointers(mi_scene).astype(np.uint32)

    def solve(li, ch):  # one call: bounded Dr.Jit temporaries
        # no interaction (-1) after the chain, up to the buffer's depth
        chb = ch if ch.shape[1] >= depth else np.pad(ch, ((0, 0), (0, depth - ch.shape[1])), constant_values=-1)
        _solve_chains(rt_scene, ptr, planes, link_src[li], link_tgt[li], chb, src_mi, tgt_mi, n, m, out)

    # the pre-test's blocks solved as they come, in calls of exactly _CANDIDATES_PER_CALL
    # candidates (the last call the rest): the calls of solving all candidates joined, in
    # memory bounded by one call's candidates and the pre-test's pending blocks
    held: list[tuple[np.ndarray, np.ndarray]] = []
    n_held = 0
    for li_b, ch_b in iter_candidate_chains(planes, src, tgt, link_src, link_tgt, 1, int(max_order)):
        if len(li_b) == 0:
            continue
        held.append((li_b, ch_b))
        n_held += len(li_b)
        while n_held >= _CANDIDATES_PER_CALL:
            li_h = np.concatenate([h[0] for h in held])
            ch_h = np.concatenate([h[1] for h in held])
            solve(li_h[:_CANDIDATES_PER_CALL], ch_h[:_CANDIDATES_PER_CALL])
            held = [(li_h[_CANDIDATES_PER_CALL:], ch_h[_CANDIDATES_PER_CALL:])]
            n_held -= _CANDIDATES_PER_CALL
    if n_held:
        solve(np.concatenate([h[0] for h in held]), np.concatenate([h[1] for h in held]))
    if los:
        per = max(1, _LOS_PAIRS_PER_CALL // max(1, m))
        for s0 in range(0, n, per):  # groups of sources, every target
            grp = src[s0:s0 + per]
            g_mi = points(grp)
            part = {k: [] for k in out}
            line_of_sight_candidates(rt_scene, g_mi, tgt_mi, len(grp), m, part)
            part["src"] = [x + s0 for x in part["src"]]
            for k in out:
                out[k].extend(part[k])
    clear_devices(rt_scene)
    return to_source_paths(out, src, tgt, need)


def _solve_chains(rt_scene, ptr, planes, link_src, link_tgt, ch, src_mi, tgt_mi, n, m, out) -> None:
    """Sionna's image method and field calculator on candidate chains ``ch`` (c, depth;
    -1 pads) of links (``link_src``, ``link_tgt``); valid paths appended to ``out``.

    In two kernels: the image method alone over every candidate, for its validity, then
    the image method and field calculator over the valid ones. Most pre-tested chains are
    not paths (occluded, or their reflection point off the plane's triangles), and one
    fused kernel computed their fields too (docs/physics.md, "One computation, one
    kernel"). The paths are those of the fused kernel to float32 rounding: the same rays
    traced in another batch.
    """
    valid = image_method(rt_scene.mi_scene, _chain_buffer(ptr, planes, link_src, link_tgt, ch),
                         diffraction=False, diffraction_lit_region=True, src_positions=src_mi,
                         tgt_positions=tgt_mi).valid.numpy().astype(bool)
    if not valid.any():
        return
    buf = _chain_buffer(ptr, planes, link_src[valid], link_tgt[valid], ch[valid])
    collect_paths(solve_paths(rt_scene, buf, src_mi, tgt_mi, n, m), out)


def _chain_buffer(ptr, planes, link_src, link_tgt, ch):
    """A paths buffer of the chains ``ch`` (c, depth; -1 pads) over ``planes``
    (:func:`propagation.sionna_internals.specular_chain_buffer`)."""
    on = ch >= 0
    p = np.where(on, ch, 0)
    # per axis, in float32 (Sionna's precision) before the gather: a third of the memory
    # traffic of gathering (c, depth, 3) float64 points, the same values
    f32 = np.float32
    point32_m = planes.point_m.astype(f32)
    return specular_chain_buffer(on, ptr[planes.shape[p]], planes.primitive[p],
                                 tuple(np.where(on, point32_m[:, i][p], f32(0.0)) for i in range(3)),
                                 link_src, link_tgt)


def merge_paths(a: SourcePaths, b: SourcePaths, length_tol_m: float = 1e-4,
                direction_tol: float = 1e-4, transfer_rtol: float | None = None) -> SourcePaths:
    """The paths of ``a`` plus those of ``b`` that ``a`` does not already hold.

    A path of ``b`` is dropped when a path of ``a`` (or an earlier one of ``b``) to the
    same tag has a length within ``length_tol_m`` and departure and arrival directions
    within ``direction_tol`` per component (``sionna_paths.path_copies``' test, without its
    transfer-matrix check). Tolerances, not rounding to a grid: the same path
    solved from two candidates differs by float32 noise (~1e-6 m at 20 m), which a
    0.1 mm grid line splits ~2 % of the time. The paths of ``a`` are all kept: Sionna's
    traces hold distinct paths with equal length and departure (a wave bouncing inside
    one wall slab, then reflecting off the opposite wall, and the same in the other
    order), whereas a pure specular-reflection path of ``b`` never equals another path in
    both length and departure direction.

    Parameters
    ----------
    a, b : SourcePaths
        Paths from the same antenna position (``source_m`` equal); ``a`` typically a
        ``PathSolver`` trace, ``b`` a :func:`complete_specular` completion.
    length_tol_m : float
        Path length tolerance, metres.
    direction_tol : float
        Departure direction tolerance (unit-vector components).
    transfer_rtol : float, optional
        Also require the transfer matrices to agree within this fraction of the larger
        one's largest entry (:func:`~propagation.sionna_paths.path_copies`), as the copies
        of one trace are tested (1e-3): for ``b`` a second shoot-and-bounce trace, whose
        paths can be distinct ones of equal length and directions. None: not compared.

    Returns
    -------
    SourcePaths
        Tags of ``a``, then the tags of ``b`` not in ``a``; per tag the paths sorted by
        delay.
    """
    if not np.array_equal(np.asarray(a.source_m, float), np.asarray(b.source_m, float)):
        raise ValueError("merge_paths needs path sets from the same antenna position")
    where_b = a.index_of(b.tag_positions_m)
    new = np.flatnonzero(where_b < 0)
    where_b[new] = len(a.tag_positions_m) + np.arange(len(new))
    tags = np.concatenate([a.tag_positions_m, b.tag_positions_m[new]]).reshape(-1, 3)
    tag = np.concatenate([np.repeat(np.arange(len(a.tag_positions_m)), np.diff(a.offsets)),
                          np.repeat(where_b, np.diff(b.offsets))]).astype(np.int64)
    from_b = np.concatenate([np.zeros(len(a.tau_s), bool), np.ones(len(b.tau_s), bool)])
    tau = np.concatenate([a.tau_s, b.tau_s])
    k_tx = np.concatenate([a.k_tx, b.k_tx]).reshape(-1, 3)
    k_rx = np.concatenate([a.k_rx, b.k_rx]).reshape(-1, 3)
    tr = np.concatenate([a.transfer, b.transfer]).reshape(-1, 2, 2)
    order = np.lexsort((from_b, tau, tag))
    tag, from_b, tau, k_tx, k_rx, tr = tag[order], from_b[order], tau[order], k_tx[order], k_rx[order], tr[order]
    drop = path_copies(np.zeros(len(tau), np.int64), tag, tau * SPEED_OF_LIGHT, k_tx, k_rx, tr,
                   droppable=from_b, length_tol_m=length_tol_m, direction_tol=direction_tol,
                   transfer_rtol=transfer_rtol)
    keep = ~drop
    tag, tau, k_tx, k_rx, tr = tag[keep], tau[keep], k_tx[keep], k_rx[keep], tr[keep]
    counts = np.bincount(tag, minlength=len(tags))
    return SourcePaths(np.asarray(a.source_m, float).copy(), tags,
                       np.concatenate([[0], np.cumsum(counts)]).astype(np.int64), tr, tau, k_tx, k_rx)
