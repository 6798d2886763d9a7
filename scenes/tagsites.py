"""Where tags can sit: candidate tag sites on a scene's vertical surfaces.

Passive UHF tags are stuck on walls, doors, boxes and cabinets, facing into the room.
:func:`tag_sites` lays a regular grid over every vertical face of the scene's solid
meshes whose outward normal points into free space, moves each grid point a few
millimetres along the normal (where a tag's centre is) and keeps the points that lie in
free space at tag heights. Each site records how much room is in front of it
(``clearance_m``): a site on a wall behind a cabinet has a centimetre, one on an open
wall has metres. These sites serve two purposes in a study:

- a held-out tag layout (:func:`draw_tags`): tags the training tour never read, at
  positions and heights of their own, drawn with their own random stream;
- the propagation truth where tags are: the learned sensor model is compared with the
  ray-traced truth at every site, behind cabinets included.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from scenes.geometry import in_triangles_2d, is_free, raycast
from scenes.scene import TagSet

__all__ = ["TagSites", "draw_tags", "tag_sites"]

#: Vertical faces: |n_z| below this (walls, box and cabinet sides; not floor, ceiling, tops).
_VERTICAL_NZ = 0.1


@dataclass(frozen=True)
class TagSites:
    """Candidate tag positions on a scene's surfaces.

    Attributes
    ----------
    positions_m : numpy.ndarray, shape (k, 3), float64
        Tag centres [m] (the surface point moved ``offset_m`` along the normal).
    normals : numpy.ndarray, shape (k, 3), float64
        Unit normal of the surface, pointing into free space (horizontal).
    material : numpy.ndarray, shape (k,), str
        Material of the surface the site is on.
    clearance_m : numpy.ndarray, shape (k,), float64
        Free distance in front of the site along its normal [m] (capped at the
        ``max_clearance_m`` of :func:`tag_sites`): small behind furniture.
    """

    positions_m: np.ndarray
    normals: np.ndarray
    material: np.ndarray
    clearance_m: np.ndarray

    def __len__(self) -> int:
        return len(self.positions_m)

    def subset(self, index) -> TagSites:
        """Sites selected by an integer or boolean index."""
        return TagSites(self.positions_m[index], self.normals[index], self.material[index],
                        self.clearance_m[index])


def _axis_points(lo: float, hi: float, spacing_m: float, between_m: float | None) -> np.ndarray:
    """Grid coordinates on one face axis [lo, hi]: cell centres ``spacing_m`` apart, the
    grid centred on the face (both ends keep the same margin); with ``between_m``, shifted
    by half a step off the centred grid of spacing ``between_m`` instead (every point
    ``spacing_m / 2 + k spacing_m`` from that grid's first point, kept >= half a step
    inside the face; an axis shorter than one step: one point a quarter of its extent off
    the centre)."""
    n = max(1, int(np.floor((hi - lo) / spacing_m)))
    if between_m is None:
        return lo + (hi - lo - (n - 1) * spacing_m) / 2 + spacing_m * np.arange(n)
    na = max(1, int(np.floor((hi - lo) / between_m)))
    a0 = lo + (hi - lo - (na - 1) * between_m) / 2  # the other grid's first point
    k = np.arange(int(np.floor((lo - a0) / spacing_m)) - 1,
                  int(np.ceil((hi - a0) / spacing_m)) + 2)
    p = a0 + spacing_m / 2 + spacing_m * k
    p = p[(p >= lo + spacing_m / 2 - 1e-9) & (p <= hi - spacing_m / 2 + 1e-9)]
    return p if len(p) else np.array([(lo + hi) / 2 + (hi - lo) / 4])


def _face_grid(tri: np.ndarray, normal: np.ndarray, spacing_m: float,
               between_m: float | None = None) -> np.ndarray:
    """Grid points (cell centres, ``spacing_m`` apart) on coplanar vertical triangles.

    ``tri`` (k, 3, 3) share the plane of unit horizontal ``normal``; returns (p, 3) points
    of the plane that fall inside one of the triangles. ``between_m``: the grid is laid
    half a step off the face's grid of that spacing (:func:`_axis_points`).
    """
    v_ax = np.array([0.0, 0.0, 1.0])
    u_ax = np.cross(v_ax, normal)
    u_ax /= np.linalg.norm(u_ax)
    o = tri[0, 0]
    uv = np.stack([(tri - o) @ u_ax, (tri - o) @ v_ax], axis=-1)  # (k, 3, 2)
    lo, hi = uv.reshape(-1, 2).min(0), uv.reshape(-1, 2).max(0)
    us = _axis_points(lo[0], hi[0], spacing_m, between_m)
    vs = _axis_points(lo[1], hi[1], spacing_m, between_m)
    cu, cv = np.meshgrid(us, vs, indexing="ij")
    c = np.stack([cu.ravel(), cv.ravel()], axis=1)
    c = c[in_triangles_2d(c, uv)]
    return o + c[:, :1] * u_ax + c[:, 1:] * v_ax


def tag_sites(scene, spacing_m: float = 0.25, z_range_m: tuple[float, float] | None = (0.2, 1.6),
              offset_m: float = 0.005, max_clearance_m: float = 2.0,
              between_m: float | None = None) -> TagSites:
    """Candidate tag sites on every vertical surface of ``scene`` that faces free space.

    Parameters
    ----------
    scene : scenes.Scene
        Its solid meshes (``scene.meshes``) are sampled; its own tags are ignored.
    spacing_m : float
        Grid spacing on each face [m].
    z_range_m : (float, float) or None
        Tag heights kept [m] (inclusive); None: every height of the faces, floor to top
        (where a user's unknown tag could be).
    offset_m : float
        Distance of the tag centre from the surface, along the normal [m].
    max_clearance_m : float
        Cap of the free distance measured in front of each site [m].
    between_m : float, optional
        Lay each face's grid half a step (``spacing_m / 2`` along both face axes) off the
        grid that ``tag_sites(scene, spacing_m=between_m)`` lays on it, instead of
        centring it on the face: when ``between_m`` is a whole multiple of ``spacing_m``
        no site of the one grid is a site of the other (each of the other's is half a
        cell diagonal from the nearest of these).

    Returns
    -------
    TagSites
        Sites in free space (:func:`scenes.geometry.is_free`), sorted by material then
        position for a reproducible order.

    Raises
    ------
    ValueError
        For a non-positive spacing or offset, or an empty height range.
    """
    if not (np.isfinite(spacing_m) and spacing_m > 0):
        raise ValueError(f"tag_sites: spacing_m must be > 0, got {spacing_m!r}")
    if between_m is not None and not (np.isfinite(between_m) and between_m > 0):
        raise ValueError(f"tag_sites: between_m must be > 0, got {between_m!r}")
    if not (np.isfinite(offset_m) and offset_m > 0):
        raise ValueError(f"tag_sites: offset_m must be > 0, got {offset_m!r}")
    z0, z1 = (-np.inf, np.inf) if z_range_m is None else (float(v) for v in z_range_m)
    if z_range_m is not None and not (np.isfinite(z0) and np.isfinite(z1) and z0 < z1):
        raise ValueError(f"tag_sites: z_range_m must be (lo, hi) with lo < hi, got {z_range_m!r}")
    pos, nrm, mat = [], [], []
    for name in sorted(scene.meshes):
        mesh = scene.meshes[name]
        n = np.asarray(mesh.face_normals, dtype=float)
        vert = np.abs(n[:, 2]) < _VERTICAL_NZ
        if not vert.any():
            continue
        tris = np.asarray(mesh.triangles, dtype=float)[vert]
        nh = n[vert].copy()
        nh[:, 2] = 0.0
        nh /= np.linalg.norm(nh, axis=1, keepdims=True)
        plane = np.column_stack([nh[:, :2], np.einsum("ij,ij->i", nh, tris[:, 0])])
        _, group = np.unique(np.round(plane, 6), axis=0, return_inverse=True)
        group = group.reshape(-1)
        for g in range(int(group.max()) + 1):
            sel = group == g
            p = _face_grid(tris[sel], nh[sel][0], spacing_m, between_m)
            if len(p) == 0:
                continue
            p = p[(p[:, 2] >= z0) & (p[:, 2] <= z1)]
            pos.append(p + offset_m * nh[sel][0])
            nrm.append(np.repeat(nh[sel][:1], len(p), axis=0))
            mat.append(np.full(len(p), name))
    if not pos:
        return TagSites(np.zeros((0, 3)), np.zeros((0, 3)), np.zeros(0, dtype=str), np.zeros(0))
    pos, nrm, mat = np.concatenate(pos), np.concatenate(nrm), np.concatenate(mat)
    free = is_free(scene, pos)
    pos, nrm, mat = pos[free], nrm[free], mat[free]
    order = np.lexsort((pos[:, 2], pos[:, 1], pos[:, 0], mat))
    pos, nrm, mat = pos[order], nrm[order], mat[order]
    if len(pos):
        hit = raycast(scene, pos + 1e-4 * nrm, nrm, max_range_m=max_clearance_m)
        clearance = np.minimum(np.where(np.isfinite(hit), hit, max_clearance_m), max_clearance_m)
    else:
        clearance = np.zeros(0)
    return TagSites(pos, nrm, mat.astype(str), np.asarray(clearance, dtype=float))


def draw_tags(sites: TagSites, n: int, rng: np.random.Generator, *, avoid_m=None,
              min_separation_m: float = 0.5, min_clearance_m: float = 0.3,
              prefix: str = "E", where: str = "held-out tags") -> TagSet:
    """Draw ``n`` tags at random sites, apart from each other and from ``avoid_m``.

    Sites are drawn without replacement in a random order; a site is taken when it is at
    least ``min_separation_m`` from every tag taken so far and from every point of
    ``avoid_m`` (e.g. the training tags), and has ``min_clearance_m`` of free space in
    front of it (a tag a reader can face).

    Parameters
    ----------
    sites : TagSites
    n : int
        Tags to draw (>= 1).
    rng : numpy.random.Generator
    avoid_m : array_like, shape (j, 3), optional
        Positions the new tags must keep away from [m].
    min_separation_m : float
        Smallest 3-D distance to any other tag [m].
    min_clearance_m : float
        Smallest free distance in front of a site [m].
    prefix : str
        Tag ids are ``f"{prefix}{i:02d}"`` (1-based).
    where : str
        Names the setting in error messages.

    Returns
    -------
    TagSet

    Raises
    ------
    ValueError
        When fewer than ``n`` sites satisfy the constraints; the message gives how many
        could be placed.
    """
    if int(n) < 1:
        raise ValueError(f"{where}: the number of tags must be >= 1, got {n!r}")
    taken: list[int] = []
    placed = np.zeros((0, 3)) if avoid_m is None else np.asarray(avoid_m, float).reshape(-1, 3)
    ok = sites.clearance_m >= float(min_clearance_m)
    for i in rng.permutation(np.flatnonzero(ok)):
        p = sites.positions_m[i]
        if len(placed) and np.min(np.linalg.norm(placed - p, axis=1)) < min_separation_m:
            continue
        taken.append(int(i))
        placed = np.vstack([placed, p[None]])
        if len(taken) == int(n):
            break
    if len(taken) < int(n):
        raise ValueError(
            f"{where}: only {len(taken)} of {int(n)} tags fit on the scene's {len(sites)} tag "
            f"sites ({int(ok.sum())} with {min_clearance_m} m clearance) at least "
            f"{min_separation_m} m apart from each other and from the training tags; lower the "
            "number of tags or the separation")
    taken_arr = np.asarray(taken)
    ids = np.array([f"{prefix}{k + 1:02d}" for k in range(len(taken))])
    return TagSet(ids, sites.positions_m[taken_arr], sites.normals[taken_arr])
