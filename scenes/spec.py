"""Scene specifications: typed dataclasses read from and written to TOML.

A scene TOML describes one source (a row of :data:`scenes.sources.SOURCES`: these three,
and ``[map]``, :mod:`scenes.mapspec`), plus doors, panels, boxes, cabinets, tags and an
optional route::

    name = "corridor_lab"
    route_m = [[0.6, 1.2], [24.4, 1.2]]        # optional robot route (x, y) [m]

    [corridor]                                 # a generated corridor ...
    length_m = 25.0                            # straight: length_m and width_m, or
    width_m = 2.4                              # several [[segment]] rectangles
    height_m = 3.0
    wall_material = "plasterboard"
    wall_construction = "stud"                 # optional: "solid" | "stud" | "double" | "single"
    material_construction = { glass = "double" }   # optional, per material

    [[segment]]                                # free-space rectangles; their union
    min_m = [0.0, 0.0]                         # is the walkable area, walls are
    max_m = [20.0, 2.4]                        # generated around it

    [mesh]                                     # ... or an imported mesh file
    path = "room.glb"                          # (relative to the TOML)
    material = "concrete"                      # or [mesh.material_map]
    radio_geometry = "as_is"                   # or "single" | "thin_boxes" (scenes.radio_import)

    [mitsuba]                                  # ... or a Mitsuba/Sionna XML scene
    path = "scene.xml"

    [[door]] / [[panel]] / [[box]] / [[cabinet]] / [[tag]]

Every key carries its unit. Unknown keys are rejected by name, and values of the
wrong type by key and value, with the file path in the message; so are numbers that
are not finite (TOML's ``nan`` and ``inf``), anywhere, and a ``[[tag]]`` item is named by
its ``id`` as well as its number.

Wall constructions decide the radio geometry of generated walls (see
:mod:`scenes.radio` and ``docs/radio_geometry.md``): ``"solid"`` is one surface on the
wall's inner face with ``wall_thickness_m``; ``"stud"`` (plasterboard's default) and
``"double"`` one leaf on each face of the wall with the material's library thickness;
``"single"`` one leaf on the inner face. A panel's ``construction`` wins over
``material_construction``, which wins over the material default; ``wall_construction``
sets the construction of the corridor's ``wall_material``.
"""

from __future__ import annotations

import dataclasses
import typing
from collections import Counter
from dataclasses import dataclass, field

from scenes.materials import UnknownMaterialError, resolve_material_name
from scenes.radio import CONSTRUCTIONS, RADIO_GEOMETRIES, THIN_BOX_FACES
from scenes.schema import ValueTypeError
from scenes.schema import convert_value as _convert

__all__ = [
    "SegmentSpec",
    "CorridorSpec",
    "DoorSpec",
    "PanelSpec",
    "BoxSpec",
    "CabinetSpec",
    "TagSpec",
    "MeshSpec",
    "MitsubaSpec",
    "MaterialOverride",
    "SceneSpec",
    "SpecError",
    "parse_item",
    "convert_value",
    "item_where",
    "check_spec",
    "spec_to_dict",
    "overrides_metadata",
]


class SpecError(ValueError):
    """A scene specification that is malformed (unknown key, wrong type, bad value)."""


@dataclass(frozen=True)
class SegmentSpec:
    """An axis-aligned rectangle of free space; the union of segments is the walkable area.

    Attributes
    ----------
    min_m, max_m : tuple of float
        Opposite corners (x, y), metres, ``min_m < max_m`` component-wise.
    """

    min_m: tuple[float, float]
    max_m: tuple[float, float]


@dataclass(frozen=True)
class CorridorSpec:
    """Common parameters of a generated corridor.

    Attributes
    ----------
    height_m : float
        Floor-to-ceiling height, metres.
    length_m, width_m : float or None
        Straight corridor along +x: free space x in [0, length_m], y in [0, width_m].
        Leave both unset when the scene lists ``[[segment]]`` rectangles instead.
    wall_material, floor_material, ceiling_material : str
        Library material names (ITU names accepted).
    wall_thickness_m, floor_thickness_m, ceiling_thickness_m : float
        Slab thicknesses of the generated solids, metres; also the thickness the ray
        tracer applies at the floor, the ceiling and solid wall surfaces.
    wall_construction : str or None
        Construction of the ``wall_material`` pieces (one of
        :data:`scenes.radio.CONSTRUCTIONS`); ``None``: ``material_construction`` or the
        material's default (plasterboard ``"stud"``, else ``"solid"``).
    material_construction : dict of str to str
        Construction per material name for every wall piece of that material (panels
        included, unless they set their own ``construction``).
    """

    height_m: float = 3.0
    length_m: float | None = None
    width_m: float | None = None
    wall_material: str = "plasterboard"
    floor_material: str = "concrete"
    ceiling_material: str = "ceiling_board"
    wall_thickness_m: float = 0.12
    floor_thickness_m: float = 0.2
    ceiling_thickness_m: float = 0.05
    wall_construction: str | None = None
    material_construction: dict[str, str] = field(default_factory=dict)


@dataclass(frozen=True)
class DoorSpec:
    """A door opening cut into a wall, open or closed by a wooden leaf.

    Attributes
    ----------
    position_m : tuple of float
        (x, y) of the opening's centre on the wall's inner face (or inside the wall), m.
    width_m, height_m : float
        Opening size, metres; the opening starts at the floor.
    closed : bool
        False: an empty opening. True: a leaf of ``leaf_material`` fills it.
    leaf_material : str
        Material of the leaf (default wood).
    leaf_thickness_m : float
        Leaf thickness, metres.
    recess_m : float
        Distance of the leaf's inner face behind the wall's inner face, metres.
    id : str
        Optional name used in error messages.
    """

    position_m: tuple[float, float]
    width_m: float = 0.9
    height_m: float = 2.1
    closed: bool = False
    leaf_material: str = "wood"
    leaf_thickness_m: float = 0.04
    recess_m: float = 0.02
    id: str = ""


@dataclass(frozen=True)
class PanelSpec:
    """A wall section made of another material (a glass panel, a brick section).

    Attributes
    ----------
    position_m : tuple of float
        (x, y) of the section's centre on the wall's inner face, metres.
    width_m : float
        Extent along the wall, metres.
    material : str
        Material replacing the wall there (default glass).
    sill_m : float
        Height of the section's bottom edge, metres.
    height_m : float or None
        Height of the section, metres; ``None``: up to the ceiling.
    construction : str or None
        Its construction (:data:`scenes.radio.CONSTRUCTIONS`, e.g. ``"double"`` glazing);
        ``None``: the corridor's ``material_construction`` or the material default.
    id : str
        Optional name used in error messages.
    """

    position_m: tuple[float, float]
    width_m: float
    material: str = "glass"
    sill_m: float = 0.0
    height_m: float | None = None
    construction: str | None = None
    id: str = ""


@dataclass(frozen=True)
class BoxSpec:
    """A box standing in the corridor (cardboard boxes: chipboard).

    Attributes
    ----------
    center_m : tuple of float
        (x, y) of the footprint centre, metres.
    size_m : tuple of float
        (length along its local x, depth, height), metres.
    material : str
        Material (default chipboard).
    z_m : float
        Height of its bottom face, metres (0: on the floor).
    yaw_deg : float
        Rotation about the vertical axis, degrees.
    id : str
        Optional name used in error messages.
    """

    center_m: tuple[float, float]
    size_m: tuple[float, float, float]
    material: str = "chipboard"
    z_m: float = 0.0
    yaw_deg: float = 0.0
    id: str = ""


@dataclass(frozen=True)
class CabinetSpec(BoxSpec):
    """A metal cabinet: a :class:`BoxSpec` whose material defaults to metal."""

    material: str = "metal"


@dataclass(frozen=True)
class TagSpec:
    """A passive tag stuck on a surface.

    Attributes
    ----------
    id : str
        Unique tag identifier (``"T01"``).
    position_m : tuple of float
        (x, y, z) of the point on the surface the tag is stuck on, metres.
    normal : tuple of float or None
        Surface normal pointing into free space; ``None``: taken from the nearest face.
    offset_m : float
        Tag centre offset from the surface along the normal, metres (default 5 mm).
    """

    id: str
    position_m: tuple[float, float, float]
    normal: tuple[float, float, float] | None = None
    offset_m: float = 0.005


@dataclass(frozen=True)
class MeshSpec:
    """An imported mesh file (PLY, OBJ, GLB/GLTF, STL).

    Attributes
    ----------
    path : str
        File path, relative to the TOML file.
    material : str or None
        Material of every geometry not named in ``material_map``.
    material_map : dict of str to str
        Geometry or node name to material name.
    radio_geometry : str
        ``"as_is"``, ``"single"`` or ``"thin_boxes"`` (:mod:`scenes.radio_import`).
    thin_box_max_m : float
        Largest smallest-extent of a box converted by ``"thin_boxes"``, metres.
    thin_box_face : str
        Face that carries a converted box (``"inner"``, ``"lower"``, ``"upper"``, ``"mid"``).
    """

    path: str
    material: str | None = None
    material_map: dict[str, str] = field(default_factory=dict)
    radio_geometry: str = "as_is"
    thin_box_max_m: float = 0.3
    thin_box_face: str = "inner"


@dataclass(frozen=True)
class MitsubaSpec:
    """A Mitsuba/Sionna XML scene.

    Attributes
    ----------
    path : str
        XML path, relative to the TOML file.
    radio_geometry, thin_box_max_m, thin_box_face
        As in :class:`MeshSpec`; ``"single"`` takes each shape's thickness from its
        radio material.
    """

    path: str
    radio_geometry: str = "as_is"
    thin_box_max_m: float = 0.3
    thin_box_face: str = "inner"


@dataclass(frozen=True)
class MaterialOverride:
    """Replacement radio properties of one library material in one scene (what-if runs).

    Attributes
    ----------
    thickness_m : float or None
        Slab thickness used by Sionna's slab model, metres: replaces the thickness of
        every traced surface of the material (each leaf of a stud wall, a solid wall's
        single surface, every face of an imported mesh traced as it is).
    relative_permittivity : float or None
        Replaces P.2040's ``a * f_GHz ** b``.
    conductivity_s_per_m : float or None
        Replaces P.2040's ``c * f_GHz ** d``, S/m.
    """

    thickness_m: float | None = None
    relative_permittivity: float | None = None
    conductivity_s_per_m: float | None = None


@dataclass(frozen=True)
class SceneSpec:
    """A whole scene description (see the module docstring for the TOML layout).

    Attributes
    ----------
    name : str
        Scene name.
    description : str
        Free text.
    source_tables : dict of str to object
        The table that says where the geometry comes from, by its name: exactly one in a
        valid spec, a row of :data:`scenes.sources.SOURCES` (``{"corridor": CorridorSpec(...)}``;
        ``"map"``: a ROS occupancy-grid map, :class:`scenes.mapspec.MapSpec`, TOML ``[map]``).
        :attr:`corridor`, :attr:`mesh`, :attr:`mitsuba` and :attr:`map` read it.
    segments : tuple of SegmentSpec
        Free-space rectangles of a generated corridor (empty: straight corridor).
    doors, panels, boxes, cabinets, tags : tuple
        Items of each kind.
    route_m : tuple of (x, y) or None
        Robot route polyline, metres; ``None``: the generated corridor's centre line.
    material_overrides : dict of str to MaterialOverride
        Per-material replacement properties (TOML ``[material_overrides.<name>]``);
        stored in ``Scene.metadata["material_overrides"]`` and used by the export.
    tag_layout : scenes.mapspec.TagLayoutSpec or None
        TOML ``[tags]``: tags laid out on a map scene's shelves or read from a CSV.
    base_dir : str
        Folder relative paths resolve against (the TOML's folder); not written to TOML.
    source : str
        The TOML file the spec was read from (``""`` if none); not written to TOML.
    """

    name: str
    description: str = ""
    source_tables: dict[str, typing.Any] = field(default_factory=dict)
    segments: tuple[SegmentSpec, ...] = ()
    doors: tuple[DoorSpec, ...] = ()
    panels: tuple[PanelSpec, ...] = ()
    boxes: tuple[BoxSpec, ...] = ()
    cabinets: tuple[CabinetSpec, ...] = ()
    tags: tuple[TagSpec, ...] = ()
    route_m: tuple[tuple[float, float], ...] | None = None
    material_overrides: dict[str, MaterialOverride] = field(default_factory=dict)
    tag_layout: typing.Any = None
    base_dir: str = "."
    source: str = ""

    @property
    def corridor(self) -> CorridorSpec | None:
        """The ``[corridor]`` table (a generated corridor), or None."""
        return self.source_tables.get("corridor")

    @property
    def mesh(self) -> MeshSpec | None:
        """The ``[mesh]`` table (an imported mesh file), or None."""
        return self.source_tables.get("mesh")

    @property
    def mitsuba(self) -> MitsubaSpec | None:
        """The ``[mitsuba]`` table (a Mitsuba XML scene), or None."""
        return self.source_tables.get("mitsuba")

    @property
    def map(self):
        """The ``[map]`` table (:class:`scenes.mapspec.MapSpec`, a ROS map), or None."""
        return self.source_tables.get("map")


#: Largest length or coordinate a scene file may give [m]: a site with room for a campus;
#: 1e300 would overflow every extent computed from it.
MAX_EXTENT_M = 100_000.0

_POSITIVE_KEYS = {"length_m", "width_m", "height_m", "wall_thickness_m", "floor_thickness_m",
                  "ceiling_thickness_m", "leaf_thickness_m", "size_m", "thickness_m",
                  "relative_permittivity", "thin_box_max_m"}
_NONNEGATIVE_KEYS = {"offset_m", "recess_m", "sill_m", "conductivity_s_per_m"}
_MATERIAL_KEYS = {"material", "wall_material", "floor_material", "ceiling_material", "leaf_material"}
_CHOICE_KEYS = {"wall_construction": CONSTRUCTIONS, "construction": CONSTRUCTIONS,
                "radio_geometry": RADIO_GEOMETRIES, "thin_box_face": THIN_BOX_FACES}


def _fail(where: str, msg: str) -> SpecError:
    return SpecError(f"{where}: {msg}")


def convert_value(value, tp, where: str, key: str):
    """Check ``value`` against annotation ``tp`` and convert it (lists -> tuples).

    The shared converter :func:`scenes.schema.convert_value`, its message prefixed
    with ``where`` (``"f.toml: [corridor]: key 'width_m' must be a number, got 'wide'"``).
    """
    try:
        return _convert(value, tp, key)
    except ValueTypeError as exc:
        raise _fail(where, str(exc)) from None


def _material_constructions(table: dict, where: str) -> dict[str, str]:
    out = {}
    for mat, cons in table.items():
        try:
            key = resolve_material_name(mat)
        except UnknownMaterialError as exc:
            raise UnknownMaterialError(f"{where}: key 'material_construction': {exc}") from None
        if cons not in CONSTRUCTIONS:
            raise _fail(where, f"key 'material_construction': {mat!r} must be one of "
                               f"{', '.join(repr(c) for c in CONSTRUCTIONS)}, got {cons!r}")
        out[key] = cons
    return dict(sorted(out.items()))


def item_where(where: str, data) -> str:
    """``where`` plus the item's ``id`` when it has one (``"f.toml: [[tag]] #3 (id 'T03')"``)."""
    ident = data.get("id") if isinstance(data, dict) else getattr(data, "id", None)
    return f"{where} (id {ident!r})" if isinstance(ident, str) and ident else where


def parse_item(cls, data, where: str):
    """Build dataclass ``cls`` from a mapping, rejecting unknown keys and wrong types.

    Parameters
    ----------
    cls : type
        One of the spec dataclasses.
    data : dict or dataclass instance
        Values by key (an instance of ``cls`` passes through).
    where : str
        Context for error messages, e.g. ``"corridor_lab.toml: [[door]] #2"``.
    """
    if isinstance(data, cls):
        return data
    if dataclasses.is_dataclass(data):
        data = {f.name: getattr(data, f.name) for f in dataclasses.fields(data)}
    if not isinstance(data, dict):
        raise _fail(where, f"expected a table, got {data!r}")
    hints = typing.get_type_hints(cls)
    fields = {f.name: f for f in dataclasses.fields(cls)}
    unknown = sorted(set(data) - set(fields))
    if unknown:
        raise _fail(where, f"unknown key {unknown[0]!r}; known keys: {', '.join(fields)}")
    kwargs = {}
    for name, f in fields.items():
        if name in data:
            value = data[name]
            if value is None:
                if f.default is not None:
                    raise _fail(where, f"key {name!r} must not be empty")
                kwargs[name] = None
                continue
            kwargs[name] = convert_value(value, hints[name], where, name)
            if name in _MATERIAL_KEYS:
                try:
                    kwargs[name] = resolve_material_name(kwargs[name])
                except UnknownMaterialError as exc:
                    raise UnknownMaterialError(f"{where}: key {name!r}: {exc}") from None
            if name in _CHOICE_KEYS and kwargs[name] not in _CHOICE_KEYS[name]:
                raise _fail(where, f"key {name!r} must be one of "
                                   f"{', '.join(repr(c) for c in _CHOICE_KEYS[name])}, got {value!r}")
            if name == "material_construction":
                kwargs[name] = _material_constructions(kwargs[name], where)
        elif f.default is dataclasses.MISSING and f.default_factory is dataclasses.MISSING:
            raise _fail(where, f"missing required key {name!r}")
    for name, value in kwargs.items():
        if value is None:
            continue
        vals = value if isinstance(value, tuple) else (value,)
        if name in _POSITIVE_KEYS and any(v <= 0 for v in vals):
            raise _fail(where, f"key {name!r} must be positive, got {value!r}")
        if name in _NONNEGATIVE_KEYS and any(v < 0 for v in vals):
            raise _fail(where, f"key {name!r} must not be negative, got {value!r}")
        if name.endswith("_m") and _beyond(value, MAX_EXTENT_M):
            raise _fail(where, f"key {name!r}: {str(value)[:40]} is beyond {MAX_EXTENT_M:g} m "
                               "(MAX_EXTENT_M): a unit error?")
    return cls(**kwargs)


def _beyond(value, limit: float) -> bool:
    """Whether a length (or a tuple of them, nested) exceeds ``limit`` in magnitude."""
    if isinstance(value, (tuple, list)):
        return any(_beyond(v, limit) for v in value)
    return isinstance(value, (int, float)) and not isinstance(value, bool) and abs(value) > limit


def check_spec(spec: SceneSpec, source: str) -> None:
    """Cross-field checks of a spec (segment corners, corridor items, unique tag ids)."""
    c = spec.corridor
    if c is not None:
        straight = c.length_m is not None or c.width_m is not None
        if straight and spec.segments:
            raise SpecError(f"{source}: [corridor] length_m/width_m and [[segment]] exclude each other")
        if not spec.segments and (c.length_m is None or c.width_m is None):
            raise SpecError(f"{source}: [corridor] needs length_m and width_m, or [[segment]] tables")
        for i, s in enumerate(spec.segments):
            if not (s.min_m[0] < s.max_m[0] and s.min_m[1] < s.max_m[1]):
                raise SpecError(f"{source}: [[segment]] #{i + 1}: min_m {s.min_m} must be below max_m {s.max_m}")
    elif spec.segments or spec.doors or spec.panels or spec.boxes or spec.cabinets:
        raise SpecError(f"{source}: [[segment]], [[door]], [[panel]], [[box]] and [[cabinet]] "
                        "need a [corridor]")
    ids = [t.id for t in spec.tags]
    dup = sorted(i for i, k in Counter(ids).items() if k > 1)  # linear: 100,000 tags in ms
    if dup:
        raise SpecError(f"{source}: duplicate tag ids {dup}")


#: Item tables of a scene TOML: TOML array-of-tables name -> (SceneSpec attribute, class).
ITEM_TABLES = {
    "segment": ("segments", SegmentSpec),
    "door": ("doors", DoorSpec),
    "panel": ("panels", PanelSpec),
    "box": ("boxes", BoxSpec),
    "cabinet": ("cabinets", CabinetSpec),
    "tag": ("tags", TagSpec),
}


def spec_to_dict(spec: SceneSpec) -> dict:
    """The TOML mapping of ``spec`` (``None`` values and ``base_dir`` left out)."""

    def clean(obj):
        if dataclasses.is_dataclass(obj):
            return {f.name: clean(getattr(obj, f.name)) for f in dataclasses.fields(obj)
                    if getattr(obj, f.name) is not None}
        if isinstance(obj, (tuple, list)):
            return [clean(v) for v in obj]
        if isinstance(obj, dict):
            return {k: clean(v) for k, v in obj.items()}
        return obj

    out: dict = {"name": spec.name}
    if spec.description:
        out["description"] = spec.description
    if spec.route_m is not None:
        out["route_m"] = clean(spec.route_m)
    if spec.material_overrides:
        out["material_overrides"] = {k: clean(v) for k, v in spec.material_overrides.items()}
    for table, value in spec.source_tables.items():
        out[table] = clean(value)
    if spec.tag_layout is not None:
        out["tags"] = clean(spec.tag_layout)
    for table, (attr, _) in ITEM_TABLES.items():
        items = getattr(spec, attr)
        if items:
            out[table] = [clean(it) for it in items]
    return out


def overrides_metadata(spec: SceneSpec) -> dict:
    """``{"material_overrides": {name: {key: value}}}`` for ``Scene.metadata`` (empty if none)."""
    if not spec.material_overrides:
        return {}
    return {"material_overrides": {
        name: {k: v for k, v in dataclasses.asdict(ov).items() if v is not None}
        for name, ov in sorted(spec.material_overrides.items())}}
