"""Scene specifications: typed dataclasses read from and written to TOML.

A scene TOML describes one of three sources, plus doors, panels, boxes, cabinets,
tags and an optional route::

    name = "corridor_lab"
    route_m = [[0.6, 1.2], [24.4, 1.2]]        # optional robot route (x, y) [m]

    [corridor]                                 # a generated corridor ...
    length_m = 25.0                            # straight: length_m and width_m, or
    width_m = 2.4                              # several [[segment]] rectangles
    height_m = 3.0
    wall_material = "plasterboard"

    [[segment]]                                # free-space rectangles; their union
    min_m = [0.0, 0.0]                         # is the walkable area, walls are
    max_m = [20.0, 2.4]                        # generated around it

    [mesh]                                     # ... or an imported mesh file
    path = "room.glb"                          # (relative to the TOML)
    material = "concrete"                      # or [mesh.material_map]

    [mitsuba]                                  # ... or a Mitsuba/Sionna XML scene
    path = "scene.xml"

    [[door]] / [[panel]] / [[box]] / [[cabinet]] / [[tag]]

Every key carries its unit. Unknown keys are rejected by name, and values of the
wrong type by key and value, with the file path in the message.
"""

from __future__ import annotations

import dataclasses
import os
import tempfile
import types
import typing
from dataclasses import dataclass, field
from pathlib import Path

import tomli_w

try:  # Python >= 3.11
    import tomllib
except ModuleNotFoundError:  # pragma: no cover - Python 3.10
    import tomli as tomllib

from scenes.materials import UnknownMaterialError, resolve_material_name

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
    "load_spec",
    "save_spec",
    "spec_to_dict",
    "spec_from_dict",
    "parse_item",
    "check_spec",
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
        Slab thicknesses of the generated solids, metres.
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
    id : str
        Optional name used in error messages.
    """

    position_m: tuple[float, float]
    width_m: float
    material: str = "glass"
    sill_m: float = 0.0
    height_m: float | None = None
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
    """

    path: str
    material: str | None = None
    material_map: dict[str, str] = field(default_factory=dict)


@dataclass(frozen=True)
class MitsubaSpec:
    """A Mitsuba/Sionna XML scene.

    Attributes
    ----------
    path : str
        XML path, relative to the TOML file.
    """

    path: str


@dataclass(frozen=True)
class MaterialOverride:
    """Replacement radio properties of one library material in one scene (what-if runs).

    Attributes
    ----------
    thickness_m : float or None
        Slab thickness used by Sionna's layered-slab model, metres. Note that a ray
        crossing a generated wall passes two faces, each modelled as a slab.
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
    corridor, mesh, mitsuba : CorridorSpec, MeshSpec, MitsubaSpec or None
        Exactly one is set: where the geometry comes from.
    segments : tuple of SegmentSpec
        Free-space rectangles of a generated corridor (empty: straight corridor).
    doors, panels, boxes, cabinets, tags : tuple
        Items of each kind.
    route_m : tuple of (x, y) or None
        Robot route polyline, metres; ``None``: the generated corridor's centre line.
    material_overrides : dict of str to MaterialOverride
        Per-material replacement properties (TOML ``[material_overrides.<name>]``);
        stored in ``Scene.metadata["material_overrides"]`` and used by the export.
    base_dir : str
        Folder relative paths resolve against (the TOML's folder); not written to TOML.
    source : str
        The TOML file the spec was read from (``""`` if none); not written to TOML.
    """

    name: str
    description: str = ""
    corridor: CorridorSpec | None = None
    mesh: MeshSpec | None = None
    mitsuba: MitsubaSpec | None = None
    segments: tuple[SegmentSpec, ...] = ()
    doors: tuple[DoorSpec, ...] = ()
    panels: tuple[PanelSpec, ...] = ()
    boxes: tuple[BoxSpec, ...] = ()
    cabinets: tuple[CabinetSpec, ...] = ()
    tags: tuple[TagSpec, ...] = ()
    route_m: tuple[tuple[float, float], ...] | None = None
    material_overrides: dict[str, MaterialOverride] = field(default_factory=dict)
    base_dir: str = "."
    source: str = ""


#: TOML array-of-tables names for the item tuples of SceneSpec.
_ITEM_TABLES = {
    "segment": ("segments", SegmentSpec),
    "door": ("doors", DoorSpec),
    "panel": ("panels", PanelSpec),
    "box": ("boxes", BoxSpec),
    "cabinet": ("cabinets", CabinetSpec),
    "tag": ("tags", TagSpec),
}
_SOURCE_TABLES = {"corridor": CorridorSpec, "mesh": MeshSpec, "mitsuba": MitsubaSpec}
_POSITIVE_KEYS = {"length_m", "width_m", "height_m", "wall_thickness_m", "floor_thickness_m",
                  "ceiling_thickness_m", "leaf_thickness_m", "size_m", "thickness_m",
                  "relative_permittivity"}
_NONNEGATIVE_KEYS = {"offset_m", "recess_m", "sill_m", "conductivity_s_per_m"}
_MATERIAL_KEYS = {"material", "wall_material", "floor_material", "ceiling_material", "leaf_material"}


def _fail(where: str, msg: str) -> SpecError:
    return SpecError(f"{where}: {msg}")


def _is_number(v) -> bool:
    return isinstance(v, (int, float)) and not isinstance(v, bool)


def _convert(value, tp, where: str, key: str):
    """Check ``value`` against annotation ``tp`` and convert it (lists -> tuples)."""
    origin = typing.get_origin(tp)
    args = typing.get_args(tp)
    if origin in (typing.Union, types.UnionType):
        inner = [a for a in args if a is not type(None)]
        return _convert(value, inner[0], where, key)
    if tp is float:
        if not _is_number(value):
            raise _fail(where, f"key {key!r} must be a number, got {value!r}")
        return float(value)
    if tp is int:
        if not isinstance(value, int) or isinstance(value, bool):
            raise _fail(where, f"key {key!r} must be an integer, got {value!r}")
        return value
    if tp is bool:
        if not isinstance(value, bool):
            raise _fail(where, f"key {key!r} must be true or false, got {value!r}")
        return value
    if tp is str:
        if not isinstance(value, str):
            raise _fail(where, f"key {key!r} must be a string, got {value!r}")
        return value
    if origin is dict:
        if not isinstance(value, dict) or not all(
            isinstance(k, str) and isinstance(v, str) for k, v in value.items()
        ):
            raise _fail(where, f"key {key!r} must be a table of strings, got {value!r}")
        return dict(value)
    if origin is tuple:
        if not isinstance(value, (list, tuple)):
            raise _fail(where, f"key {key!r} must be an array, got {value!r}")
        if len(args) == 2 and args[1] is Ellipsis:
            return tuple(_convert(v, args[0], where, key) for v in value)
        if len(value) != len(args):
            raise _fail(where, f"key {key!r} must have {len(args)} elements, got {value!r}")
        return tuple(_convert(v, a, where, key) for v, a in zip(value, args, strict=True))
    raise TypeError(f"unsupported annotation {tp!r}")  # pragma: no cover


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
            kwargs[name] = _convert(value, hints[name], where, name)
            if name in _MATERIAL_KEYS:
                try:
                    kwargs[name] = resolve_material_name(kwargs[name])
                except UnknownMaterialError as exc:
                    raise UnknownMaterialError(f"{where}: key {name!r}: {exc}") from None
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
    return cls(**kwargs)


def spec_from_dict(data: dict, source: str = "<dict>", base_dir: str | Path = ".") -> SceneSpec:
    """Build a :class:`SceneSpec` from the parsed TOML mapping (see :func:`load_spec`)."""
    if not isinstance(data, dict):
        raise SpecError(f"{source}: expected a table at top level")
    top_known = {"name", "description", "route_m", "material_overrides", *_SOURCE_TABLES,
                 *_ITEM_TABLES}
    unknown = sorted(set(data) - top_known)
    if unknown:
        raise SpecError(
            f"{source}: unknown key {unknown[0]!r} at top level; known keys: "
            f"{', '.join(sorted(top_known))}"
        )
    kwargs: dict = {"base_dir": str(base_dir), "source": source if source != "<dict>" else ""}
    kwargs["name"] = _convert(data.get("name", Path(source).stem), str, source, "name")
    kwargs["description"] = _convert(data.get("description", ""), str, source, "description")
    if "route_m" in data:
        route = _convert(data["route_m"], tuple[tuple[float, float], ...], source, "route_m")
        if len(route) < 2:
            raise SpecError(f"{source}: key 'route_m' needs at least 2 points, got {route!r}")
        kwargs["route_m"] = route
    overrides = data.get("material_overrides", {})
    if not isinstance(overrides, dict):
        raise SpecError(f"{source}: [material_overrides] must be a table, got {overrides!r}")
    kwargs["material_overrides"] = {}
    for mat, values in overrides.items():
        try:
            key = resolve_material_name(mat)
        except UnknownMaterialError as exc:
            raise UnknownMaterialError(f"{source}: [material_overrides.{mat}]: {exc}") from None
        kwargs["material_overrides"][key] = parse_item(
            MaterialOverride, values, f"{source}: [material_overrides.{mat}]")
    for table, cls in _SOURCE_TABLES.items():
        if table in data:
            kwargs[table] = parse_item(cls, data[table], f"{source}: [{table}]")
    sources = [t for t in _SOURCE_TABLES if t in kwargs]
    if len(sources) != 1:
        raise SpecError(
            f"{source}: exactly one of [corridor], [mesh], [mitsuba] is needed, got "
            f"{sources or 'none'}"
        )
    for table, (attr, cls) in _ITEM_TABLES.items():
        items = data.get(table, [])
        if isinstance(items, dict):
            items = [items]
        if not isinstance(items, list):
            raise SpecError(f"{source}: [[{table}]] must be an array of tables, got {items!r}")
        kwargs[attr] = tuple(
            parse_item(cls, it, f"{source}: [[{table}]] #{i + 1}") for i, it in enumerate(items)
        )
    spec = SceneSpec(**kwargs)
    check_spec(spec, source)
    return spec


def check_spec(spec: SceneSpec, source: str) -> None:
    """Cross-field checks of a spec (source exclusivity, segment corners, unique tag ids)."""
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
    dup = sorted({i for i in ids if ids.count(i) > 1})
    if dup:
        raise SpecError(f"{source}: duplicate tag ids {dup}")


def load_spec(path: str | Path) -> SceneSpec:
    """Read a scene TOML file into a :class:`SceneSpec`.

    Raises
    ------
    FileNotFoundError
        If ``path`` does not exist.
    SpecError
        On an unknown key (named), a value of the wrong type (key and value named),
        or an inconsistent layout; the message starts with the file name.
    UnknownMaterialError
        On a material name that is not in the library.
    """
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"scene spec {str(path)!r} does not exist")
    try:
        data = tomllib.loads(path.read_text())
    except tomllib.TOMLDecodeError as exc:
        raise SpecError(f"{path}: invalid TOML: {exc}") from None
    return spec_from_dict(data, source=str(path), base_dir=path.parent)


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
    for table in _SOURCE_TABLES:
        value = getattr(spec, table)
        if value is not None:
            out[table] = clean(value)
    for table, (attr, _) in _ITEM_TABLES.items():
        items = getattr(spec, attr)
        if items:
            out[table] = [clean(it) for it in items]
    return out


def save_spec(spec: SceneSpec, path: str | Path) -> Path:
    """Write ``spec`` as TOML (temporary file renamed into place); returns the path."""
    path = Path(path)
    data = tomli_w.dumps(spec_to_dict(spec)).encode()
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.", suffix=".tmp")
    try:
        with os.fdopen(fd, "wb") as fh:
            fh.write(data)
        os.replace(tmp, path)
    except BaseException:
        if os.path.exists(tmp):
            os.unlink(tmp)
        raise
    return path


def overrides_metadata(spec: SceneSpec) -> dict:
    """``{"material_overrides": {name: {key: value}}}`` for ``Scene.metadata`` (empty if none)."""
    if not spec.material_overrides:
        return {}
    return {"material_overrides": {
        name: {k: v for k, v in dataclasses.asdict(ov).items() if v is not None}
        for name, ov in sorted(spec.material_overrides.items())}}
