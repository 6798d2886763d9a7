"""Reading and writing scene specs as TOML (see :mod:`scenes.spec` for the layout).

The source tables a scene TOML may hold (``[corridor]``, ``[mesh]``, ``[mitsuba]``,
``[map]`` ...) and the tables that go with one (the map's ``[tags]``) are the rows of
:data:`scenes.sources.SOURCES`.
"""

from __future__ import annotations

from pathlib import Path

import tomli_w

from scenes.fileio import atomic_write_bytes
from scenes.materials import UnknownMaterialError, resolve_material_name
from scenes.sources import SOURCES
from scenes.spec import (
    ITEM_TABLES,
    MaterialOverride,
    SceneSpec,
    SpecError,
    check_spec,
    convert_value,
    item_where,
    overrides_metadata,
    parse_item,
    spec_to_dict,
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


def spec_from_dict(data: dict, source: str = "<dict>", base_dir: str | Path = ".") -> SceneSpec:
    """Build a :class:`SceneSpec` from the parsed TOML mapping (see :func:`load_spec`)."""
    if not isinstance(data, dict):
        raise SpecError(f"{source}: expected a table at top level")
    extra = [(row, t) for row in SOURCES.values() for t in row.extra_tables]
    top_known = {"name", "description", "route_m", "material_overrides", *SOURCES,
                 *(t.name for _, t in extra), *ITEM_TABLES}
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
    kwargs["source_tables"] = {name: row.read_table(data[name], f"{source}: [{name}]")
                               for name, row in SOURCES.items() if name in data}
    for row, t in extra:
        if t.name in data:
            if row.name not in data:
                why = f" ({t.what})" if t.what else ""
                raise SpecError(f"{source}: [{t.name}] needs a [{row.name}]{why}")
            kwargs[t.attr] = t.parse(data[t.name], f"{source}: [{t.name}]")
    if len(kwargs["source_tables"]) != 1:
        raise SpecError(
            f"{source}: exactly one of {', '.join(f'[{n}]' for n in SOURCES)} is needed, got "
            f"{list(kwargs['source_tables']) or 'none'}"
        )
    for table, (attr, cls) in ITEM_TABLES.items():
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


def save_spec(spec: SceneSpec, path: str | Path) -> Path:
    """Write ``spec`` as TOML (temporary file renamed into place); returns the path."""
    path = Path(path)
    data = tomli_w.dumps(spec_to_dict(spec)).encode()
    return atomic_write_bytes(path, data)
