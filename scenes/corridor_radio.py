"""Radio surfaces of a generated corridor: each physical layer once (see :mod:`scenes.radio`).

The generator (:mod:`scenes.generator`) cuts the plane into cells on a compressed grid;
wall cells carry a vertical profile of ``(z0, z1, (material, construction))`` intervals
(``None`` gaps are door openings). Here every side of a wall cell that faces free space
is an *inner face* and every side that faces the outside of the building an *outer
face*; per profile interval:

- ``"solid"``: one surface on the inner face, ``wall_thickness_m`` thick;
- ``"single"``: one leaf on the inner face, the material's library thickness;
- ``"stud"`` / ``"double"``: a leaf of the library thickness on the inner *and* the outer
  face (corner cells, which have only outer faces, close the outer leaf).

Pieces on the same plane with the same height interval, material and thickness that
touch along the wall are merged into one rectangle: a wall without openings is one
surface, a door leaves a lintel piece above it. Door reveals (the wall's sides at an
opening) get no surface. Floor and ceiling are one surface each at z = 0 and z = height.
"""

from __future__ import annotations

import numpy as np

from scenes.geometry import merge_meshes
from scenes.materials import get_material, resolve_material_name
from scenes.radio import RadioSurface, default_construction, rectangle_mesh

__all__ = ["construction_of", "slab_surface", "wall_surfaces"]

_EPS = 1e-9
_SIDES = ((-1, 0), (1, 0), (0, -1), (0, 1))


def construction_of(corridor, material: str, explicit: str | None = None) -> str:
    """Construction of a wall piece of ``material`` in a generated corridor.

    Parameters
    ----------
    corridor : scenes.spec.CorridorSpec
        Its ``wall_construction`` (for the ``wall_material``) and ``material_construction``.
    material : str
        Library name of the piece's material.
    explicit : str, optional
        A panel's own ``construction``: wins when given.

    Returns
    -------
    str
        One of :data:`scenes.radio.CONSTRUCTIONS`: the explicit choice, else the
        corridor's ``wall_construction`` for its wall material, else its
        ``material_construction``, else the material default (plasterboard ``"stud"``).
    """
    if explicit is not None:
        return explicit
    if material == resolve_material_name(corridor.wall_material) and corridor.wall_construction is not None:
        return corridor.wall_construction
    return corridor.material_construction.get(material, default_construction(material))


def _layers(construction: str, inner: bool, material: str, wall_thickness_m: float):
    """(thickness_m, kind) of the surfaces a cell side carries for one profile interval."""
    if construction in ("stud", "double"):
        return [(get_material(material).thickness_m, "leaf")]
    if not inner:
        return []
    if construction == "single":
        return [(get_material(material).thickness_m, "leaf")]
    return [(wall_thickness_m, "wall")]


def wall_surfaces(xs, ys, free, grown, keys, wall_thickness_m: float) -> list[RadioSurface]:
    """Wall surfaces of a generated corridor, merged along each wall.

    Parameters
    ----------
    xs, ys : numpy.ndarray
        Cell edges, shapes (nx + 1,) and (ny + 1,), metres.
    free, grown : numpy.ndarray
        Cells of free space and of the grown union (free space plus wall band),
        shape (nx, ny), bool.
    keys : numpy.ndarray
        Profile of each wall cell, shape (nx, ny), object: a tuple of
        ``(z0_m, z1_m, (material, construction))``.
    wall_thickness_m : float
        Thickness of ``"solid"`` pieces, metres.

    Returns
    -------
    list of RadioSurface
        Sorted by plane, then height interval, then material; normals point to the
        neighbouring cell (into free space on inner faces, outwards on outer ones).
    """
    nx, ny = free.shape
    pieces: dict[tuple, list[tuple[float, float]]] = {}
    for i, j in zip(*np.nonzero(grown & ~free), strict=True):
        for di, dj in _SIDES:
            ni, nj = i + di, j + dj
            in_grid = 0 <= ni < nx and 0 <= nj < ny
            inner = bool(in_grid and free[ni, nj])
            if not inner and in_grid and grown[ni, nj]:
                continue  # a side between two wall cells
            if di:
                axis, coord, span = 0, float(xs[i + (di > 0)]), (float(ys[j]), float(ys[j + 1]))
            else:
                axis, coord, span = 1, float(ys[j + (dj > 0)]), (float(xs[i]), float(xs[i + 1]))
            for z0, z1, (mat, cons) in keys[i, j]:
                for t, kind in _layers(cons, inner, mat, wall_thickness_m):
                    key = (axis, round(coord, 9), di + dj, float(z0), float(z1), mat, float(t), kind)
                    pieces.setdefault(key, []).append(span)
    out = []
    for key in sorted(pieces):
        axis, coord, sign, z0, z1, mat, t, kind = key
        spans = sorted(pieces[key])
        merged = [list(spans[0])]
        for a0, a1 in spans[1:]:
            if a0 <= merged[-1][1] + _EPS:
                merged[-1][1] = max(merged[-1][1], a1)
            else:
                merged.append([a0, a1])
        for a0, a1 in merged:
            lo, hi = np.array([0.0, 0.0, z0]), np.array([0.0, 0.0, z1])
            lo[axis] = hi[axis] = coord
            lo[1 - axis], hi[1 - axis] = a0, a1
            normal = np.zeros(3)
            normal[axis] = sign
            out.append(RadioSurface(mat, t, rectangle_mesh(lo, hi, normal), kind))
    return out


def slab_surface(rects_m, z_m: float, up: bool, material: str, thickness_m: float,
                 kind: str) -> RadioSurface:
    """One horizontal surface over rectangles (a floor or a ceiling).

    Parameters
    ----------
    rects_m : sequence of (x0, y0, x1, y1)
        Footprint rectangles, metres.
    z_m : float
        Height of the surface, metres.
    up : bool
        Normal +z (a floor seen from above) or -z (a ceiling seen from below).
    material : str
        Library material.
    thickness_m : float
        Slab thickness, metres.
    kind : str
        ``"floor"`` or ``"ceiling"``.
    """
    normal = (0.0, 0.0, 1.0 if up else -1.0)
    meshes = [rectangle_mesh([x0, y0, z_m], [x1, y1, z_m], normal) for x0, y0, x1, y1 in rects_m]
    return RadioSurface(material, thickness_m, merge_meshes(meshes), kind)
