"""Typed configuration machinery: dataclass trees read from and written to TOML.

A configuration section is a dataclass whose every field is declared with
:func:`option`, which carries the field's one-line documentation. From that one
source this module

* builds each section's numpydoc ``Attributes`` docstring (:func:`section`);
* reads a nested dict (parsed TOML) into the dataclass tree, rejecting unknown keys
  by name and wrong types by key, expected type and received value
  (:func:`from_dict`, values through :func:`scenes.schema.convert_value`, the
  converter the scene specs use too), every message prefixed with the file it came from;
* writes the tree back to a dict (:func:`to_dict`) and to a commented reference
  TOML with every key, its default and its documentation (:func:`reference_toml`).

Supported field types: ``bool``, ``int``, ``float`` (an int is accepted),
``str``, ``X | None`` (TOML has no null: a missing key means the default, and the
string ``""`` stands for ``None`` where a string-like option may be absent),
``list[T]`` / ``tuple[T, ...]`` of those, nested sections and ``list[Section]``
(TOML arrays of tables).
"""

from __future__ import annotations

import dataclasses
import types
import typing
from typing import Any

from scenes.schema import ValueTypeError, convert_value

__all__ = [
    "ConfigError",
    "UnknownKeyError",
    "check_bounds",
    "check_keys",
    "from_dict",
    "option",
    "reference_toml",
    "section",
    "to_dict",
]


class ConfigError(ValueError):
    """A configuration file or value is invalid; the message names file and key."""


class UnknownKeyError(ConfigError, KeyError):
    """A mapping holds a key its dataclass does not know (a ``ValueError`` and a ``KeyError``)."""

    def __str__(self) -> str:  # the message, not KeyError's quoted repr
        return ValueError.__str__(self)


def check_keys(data, allowed, where: str, required=()) -> None:
    """Reject keys of ``data`` not in ``allowed``, and missing ``required`` keys.

    Parameters
    ----------
    data : Mapping
        The mapping read from a file (TOML table, JSON object).
    allowed : iterable of str
        Accepted keys.
    where : str
        File and table, prefixed to the message (e.g. ``"study.toml: [acquisition]"``).
    required : iterable of str
        Keys that must be present.

    Raises
    ------
    ConfigError
        ``data`` is not a mapping, or a required key is missing (named).
    UnknownKeyError
        Naming every unknown key and listing the accepted ones.
    """
    if not isinstance(data, dict):
        raise ConfigError(f"{where}: expected a table, got {type(data).__name__} {data!r}")
    unknown = sorted(set(data) - set(allowed))
    if unknown:
        raise UnknownKeyError(
            f"{where}: unknown key(s) {unknown}; known keys: {', '.join(sorted(allowed))}"
        )
    missing = sorted(set(required) - set(data))
    if missing:
        raise ConfigError(f"{where}: missing key(s) {missing}")


def option(default: Any = dataclasses.MISSING, doc: str = "", *, factory: Any = None,
           max: float | None = None):  # noqa: A002 - reads as the bound it is
    """Declare a configuration field with its documentation.

    Parameters
    ----------
    default : object
        Default value (immutable); use ``factory`` for lists and sections.
    doc : str
        One-line description, with the unit; shown in ``--help`` and reference.toml.
    factory : callable, optional
        Default factory (for mutable defaults).
    max : float, optional
        Upper bound of a size-like value (a count, a number of rays or of iterations),
        or of a list's length; checked when the section is built, before any work, so
        that a typo of a few zeros stops at once with the key named instead of running
        for days or exhausting the memory. Shown in the reference config.
    """
    meta = {"doc": doc}
    if max is not None:
        meta["max"] = max
        meta["doc"] = f"{doc} At most {max:,}." if doc else f"At most {max:,}."
    if factory is not None:
        return dataclasses.field(default_factory=factory, metadata=meta)
    return dataclasses.field(default=default, metadata=meta)


def _type_name(tp: Any) -> str:
    origin = typing.get_origin(tp)
    if origin in (typing.Union, types.UnionType):
        return " | ".join(_type_name(a) for a in typing.get_args(tp))
    if origin in (list, tuple):
        args = [a for a in typing.get_args(tp) if a is not Ellipsis]
        return f"list of {_type_name(args[0])}" if args else "list"
    if origin is typing.Literal:
        return " | ".join(repr(a) for a in typing.get_args(tp))
    if tp is type(None):
        return "None"
    if dataclasses.is_dataclass(tp):
        return f"table [{tp.__name__}]"
    return getattr(tp, "__name__", str(tp))


def check_bounds(obj) -> None:
    """Raise :class:`ConfigError` naming the first field of ``obj`` above its ``max``."""
    for f in dataclasses.fields(obj):
        bound = f.metadata.get("max")
        if bound is None:
            continue
        v = getattr(obj, f.name)
        size = len(v) if isinstance(v, (list, tuple)) else v
        if isinstance(size, (int, float)) and not isinstance(size, bool) and size > bound:
            what = f"has {size:,} entries" if isinstance(v, (list, tuple)) else f"= {v!r}"
            raise ConfigError(f"{f.name} {what}: more than its upper bound {bound:,} (a size "
                              "this tool refuses before any work; see the reference config)")


def section(cls):
    """Class decorator: a frozen dataclass whose docstring lists every field's doc, and
    whose fields' upper bounds (``option(max=...)``) are checked on construction."""
    post = getattr(cls, "__post_init__", None)

    def __post_init__(self):
        check_bounds(self)
        if post is not None:
            post(self)

    cls.__post_init__ = __post_init__
    cls = dataclasses.dataclass(frozen=True)(cls)
    hints = typing.get_type_hints(cls)
    lines = [(cls.__doc__ or "").rstrip(), "", "Attributes", "----------"]
    for f in dataclasses.fields(cls):
        lines.append(f"{f.name} : {_type_name(hints[f.name])}")
        lines.append(f"    {f.metadata.get('doc', '')}")
    cls.__doc__ = "\n".join(lines) + "\n"
    return cls


def _fail(source: str, key: str, msg: str) -> ConfigError:
    return ConfigError(f"{source}: {key}: {msg}")


def from_dict(cls, data: dict, source: str = "<config>", prefix: str = ""):
    """Build a section dataclass from a nested dict, validating keys and types.

    Values are checked and converted by the one converter of this project,
    :func:`scenes.schema.convert_value` (shared with the scene specs); nested sections
    and arrays of tables are read by this function, recursively.

    Parameters
    ----------
    cls : type
        A :func:`section` dataclass.
    data : dict
        Parsed TOML (missing keys take their defaults).
    source : str
        File name (or description) prefixed to every error message.
    prefix : str
        Dotted key of this section inside the file (for messages).

    Raises
    ------
    ConfigError
        On an unknown key (named, with the known keys listed), a wrong type, or a
        value the section's ``__post_init__`` rejects.
    """
    if not isinstance(data, dict):
        raise _fail(source, prefix or "<root>", f"expected a table, got {type(data).__name__}")
    hints = typing.get_type_hints(cls)
    names = [f.name for f in dataclasses.fields(cls)]

    def table(tp, value, key):
        return from_dict(tp, value, source, key)

    kwargs = {}
    for key, value in data.items():
        dotted = f"{prefix}.{key}" if prefix else key
        if key not in names:
            where = f"section [{prefix}]" if prefix else "the top level"
            raise UnknownKeyError(
                f"{source}: {dotted}: unknown key {key!r} in {where}; known keys: {', '.join(names)}"
            )
        try:
            kwargs[key] = convert_value(value, hints[key], dotted, empty_is_none=True, table=table)
        except ValueTypeError as exc:
            raise _fail(source, exc.key, exc.problem) from None
    try:
        return cls(**kwargs)
    except ConfigError as exc:
        raise _fail(source, prefix or "<root>", str(exc)) from None
    except (TypeError, ValueError) as exc:
        raise _fail(source, prefix or "<root>", str(exc)) from None


def to_dict(obj) -> dict:
    """Section dataclass tree -> nested dict of TOML-able values (``None`` dropped)."""
    out = {}
    for f in dataclasses.fields(obj):
        v = getattr(obj, f.name)
        if v is None:
            continue
        if dataclasses.is_dataclass(v):
            out[f.name] = to_dict(v)
        elif isinstance(v, (list, tuple)):
            out[f.name] = [to_dict(x) if dataclasses.is_dataclass(x) else x for x in v]
        else:
            out[f.name] = v
    return out


def _toml_value(v: Any) -> str:
    import tomli_w

    if isinstance(v, (list, tuple)):
        return "[" + ", ".join(_toml_value(x) for x in v) + "]"
    return tomli_w.dumps({"x": v}).split("=", 1)[1].strip()


def reference_toml(obj, header: str = "") -> str:
    """A commented TOML document listing every key of ``obj`` with its value and doc.

    Parameters
    ----------
    obj : dataclass instance
        The section tree (normally the defaults).
    header : str
        Comment lines put on top (without ``#``).

    Returns
    -------
    str
        TOML text that :func:`from_dict` reads back to ``obj``. Keys whose value is
        ``None`` are written commented out.
    """
    lines = [f"# {h}".rstrip() for h in header.splitlines()] if header else []

    def emit(o, table: str | None, array: bool = False):
        scalars, subs = [], []
        for f in dataclasses.fields(o):
            v = getattr(o, f.name)
            doc = f.metadata.get("doc", "")
            is_tables = isinstance(v, (list, tuple)) and v and dataclasses.is_dataclass(v[0])
            if dataclasses.is_dataclass(v) or is_tables:
                subs.append((f, v))
            else:
                scalars.append((f, v, doc))
        if table is not None:
            if lines and lines[-1] != "" and not (array and lines[-1].startswith("# ")):
                lines.append("")
            lines.append(f"[[{table}]]" if array else f"[{table}]")
            if not array and o.__doc__:
                lines.insert(len(lines) - 1, f"# {o.__doc__.strip().splitlines()[0]}")
        for f, v, doc in scalars:
            lines.append(f"# {doc}")
            if v is None:
                lines.append(f"# {f.name} =  (unset)")
            else:
                lines.append(f"{f.name} = {_toml_value(v)}")
        for f, v in subs:
            name = f"{table}.{f.name}" if table else f.name
            if dataclasses.is_dataclass(v):
                emit(v, name)
            else:
                lines.append("")
                lines.append(f"# {f.metadata.get('doc', '')}")
                for item in v:
                    emit(item, name, array=True)

    emit(obj, None)
    return "\n".join(lines).rstrip() + "\n"
