"""Geometric queries on a :class:`~scenes.scene.Scene`: solids, free space, sections, rays.

Everything here is plain NumPy (plus SciPy's sparse connected components): no ray
accelerator (embree, rtree) is needed, so the queries run wherever trimesh imports.
Scenes hold few triangles (boxes, not fine tessellation), which keeps brute-force
ray/triangle tests cheap.

Solids
    A connected component of a material mesh whose directed edges cancel (every edge
    ``u -> v`` is matched by a ``v -> u``) is a closed surface; its generalised winding
    number (Jacobson et al. 2013, "Robust inside-outside segmentation using generalized
    winding numbers") is 1 inside and 0 outside. Summed over overlapping or touching
    closed boxes it counts how many contain a point, so ``w >= 0.5`` means "inside some
    solid" whether or not coincident vertices were merged on import. Open surfaces
    (a lone ground plane) are not solids and never contain a point. Components that are
    exact axis-aligned boxes are tested by their bounds, which is exact and fast.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import trimesh
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components

__all__ = [
    "Solid",
    "SurfaceQuery",
    "box_mesh",
    "merge_meshes",
    "solids",
    "inside_solid",
    "in_free_space",
    "points_in_boxes",
    "solid_material_at",
    "is_free",
    "floor_plan_segments",
    "raycast",
    "closest_surface",
]

_CHUNK = 2_000_000  # point-triangle pairs per vectorised block (~100 MB of temporaries)


@dataclass(frozen=True)
class Solid:
    """One closed body of a scene.

    Attributes
    ----------
    material : str
        Library name of the material it is made of.
    bounds_m : numpy.ndarray
        Axis-aligned bounds, shape (2, 3), float64, metres.
    triangles_m : numpy.ndarray
        Its triangles, shape (n_triangles, 3, 3), float64, metres (outward oriented).
    is_box : bool
        True when the body equals its bounds (containment is then a bounds test).
    """

    material: str
    bounds_m: np.ndarray
    triangles_m: np.ndarray
    is_box: bool


@dataclass(frozen=True)
class SurfaceQuery:
    """Nearest scene surface to each query point.

    Attributes
    ----------
    distance_m : numpy.ndarray
        Distance to the nearest triangle, shape (n,), float64, metres.
    point_m : numpy.ndarray
        Nearest point on that triangle, shape (n, 3), float64, metres.
    normal : numpy.ndarray
        Unit face normal of that triangle, shape (n, 3), float64.
    material : numpy.ndarray
        Material of that triangle, shape (n,), str.
    """

    distance_m: np.ndarray
    point_m: np.ndarray
    normal: np.ndarray
    material: np.ndarray


def box_mesh(lo, hi, yaw_rad: float = 0.0) -> trimesh.Trimesh:
    """A closed box (12 triangles, outward normals) spanning ``lo``..``hi``.

    Parameters
    ----------
    lo, hi : array_like
        Opposite corners, shape (3,), metres, before rotation.
    yaw_rad : float
        Rotation about the vertical axis through the box centre, rad.
    """
    lo = np.asarray(lo, dtype=float)
    hi = np.asarray(hi, dtype=float)
    transform = trimesh.transformations.rotation_matrix(yaw_rad, [0, 0, 1])
    transform[:3, 3] = (lo + hi) / 2
    return trimesh.creation.box(extents=hi - lo, transform=transform)


def merge_meshes(meshes: list[trimesh.Trimesh]) -> trimesh.Trimesh:
    """Concatenate meshes without merging vertices (each part stays its own component)."""
    verts, faces, offset = [], [], 0
    for m in meshes:
        verts.append(np.asarray(m.vertices, dtype=float))
        faces.append(np.asarray(m.faces, dtype=np.int64) + offset)
        offset += len(m.vertices)
    return trimesh.Trimesh(np.vstack(verts), np.vstack(faces), process=False)


def _components(mesh: trimesh.Trimesh) -> list[np.ndarray]:
    faces = np.asarray(mesh.faces, dtype=np.int64)
    nv = len(mesh.vertices)
    rows = np.concatenate([faces[:, 0], faces[:, 1]])
    cols = np.concatenate([faces[:, 1], faces[:, 2]])
    graph = coo_matrix((np.ones(len(rows)), (rows, cols)), shape=(nv, nv))
    _, labels = connected_components(graph, directed=False)
    face_label = labels[faces[:, 0]]
    order = np.argsort(face_label, kind="stable")
    splits = np.flatnonzero(np.diff(face_label[order])) + 1
    return np.split(order, splits)


def _is_closed(faces: np.ndarray) -> bool:
    edges = np.concatenate([faces[:, [0, 1]], faces[:, [1, 2]], faces[:, [2, 0]]])
    fwd = edges[:, 0] * (edges.max() + 1) + edges[:, 1]
    rev = edges[:, 1] * (edges.max() + 1) + edges[:, 0]
    u_f, c_f = np.unique(fwd, return_counts=True)
    u_r, c_r = np.unique(rev, return_counts=True)
    return bool(np.array_equal(u_f, u_r) and np.array_equal(c_f, c_r))


def _signed_volume(tris: np.ndarray) -> float:
    return float(np.einsum("ij,ij->i", tris[:, 0], np.cross(tris[:, 1], tris[:, 2])).sum() / 6)


_SOLIDS_CACHE: dict[str, list[Solid]] = {}


def solids(scene) -> list[Solid]:
    """Closed bodies of ``scene`` (cached by :meth:`Scene.content_hash`)."""
    key = scene.content_hash()
    if key in _SOLIDS_CACHE:
        return _SOLIDS_CACHE[key]
    out: list[Solid] = []
    for name in scene.materials:
        mesh = scene.meshes[name]
        if len(mesh.faces) == 0:
            continue
        verts = np.asarray(mesh.vertices, dtype=float)
        faces = np.asarray(mesh.faces, dtype=np.int64)
        for idx in _components(mesh):
            f = faces[idx]
            if not _is_closed(f):
                continue
            tris = verts[f]
            vol = _signed_volume(tris)
            if vol < 0:  # inward oriented: flip so the winding number is +1 inside
                tris = tris[:, ::-1]
                vol = -vol
            if vol <= 0:
                continue
            lo, hi = tris.reshape(-1, 3).min(0), tris.reshape(-1, 3).max(0)
            box_vol = float(np.prod(hi - lo))
            v = tris.reshape(-1, 3)
            corner = np.all(np.isclose(v, lo, atol=1e-9) | np.isclose(v, hi, atol=1e-9), axis=1)
            is_box = bool(np.all(corner) and abs(vol - box_vol) <= 1e-9 * max(box_vol, 1.0))
            out.append(Solid(name, np.stack([lo, hi]), tris, is_box))
    if len(_SOLIDS_CACHE) > 16:
        _SOLIDS_CACHE.clear()
    _SOLIDS_CACHE[key] = out
    return out


def _winding_number(points: np.ndarray, tris: np.ndarray) -> np.ndarray:
    """Generalised winding number of a closed triangle soup at ``points`` (n,).

    Van Oosterom & Strackee (1983) solid angle per triangle, summed and divided by 4 pi.
    """
    out = np.zeros(len(points))
    step = max(1, _CHUNK // max(len(tris), 1))
    for s in range(0, len(points), step):
        p = points[s:s + step, None, :]
        a, b, c = tris[None, :, 0] - p, tris[None, :, 1] - p, tris[None, :, 2] - p
        la, lb, lc = (np.linalg.norm(v, axis=-1) for v in (a, b, c))
        det = np.einsum("...i,...i->...", a, np.cross(b, c))
        den = (la * lb * lc + np.einsum("...i,...i->...", a, b) * lc
               + np.einsum("...i,...i->...", a, c) * lb + np.einsum("...i,...i->...", b, c) * la)
        out[s:s + step] = np.arctan2(det, den).sum(axis=1) / (2 * np.pi)
    return out


def inside_solid(scene, points) -> np.ndarray:
    """Whether each point lies strictly inside some closed body of the scene.

    Parameters
    ----------
    scene : scenes.Scene
    points : array_like, shape (n, 3), metres

    Returns
    -------
    numpy.ndarray, shape (n,), bool
        Points on a surface count as outside (a tag or the laser may touch a wall).
    """
    return solid_material_at(scene, points) != ""


def solid_material_at(scene, points) -> np.ndarray:
    """Material of the solid containing each point, ``""`` where none does; shape (n,), str."""
    pts = np.asarray(points, dtype=float).reshape(-1, 3)
    which = np.full(len(pts), "", dtype=object)
    for solid in solids(scene):
        lo, hi = solid.bounds_m
        cand = np.all((pts > lo + 1e-9) & (pts < hi - 1e-9), axis=1) & (which == "")
        if not np.any(cand):
            continue
        if solid.is_box:
            which[cand] = solid.material
            continue
        idx = np.flatnonzero(cand)
        w = _winding_number(pts[idx], solid.triangles_m)
        which[idx[w >= 0.5]] = solid.material
    return which.astype(str)


def in_free_space(scene, points) -> np.ndarray:
    """Whether each point lies in the scene's free (walkable) volume, ignoring solids.

    The free volume is ``scene.free_space_m`` (union of axis-aligned boxes) when the
    scene has one, else the scene's bounding box. Shape (n,), bool.
    """
    pts = np.asarray(points, dtype=float).reshape(-1, 3)
    boxes = getattr(scene, "free_space_m", None)
    if boxes is None or len(boxes) == 0:
        boxes = scene.bounds_m[None]
    return points_in_boxes(pts, boxes)


def points_in_boxes(points, boxes) -> np.ndarray:
    """Whether each point lies in (or on) any of the axis-aligned boxes.

    Parameters
    ----------
    points : array_like, shape (n, 3)
    boxes : array_like, shape (k, 2, 3): [min xyz, max xyz] per box

    Returns
    -------
    numpy.ndarray, shape (n,), bool
    """
    pts = np.asarray(points, dtype=float).reshape(-1, 3)
    boxes = np.asarray(boxes, dtype=float).reshape(-1, 2, 3)
    lo, hi = boxes[:, 0], boxes[:, 1]
    inside = np.all((pts[:, None, :] >= lo[None] - 1e-9) & (pts[:, None, :] <= hi[None] + 1e-9), axis=2)
    return np.any(inside, axis=1)


def is_free(scene, points) -> np.ndarray:
    """Whether each point is in free space: inside the walkable volume, outside every solid.

    Parameters
    ----------
    scene : scenes.Scene
    points : array_like, shape (n, 3), float, metres (world frame, z up)

    Returns
    -------
    numpy.ndarray, shape (n,), bool
    """
    pts = np.asarray(points, dtype=float).reshape(-1, 3)
    free = in_free_space(scene, pts)
    if np.any(free):
        free[free] = ~inside_solid(scene, pts[free])
    return free


def floor_plan_segments(scene, z_m: float) -> np.ndarray:
    """2-D wall segments: every mesh cut by the horizontal plane at height ``z_m``.

    Parameters
    ----------
    scene : scenes.Scene
    z_m : float
        Height of the cutting plane, metres (e.g. the laser height).

    Returns
    -------
    numpy.ndarray, shape (k, 2, 2), float64
        Segment end points (x, y) in metres; each closed box contributes the outline of
        its cross-section.
    """
    segs = []
    for name in scene.materials:
        mesh = scene.meshes[name]
        lo, hi = mesh.bounds
        if not (lo[2] < z_m < hi[2]):
            continue
        s = trimesh.intersections.mesh_plane(mesh, [0.0, 0.0, 1.0], [0.0, 0.0, float(z_m)])
        if len(s):
            segs.append(np.asarray(s, dtype=float)[:, :, :2])
    if not segs:
        return np.zeros((0, 2, 2))
    out = np.concatenate(segs)
    keep = np.linalg.norm(out[:, 1] - out[:, 0], axis=1) > 1e-12
    return out[keep]


def in_triangles_2d(points, triangles) -> np.ndarray:
    """Which 2-D points lie in at least one of the 2-D triangles (barycentric test).

    Parameters
    ----------
    points : array_like, shape (p, 2)
    triangles : array_like, shape (k, 3, 2)
        Degenerate triangles (zero area) contain nothing.

    Returns
    -------
    numpy.ndarray, shape (p,), bool
        Edges and vertices count as inside (1e-9 slack in barycentric coordinates).
    """
    c = np.asarray(points, dtype=float).reshape(-1, 2)
    uv = np.asarray(triangles, dtype=float).reshape(-1, 3, 2)
    a, b, d = uv[:, 0], uv[:, 1], uv[:, 2]
    det = (b[:, 0] - a[:, 0]) * (d[:, 1] - a[:, 1]) - (d[:, 0] - a[:, 0]) * (b[:, 1] - a[:, 1])
    ok = np.abs(det) > 1e-12
    det = np.where(ok, det, 1.0)
    px, py = c[:, None, 0] - a[None, :, 0], c[:, None, 1] - a[None, :, 1]
    l1 = (px * (d[:, 1] - a[:, 1]) - py * (d[:, 0] - a[:, 0])) / det
    l2 = (py * (b[:, 0] - a[:, 0]) - px * (b[:, 1] - a[:, 1])) / det
    return (ok & (l1 >= -1e-9) & (l2 >= -1e-9) & (l1 + l2 <= 1 + 1e-9)).any(axis=1)


def _scene_triangles(scene) -> tuple[np.ndarray, np.ndarray]:
    tris, mats = [], []
    for name in scene.materials:
        t = np.asarray(scene.meshes[name].triangles, dtype=float)
        tris.append(t)
        mats.append(np.full(len(t), name, dtype=object))
    return np.concatenate(tris), np.concatenate(mats).astype(str)


def raycast(scene, origins, directions, max_range_m: float = np.inf) -> np.ndarray:
    """Distance along each ray to the first triangle hit (Moeller & Trumbore 1997).

    Parameters
    ----------
    scene : scenes.Scene
    origins : array_like, shape (n, 3), metres
    directions : array_like, shape (n, 3)
        Need not be normalised; distances are in metres along the unit direction.
    max_range_m : float or array_like, shape (n,)
        Hits beyond this are ignored; one per ray, or one for all. Triangles are pruned by
        the box of each chunk's ray segments, so a per-ray range (and rays in spatial
        order) prunes more, with the same hits.

    Returns
    -------
    numpy.ndarray, shape (n,), float64
        Hit distance in metres, ``inf`` where nothing is hit within ``max_range_m``.
    """
    o = np.asarray(origins, dtype=float).reshape(-1, 3)
    d = np.asarray(directions, dtype=float).reshape(-1, 3)
    d = d / np.linalg.norm(d, axis=1, keepdims=True)
    tris, _ = _scene_triangles(scene)
    v0_all, e1_all, e2_all = tris[:, 0], tris[:, 1] - tris[:, 0], tris[:, 2] - tris[:, 0]
    t_lo, t_hi = tris.min(axis=1), tris.max(axis=1)
    rng_all = np.broadcast_to(np.asarray(max_range_m, dtype=float), (len(o),))
    out = np.full(len(o), np.inf)
    step = max(1, _CHUNK // max(len(tris), 1))
    for s in range(0, len(o), step):
        oo, dd = o[s:s + step, None, :], d[s:s + step, None, :]
        v0, e1, e2 = v0_all, e1_all, e2_all
        rng = rng_all[s:s + step]
        if np.all(np.isfinite(rng)):
            # only triangles whose box meets the box of the chunk's ray segments can be hit
            # within range (1 mm of slack): the same hits, exactly, at a fraction of the pairs
            ends = o[s:s + step] + rng[:, None] * d[s:s + step]
            lo = np.minimum(o[s:s + step].min(axis=0), ends.min(axis=0)) - 1e-3
            hi = np.maximum(o[s:s + step].max(axis=0), ends.max(axis=0)) + 1e-3
            near = np.flatnonzero(np.all((t_hi >= lo) & (t_lo <= hi), axis=1))
            if not len(near):
                continue
            v0, e1, e2 = v0_all[near], e1_all[near], e2_all[near]
        p = np.cross(dd, e2[None])
        det = np.einsum("...i,...i->...", e1[None], p)
        ok = np.abs(det) > 1e-12
        inv = np.where(ok, 1.0 / np.where(ok, det, 1.0), 0.0)
        tvec = oo - v0[None]
        u = np.einsum("...i,...i->...", tvec, p) * inv
        q = np.cross(tvec, e1[None])
        v = np.einsum("...i,...i->...", dd, q) * inv
        t = np.einsum("...i,...i->...", e2[None], q) * inv
        hit = ok & (u >= 0) & (v >= 0) & (u + v <= 1) & (t > 1e-9) & (t <= rng[:, None])
        t = np.where(hit, t, np.inf)
        out[s:s + step] = t.min(axis=1)
    return out


def closest_surface(scene, points) -> SurfaceQuery:
    """Nearest triangle of the scene to each point (brute force, chunked).

    Parameters
    ----------
    scene : scenes.Scene
    points : array_like, shape (n, 3), metres

    Returns
    -------
    SurfaceQuery
    """
    pts = np.asarray(points, dtype=float).reshape(-1, 3)
    tris, mats = _scene_triangles(scene)
    normals = np.cross(tris[:, 1] - tris[:, 0], tris[:, 2] - tris[:, 0])
    nn = np.linalg.norm(normals, axis=1, keepdims=True)
    normals = normals / np.where(nn > 0, nn, 1.0)
    dist = np.empty(len(pts))
    near = np.empty((len(pts), 3))
    which = np.empty(len(pts), dtype=np.int64)
    for i, p in enumerate(pts):  # n is small (tags); each step is vectorised over triangles
        cp = trimesh.triangles.closest_point(tris, np.broadcast_to(p, (len(tris), 3)))
        dd = np.linalg.norm(cp - p, axis=1)
        j = int(np.argmin(dd))
        dist[i], near[i], which[i] = dd[j], cp[j], j
    return SurfaceQuery(dist, near, normals[which], mats[which])
