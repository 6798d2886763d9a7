"""Radio geometry of imported meshes: as they are, declared single surfaces, or thin boxes.

An imported mesh says nothing about how its surfaces relate to physical layers. Three
treatments (``radio_geometry=`` of :func:`scenes.import_mesh` and
:func:`scenes.load_mitsuba_xml`, see ``docs/radio_geometry.md``):

``"as_is"``
    No radio surfaces: every face is traced with the library thickness of its material.
    A wall modelled as a closed box is crossed twice (two slabs).
``"single"``
    The file already holds one surface per physical layer: each part is traced as it is,
    with the thickness of its material (the ``thickness`` of its Mitsuba radio material
    when the XML gives one, else the library's).
``"thin_boxes"``
    Closed axis-aligned boxes whose smallest extent is below ``thin_box_max_m`` become
    one rectangle on a chosen face, carrying that extent as thickness; everything else
    (rotated boxes, furniture, open surfaces, any other shape) stays as in ``"single"``.
"""

from __future__ import annotations

import numpy as np
import trimesh
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components

from scenes.geometry import _is_closed, _signed_volume
from scenes.materials import get_material
from scenes.radio import (
    RADIO_GEOMETRIES,
    THIN_BOX_FACES,
    RadioSurface,
    check_choice,
    rectangle_mesh,
)

__all__ = ["imported_radio_surfaces", "split_thin_boxes"]


def _face_components(vertices: np.ndarray, faces: np.ndarray) -> list[np.ndarray]:
    """Face index arrays of the closed-shell candidates of a triangle soup.

    Vertices are merged by position (1e-9 m); two faces are linked across an edge only
    when exactly two faces use that edge, so boxes sharing an edge or a corner after
    vertex merging (slabs meeting at a room's corner) stay separate components.
    """
    _, inv = np.unique(np.round(vertices, 9), axis=0, return_inverse=True)
    f = inv.reshape(-1)[faces]
    edges = np.sort(np.concatenate([f[:, [0, 1]], f[:, [1, 2]], f[:, [2, 0]]]), axis=1)
    owner = np.tile(np.arange(len(f)), 3)
    _, eid, counts = np.unique(edges, axis=0, return_inverse=True, return_counts=True)
    eid = eid.reshape(-1)
    manifold = counts[eid] == 2
    order = np.argsort(eid[manifold], kind="stable")
    pairs = owner[manifold][order].reshape(-1, 2)
    graph = coo_matrix((np.ones(len(pairs)), (pairs[:, 0], pairs[:, 1])), shape=(len(f), len(f)))
    n, labels = connected_components(graph, directed=False)
    return [np.flatnonzero(labels == k) for k in range(n)]


def _box_bounds(vertices: np.ndarray, faces: np.ndarray) -> np.ndarray | None:
    """Bounds (2, 3) if the faces form a closed axis-aligned box, else ``None``."""
    _, inv = np.unique(np.round(vertices, 9), axis=0, return_inverse=True)
    if not _is_closed(inv.reshape(-1)[faces]):
        return None
    v = vertices[np.unique(faces)]
    lo, hi = v.min(0), v.max(0)
    if np.any(hi - lo <= 1e-9):
        return None
    corner = np.all(np.isclose(v, lo, rtol=0, atol=1e-9) | np.isclose(v, hi, rtol=0, atol=1e-9), axis=1)
    vol = abs(_signed_volume(vertices[faces]))
    box_vol = float(np.prod(hi - lo))
    if not (np.all(corner) and abs(vol - box_vol) <= 1e-6 * box_vol):
        return None
    return np.stack([lo, hi])


def split_thin_boxes(mesh: trimesh.Trimesh, thin_box_max_m: float, face: str, centre_m):
    """Replace the thin closed axis-aligned boxes of ``mesh`` by one rectangle each.

    Parameters
    ----------
    mesh : trimesh.Trimesh
        One imported part (any triangles).
    thin_box_max_m : float
        A closed axis-aligned box whose smallest extent is below this is converted, m.
    face : {"inner", "lower", "upper", "mid"}
        Where the rectangle goes (see :data:`scenes.radio.THIN_BOX_FACES`).
    centre_m : array_like, shape (3,)
        Reference point of ``"inner"`` (the centre of the scene's bounds), metres.

    Returns
    -------
    (rectangles, rest) : list of (trimesh.Trimesh, float), trimesh.Trimesh or None
        Each converted box as a rectangle and its thickness (the smallest extent, m);
        the faces left as they are (``None`` if none).
    """
    check_choice(face, THIN_BOX_FACES, "thin_box_face")
    verts = np.asarray(mesh.vertices, float)
    faces = np.asarray(mesh.faces, np.int64)
    centre = np.asarray(centre_m, float)
    rects, keep = [], np.ones(len(faces), bool)
    for comp in _face_components(verts, faces):
        bounds = _box_bounds(verts, faces[comp])
        if bounds is None:
            continue
        lo, hi = bounds
        k = int(np.argmin(hi - lo))
        t = float(hi[k] - lo[k])
        if t >= thin_box_max_m:
            continue
        if face == "inner":
            upper = abs(hi[k] - centre[k]) <= abs(lo[k] - centre[k])
            coord = hi[k] if upper else lo[k]
            sign = 1.0 if upper else -1.0
        elif face == "mid":
            coord, sign = (lo[k] + hi[k]) / 2, 1.0
        else:
            coord, sign = (hi[k], 1.0) if face == "upper" else (lo[k], -1.0)
        a, b = lo.copy(), hi.copy()
        a[k] = b[k] = coord
        n = np.zeros(3)
        n[k] = sign
        rects.append((rectangle_mesh(a, b, n), t))
        keep[comp] = False
    rest = None
    if np.any(keep):
        used, new = np.unique(faces[keep], return_inverse=True)
        rest = trimesh.Trimesh(verts[used], new.reshape(-1, 3), process=False)
    return rects, rest


def imported_radio_surfaces(parts, radio_geometry: str = "as_is", thin_box_max_m: float = 0.3,
                            thin_box_face: str = "inner"):
    """Radio surfaces of imported parts (``None`` for ``"as_is"``).

    Parameters
    ----------
    parts : sequence of (str, float or None, trimesh.Trimesh)
        Material, thickness (``None``: the library's) and mesh of each imported part.
    radio_geometry : {"as_is", "single", "thin_boxes"}
        See the module docstring.
    thin_box_max_m : float
        Threshold of ``"thin_boxes"``, metres.
    thin_box_face : {"inner", "lower", "upper", "mid"}
        Face of ``"thin_boxes"``.

    Returns
    -------
    tuple of RadioSurface or None
    """
    check_choice(radio_geometry, RADIO_GEOMETRIES, "radio_geometry")
    if radio_geometry == "as_is":
        return None
    if not thin_box_max_m > 0:
        raise ValueError(f"thin_box_max_m must be positive, got {thin_box_max_m!r}")
    out: list[RadioSurface] = []
    meshes = [m for _, _, m in parts if len(m.faces)]
    lo = np.min([m.bounds[0] for m in meshes], axis=0)
    hi = np.max([m.bounds[1] for m in meshes], axis=0)
    for mat, thickness, mesh in parts:
        if len(mesh.faces) == 0:
            continue
        t = thickness if thickness is not None else get_material(mat).thickness_m
        if radio_geometry == "single":
            out.append(RadioSurface(mat, t, mesh, "imported"))
            continue
        rects, rest = split_thin_boxes(mesh, thin_box_max_m, thin_box_face, (lo + hi) / 2)
        out += [RadioSurface(mat, tr, r, "wall") for r, tr in rects]
        if rest is not None:
            out.append(RadioSurface(mat, t, rest, "imported"))
    return tuple(out)
