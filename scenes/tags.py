"""Placing tags on surfaces and checking that they sit in free space next to one."""

from __future__ import annotations

import numpy as np

from scenes.geometry import closest_surface, in_free_space, solid_material_at
from scenes.scene import TagSet
from scenes.spec import TagSpec, item_where, parse_item

__all__ = ["make_tags", "validate_tags", "DEFAULT_MAX_SURFACE_DISTANCE_M"]

#: A tag farther than this from every surface is "floating in the air" (it is stuck
#: on something: 5 mm offset plus a few cm of slack for hand-placed coordinates).
DEFAULT_MAX_SURFACE_DISTANCE_M = 0.05
#: Most tags one scene may hold: every tag is traced from every antenna position (a study
#: of 1,000 positions and 20,000 tags is 2e7 links, hours on 2 cores; the warehouse-scale
#: case holds 640); more is refused before any work instead of a study that never ends.
MAX_TAGS = 20_000


def make_tags(scene, tags, where: str = "tags") -> TagSet:
    """Turn tag specs into a :class:`TagSet` on the surfaces of ``scene``.

    Parameters
    ----------
    scene : scenes.Scene
        The geometry the tags are stuck on (its own tags are ignored).
    tags : sequence of TagSpec or dict
        Each gives the point on the surface, an optional normal (``None``: the normal of
        the nearest face, which points out of the solid into free space) and the offset
        of the tag centre along it (default 5 mm).
    where : str
        Context for error messages.

    Returns
    -------
    TagSet
        Centres ``position_m + offset_m * normal``, unit normals.
    """
    tags = list(tags)
    if len(tags) > MAX_TAGS:
        raise ValueError(f"{where}: {len(tags):,} tags, more than the {MAX_TAGS:,} a scene may hold "
                         "(each is traced from every antenna position)")
    specs = [parse_item(TagSpec, t, item_where(f"{where} #{i + 1}", t)) for i, t in enumerate(tags)]
    if not specs:
        return TagSet(np.zeros(0, dtype=str), np.zeros((0, 3)), np.zeros((0, 3)))
    pos = np.array([s.position_m for s in specs], dtype=float)
    for i, s in enumerate(specs):  # specs built elsewhere (TagSpec(...)) skip parse_item's checks
        for key, value in (("position_m", s.position_m), ("normal", s.normal), ("offset_m", s.offset_m)):
            if value is not None and not np.all(np.isfinite(np.asarray(value, dtype=float))):
                raise ValueError(f"{item_where(f'{where} #{i + 1}', {'id': s.id})}: key {key!r} must "
                                 f"hold finite numbers, got {value!r}")
    # only an absent normal is taken from the nearest face (never a NaN one)
    missing = np.array([s.normal is None for s in specs])
    normals = np.array([s.normal if s.normal is not None else (0.0, 0.0, 0.0) for s in specs],
                       dtype=float)
    if np.any(missing):
        normals[missing] = closest_surface(scene, pos[missing]).normal
    norm = np.linalg.norm(normals, axis=1)
    if np.any(norm < 1e-9):
        bad = [specs[i].id for i in np.flatnonzero(norm < 1e-9)]
        raise ValueError(f"{where}: tags {bad} have a zero normal")
    normals = normals / norm[:, None]
    offsets = np.array([s.offset_m for s in specs])
    centres = pos + offsets[:, None] * normals
    return TagSet(np.array([s.id for s in specs]), centres, normals)


def validate_tags(scene, max_surface_distance_m: float = DEFAULT_MAX_SURFACE_DISTANCE_M) -> None:
    """Check that every tag of ``scene`` sits in free space within reach of a surface.

    Raises
    ------
    ValueError
        Naming the tag id and position when a tag lies outside the scene bounds, inside
        a solid (wall, box, cabinet; the material is named), outside the free volume, or
        farther than ``max_surface_distance_m`` from every surface.
    """
    tags = scene.tags
    if len(tags) == 0:
        return
    if len(tags) > MAX_TAGS:
        raise ValueError(f"{scene.name}: {len(tags):,} tags, more than the {MAX_TAGS:,} a scene may "
                         "hold (each is traced from every antenna position)")
    pos = tags.positions_m

    def where(i: int) -> str:
        x, y, z = pos[i]
        return f"{scene.name}: tag {str(tags.ids[i])!r} at ({x:.4g}, {y:.4g}, {z:.4g}) m"

    lo, hi = scene.bounds_m
    outside = np.flatnonzero(np.any((pos < lo - 1e-9) | (pos > hi + 1e-9), axis=1))
    if len(outside):
        i = outside[0]
        raise ValueError(f"{where(i)} lies outside the scene bounds {lo.round(4).tolist()} .. "
                         f"{hi.round(4).tolist()}")
    mats = solid_material_at(scene, pos)
    inside = np.flatnonzero(mats != "")
    if len(inside):
        i = inside[0]
        raise ValueError(f"{where(i)} lies inside solid geometry (material {str(mats[i])!r}); a tag "
                         "must sit in free space, offset from the surface along its normal")
    free = in_free_space(scene, pos)
    if not np.all(free):
        i = np.flatnonzero(~free)[0]
        raise ValueError(f"{where(i)} lies outside the scene's free space")
    dist = closest_surface(scene, pos).distance_m
    far = np.flatnonzero(dist > max_surface_distance_m)
    if len(far):
        i = far[0]
        raise ValueError(f"{where(i)} is {dist[i]:.3g} m from the nearest surface (more than "
                         f"{max_surface_distance_m} m): a tag must be stuck on a surface")
