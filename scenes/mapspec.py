"""Scene-TOML tables of a building from a ROS map: ``[map]``, ``[[map.override]]``, ``[tags]``.

::

    name = "warehouse"
    [map]
    path = "warehouse_small.yaml"          # map_server YAML, relative to this TOML
    height_m = 4.0                         # wall height; floor and ceiling slabs below/above
    rack_height_m = 2.2
    shelf_levels_m = [0.3, 0.8, 1.3, 1.8]  # bottom of each shelf's front beam
    route_standoff_m = 1.0                 # planned route: every tag face within this

    [[map.override]]                       # by a point on or in an obstacle ...
    point_m = [11.05, 3.0]
    material = "glass"
    construction = "double"
    [[map.override]]                       # ... or every obstacle inside a polygon
    polygon_m = [[0, 0], [5, 0], [5, 5], [0, 5]]
    kind = "rack"

    [tags]
    layout = "shelves"                     # or "csv" (csv = "tags.csv") or "none"
    spacing_m = 0.5
    walls = false                          # true: also on the room-facing faces of walls

Every key carries its unit; unknown keys are refused by name (:func:`scenes.spec.parse_item`).
"""

from __future__ import annotations

from dataclasses import dataclass, replace

from scenes.mapextract import KINDS, ExtractionRules
from scenes.spec import SpecError, item_where, parse_item

__all__ = ["TAG_LAYOUTS", "MapOverride", "MapSpec", "TagLayoutSpec", "parse_map_table",
           "parse_tags_table", "rules_of"]

#: ``[tags] layout`` values.
TAG_LAYOUTS = ("shelves", "csv", "none")


@dataclass(frozen=True)
class MapOverride:
    """What one obstacle (or every obstacle in a region) is made of, overriding the rules.

    Attributes
    ----------
    point_m : tuple of float or None
        (x, y) [m] on or inside the obstacle (within one map cell of its outline).
    polygon_m : tuple of (x, y) or None
        Region [m]: every obstacle whose interior point lies inside it.
    kind : str or None
        ``"wall"``, ``"rack"`` or ``"pillar"`` (:data:`scenes.mapextract.KINDS`).
    material : str or None
        Library material name.
    construction : str or None
        Wall construction (:data:`scenes.radio.CONSTRUCTIONS`); walls only.
    id : str
        Optional name used in error messages.
    """

    point_m: tuple[float, float] | None = None
    polygon_m: tuple[tuple[float, float], ...] | None = None
    kind: str | None = None
    material: str | None = None
    construction: str | None = None
    id: str = ""


@dataclass(frozen=True)
class MapSpec:
    """A building from a ROS map (the scene TOML's ``[map]`` table).

    Attributes
    ----------
    path : str
        map_server YAML, relative to the TOML.
    height_m : float
        Height of walls and pillars, floor to ceiling [m].
    floor_material, ceiling_material : str
        Slab materials.
    floor_thickness_m, ceiling_thickness_m : float
        Slab thicknesses [m].
    tolerance_m : float or None
        Outline and centre-line simplification tolerance [m]; None: 0.05 m (a SLAM map's
        laser band) or half a map cell, whichever is larger.
    outer_material, thick_material, thin_material, pillar_material : str
        Materials of the rules (:class:`scenes.mapextract.ExtractionRules`).
    thin_wall_max_m, pillar_max_m, rack_min_fill, rack_min_depth_m, rack_min_length_m, min_area_m2 : float
        Rule thresholds (:class:`scenes.mapextract.ExtractionRules`).
    gap_close_m : float
        Outline gaps up to this wide are closed before extraction [m]; 0: none
        (:mod:`scenes.mapclean`).
    fill_max_width_m : float
        Enclosed regions at most this wide (largest inscribed disc) become obstacle: the
        inside of a rack's or pallet's outline, when mostly unknown [m]; 0 (with
        ``fill_free_max_width_m = 0``): none (:mod:`scenes.mapclean`).
    fill_free_max_width_m : float
        Enclosed regions at most this wide become obstacle whatever they hold [m]; 0: none.
    solid_wall_thickness_m : float or None
        Slab thickness the tracer gives a solid wall (outer walls, thick inner walls) [m].
        None (the default): the wall material's library thickness
        (:data:`scenes.materials.MATERIALS`: concrete 0.20 m, brick 0.12 m), a
        construction default; a SLAM map's occupied band is the laser's spread, not the
        wall (ITU-R P.2040 concrete reflects 6.5 dB differently at 5 and 15 cm). 0: the
        map's band, as drawn (a map drawn to scale).
    rack_height_m : float
        Height of a rack's uprights [m].
    shelf_levels_m : tuple of float
        Height of the bottom of each shelf's front beam [m], increasing.
    beam_height_m : float
        Height of a shelf's front and back beams [m] (tags sit on the front beam).
    bay_length_m : float
        Largest distance between uprights along a rack [m].
    post_width_m : float
        Side of an upright's square section [m].
    route_standoff_m : float
        The planned coverage route passes every tag-bearing face within this [m].
    override : tuple of MapOverride
        ``[[map.override]]`` items, applied in order.
    """

    path: str
    height_m: float = 3.0
    floor_material: str = "concrete"
    ceiling_material: str = "ceiling_board"
    floor_thickness_m: float = 0.2
    ceiling_thickness_m: float = 0.05
    tolerance_m: float | None = None
    outer_material: str = "concrete"
    thick_material: str = "brick"
    thin_material: str = "plasterboard"
    pillar_material: str = "concrete"
    thin_wall_max_m: float = 0.15
    pillar_max_m: float = 0.8
    rack_min_fill: float = 0.85
    rack_min_depth_m: float = 0.35
    rack_min_length_m: float = 1.0
    min_area_m2: float = 0.02
    gap_close_m: float = 0.1
    fill_max_width_m: float = 2.5
    fill_free_max_width_m: float = 0.8
    solid_wall_thickness_m: float | None = None
    rack_height_m: float = 2.2
    shelf_levels_m: tuple[float, ...] = (0.3, 0.8, 1.3, 1.8)
    beam_height_m: float = 0.1
    bay_length_m: float = 1.35
    post_width_m: float = 0.08
    route_standoff_m: float = 1.0
    override: tuple[MapOverride, ...] = ()


@dataclass(frozen=True)
class TagLayoutSpec:
    """Where a map scene's tags are (the scene TOML's ``[tags]`` table).

    Attributes
    ----------
    layout : str
        ``"shelves"``: on the front beams of every rack face that looks onto free space;
        ``"csv"``: from ``csv``; ``"none"``: only the ``[[tag]]`` items.
    heights_m : tuple of float or None
        Heights of the tag centres on the shelf fronts [m]; each must lie on a front beam.
        None: the middle of every beam.
    spacing_m : float
        Distance between neighbouring tags along a shelf front [m].
    margin_m : float
        Distance kept from a rack's ends [m].
    csv : str
        CSV file (relative to the TOML) with columns ``id, x_m, y_m, z_m, nx, ny, nz``:
        the point on the surface and the normal into free space.
    offset_m : float
        Tag centre offset from the surface along the normal [m].
    walls : bool or None
        ``layout = "shelves"`` only: also tag the faces of wall obstacles (the outer
        wall's inner face, partitions, thick walls) that look onto free space, at the
        same heights, spacing, margin and offset
        (:func:`scenes.mapscene.wall_tags`). None (the default): only where the map has
        no rack, so an office or arena gets tags too.
    """

    layout: str = "shelves"
    heights_m: tuple[float, ...] | None = None
    spacing_m: float = 0.5
    margin_m: float = 0.2
    csv: str = ""
    offset_m: float = 0.005
    walls: bool | None = None


_POSITIVE = ("height_m", "floor_thickness_m", "ceiling_thickness_m", "thin_wall_max_m", "pillar_max_m",
             "rack_min_depth_m", "rack_min_length_m", "rack_height_m", "beam_height_m",
             "bay_length_m", "post_width_m", "route_standoff_m", "spacing_m")


def _check_positive(obj, where: str) -> None:
    for key in _POSITIVE:
        value = getattr(obj, key, None)
        if value is not None and not value > 0:
            raise SpecError(f"{where}: key {key!r} must be positive, got {value!r}")


def parse_map_table(data, where: str) -> MapSpec:
    """The :class:`MapSpec` of a ``[map]`` table (``override`` items included)."""
    if isinstance(data, MapSpec):
        return data
    if not isinstance(data, dict):
        raise SpecError(f"{where}: expected a table, got {data!r}")
    items = data.get("override", [])
    if isinstance(items, dict):
        items = [items]
    if not isinstance(items, list):
        raise SpecError(f"{where}: [[map.override]] must be an array of tables, got {items!r}")
    overrides = []
    for i, it in enumerate(items):
        w = item_where(f"{where.rsplit('[map]', 1)[0]}[[map.override]] #{i + 1}", it)
        ov = parse_item(MapOverride, it, w)
        if (ov.point_m is None) == (ov.polygon_m is None):
            raise SpecError(f"{w}: give exactly one of 'point_m' and 'polygon_m'")
        if ov.polygon_m is not None and len(ov.polygon_m) < 3:
            raise SpecError(f"{w}: key 'polygon_m' needs at least 3 points, got {ov.polygon_m!r}")
        if ov.kind is not None and ov.kind not in KINDS:
            raise SpecError(f"{w}: key 'kind' must be one of {', '.join(map(repr, KINDS))}, "
                            f"got {ov.kind!r}")
        if ov.construction is not None and (ov.kind or "wall") != "wall":
            raise SpecError(f"{w}: key 'construction' applies to walls only (kind {ov.kind!r})")
        if ov.kind is None and ov.material is None and ov.construction is None:
            raise SpecError(f"{w}: give at least one of 'kind', 'material', 'construction'")
        overrides.append(ov)
    rest = {k: v for k, v in data.items() if k != "override"}
    spec = parse_item(MapSpec, rest, where)
    _check_positive(spec, where)
    levels = spec.shelf_levels_m
    if not levels or any(b <= a for a, b in zip(levels[:-1], levels[1:], strict=True)) or levels[0] < 0:
        raise SpecError(f"{where}: key 'shelf_levels_m' must be increasing heights >= 0, got {levels!r}")
    if levels[-1] + spec.beam_height_m > spec.rack_height_m:
        raise SpecError(f"{where}: key 'shelf_levels_m': the top beam ({levels[-1]} + beam_height_m "
                        f"{spec.beam_height_m}) is above rack_height_m {spec.rack_height_m}")
    if spec.rack_height_m > spec.height_m:
        raise SpecError(f"{where}: key 'rack_height_m' {spec.rack_height_m} is above height_m "
                        f"{spec.height_m} (the ceiling)")
    if spec.tolerance_m is not None and spec.tolerance_m < 0:
        raise SpecError(f"{where}: key 'tolerance_m' must not be negative, got {spec.tolerance_m!r}")
    for key in ("gap_close_m", "fill_max_width_m", "fill_free_max_width_m", "solid_wall_thickness_m"):
        if getattr(spec, key) is not None and not getattr(spec, key) >= 0:
            raise SpecError(f"{where}: key {key!r} must not be negative, got {getattr(spec, key)!r}")
    if not 0 < spec.rack_min_fill <= 1:
        raise SpecError(f"{where}: key 'rack_min_fill' must be in (0, 1], got {spec.rack_min_fill!r}")
    return replace(spec, override=tuple(overrides))


def parse_tags_table(data, where: str) -> TagLayoutSpec:
    """The :class:`TagLayoutSpec` of a ``[tags]`` table."""
    spec = parse_item(TagLayoutSpec, data, where)
    if spec.layout not in TAG_LAYOUTS:
        raise SpecError(f"{where}: key 'layout' must be one of {', '.join(map(repr, TAG_LAYOUTS))}, "
                        f"got {spec.layout!r}")
    if spec.layout == "csv" and not spec.csv:
        raise SpecError(f"{where}: layout = 'csv' needs key 'csv' (the file)")
    if spec.layout != "csv" and spec.csv:
        raise SpecError(f"{where}: key 'csv' needs layout = 'csv', got layout {spec.layout!r}")
    if not spec.spacing_m > 0 or spec.margin_m < 0 or spec.offset_m < 0:
        raise SpecError(f"{where}: spacing_m must be > 0, margin_m and offset_m >= 0")
    if spec.walls is not None and not isinstance(spec.walls, bool):
        raise SpecError(f"{where}: key 'walls' must be true or false, got {spec.walls!r}")
    if spec.walls and spec.layout != "shelves":
        raise SpecError(f"{where}: key 'walls' needs layout = 'shelves', got layout {spec.layout!r}")
    return spec


def rules_of(spec: MapSpec) -> ExtractionRules:
    """The :class:`~scenes.mapextract.ExtractionRules` a :class:`MapSpec` sets."""
    return ExtractionRules(
        outer_material=spec.outer_material, thick_material=spec.thick_material,
        thin_material=spec.thin_material, thin_wall_max_m=spec.thin_wall_max_m,
        pillar_max_m=spec.pillar_max_m, pillar_material=spec.pillar_material,
        rack_min_fill=spec.rack_min_fill, rack_min_depth_m=spec.rack_min_depth_m,
        rack_min_length_m=spec.rack_min_length_m, min_area_m2=spec.min_area_m2,
        gap_close_m=spec.gap_close_m, fill_max_width_m=spec.fill_max_width_m,
        fill_free_max_width_m=spec.fill_free_max_width_m)
