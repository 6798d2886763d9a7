"""Reading and writing scene specs as TOML (see :mod:`scenes.spec` for the layout)."""

from __future__ import annotations

import dataclasses
from collections import Counter
from pathlib import Path

import tomli_w

from scenes.fileio import atomic_write_bytes
from scenes.materials import UnknownMaterialError, resolve_material_name
from scenes.spec import (
    BoxSpec,
    CabinetSpec,
    CorridorSpec,
    DoorSpec,
    MaterialOverride,
    MeshSpec,
    MitsubaSpec,
    PanelSpec,
    SceneSpec,
    SegmentSpec,
    SpecError,
    TagSpec,
    convert_value,
    item_where,
    parse_item,
)

try:  # Python >= 3.11
    import tomllib
except ModuleNotFoundError:  # pragma: no cover - Python 3.10
    import tomli as tomllib

__all__ = [
    "spec_from_dict",
    "check_spec",
    "load_spec",
    "spec_to_dict",
    "save_spec",
    "overrides_metadata",
]

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


def spec_from_dict(data: dict, source: str = "<dict>", base_dir: str | Path = ".") -> SceneSpec:
    """Build a :class:`SceneSpec` from the parsed TOML mapping (see :func:`load_spec`)."""
    if not isinstance(data, dict):
        raise SpecError(f"{source}: expected a table at top level")
    top_known = {"name", "description", "route_m", "material_overrides", "map", "tags",
                 *_SOURCE_TABLES, *_ITEM_TABLES}
    unknown = sorted(set(data) - top_known)
    if unknown:
        raise SpecError(
            f"{source}: unknown key {unknown[0]!r} at top level; known keys: "
            f"{', '.join(sorted(top_known))}"
        )
    kwargs: dict = {"base_dir": str(base_dir), "source": source if source != "<dict>" else ""}
    kwargs["name"] = convert_value(data.get("name", Path(source).stem), str, source, "name")
    kwargs["description"] = convert_value(data.get("description", ""), str, source, "description")
    if "route_m" in data:
        route = convert_value(data["route_m"], tuple[tuple[float, float], ...], source, "route_m")
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
    if "map" in data:
        from scenes.mapspec import parse_map_table

        kwargs["map"] = parse_map_table(data["map"], f"{source}: [map]")
    if "tags" in data:
        if "map" not in data:
            raise SpecError(f"{source}: [tags] needs a [map] (tag layouts on shelves)")
        from scenes.mapspec import parse_tags_table

        kwargs["tag_layout"] = parse_tags_table(data["tags"], f"{source}: [tags]")
    sources = [t for t in (*_SOURCE_TABLES, "map") if t in kwargs]
    if len(sources) != 1:
        raise SpecError(
            f"{source}: exactly one of [corridor], [mesh], [mitsuba], [map] is needed, got "
            f"{sources or 'none'}"
        )
    for table, (attr, cls) in _ITEM_TABLES.items():
        items = data.get(table, [])
        if isinstance(items, dict):
            items = [items]
        if not isinstance(items, list):
            raise SpecError(f"{source}: [[{table}]] must be an array of tables, got {items!r}")
        kwargs[attr] = tuple(
            parse_item(cls, it, item_where(f"{source}: [[{table}]] #{i + 1}", it))
            for i, it in enumerate(items)
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
    dup = sorted(i for i, k in Counter(ids).items() if k > 1)  # linear: 100,000 tags in ms
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
        raise FileNotFoundError(f"scene spec {str(path)!r} "
                                + ("is a directory, not a file" if path.is_dir() else "does not exist"))
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
    if spec.map is not None:
        out["map"] = clean(spec.map)
    if spec.tag_layout is not None:
        out["tags"] = clean(spec.tag_layout)
    for table, (attr, _) in _ITEM_TABLES.items():
        items = getattr(spec, attr)
        if items:
            out[table] = [clean(it) for it in items]
    return out


def save_spec(spec: SceneSpec, path: str | Path) -> Path:
    """Write ``spec`` as TOML (temporary file renamed into place); returns the path."""
    path = Path(path)
    data = tomli_w.dumps(spec_to_dict(spec)).encode()
    return atomic_write_bytes(path, data)


def overrides_metadata(spec: SceneSpec) -> dict:
    """``{"material_overrides": {name: {key: value}}}`` for ``Scene.metadata`` (empty if none)."""
    if not spec.material_overrides:
        return {}
    return {"material_overrides": {
        name: {k: v for k, v in dataclasses.asdict(ov).items() if v is not None}
        for name, ov in sorted(spec.material_overrides.items())}}
