"""Typed values from TOML: the one converter of scene specs and of the study config.

:func:`convert_value` checks a parsed TOML value against a type annotation and converts
it (arrays become tuples, an integer where a float is expected becomes a float). On a
mismatch it raises :class:`ValueTypeError`, which carries the key and the problem
(``must be a number, got 'wide'``); each caller puts its own file and table in front
(``scenes.spec``: ``"scene.toml: [corridor]: key 'width_m' must be a number, got
'wide'"``; ``pipeline.configschema``: ``"study.toml: tracing.max_depth: must be an
integer, got 'five'"``).

It lives in ``scenes`` because both ``scenes`` and ``pipeline`` need it and the
dependencies point ``pipeline -> scenes`` only; it uses nothing but the standard library.

Supported annotations: ``bool``, ``int``, ``float`` (finite; an int is accepted),
``str``, ``typing.Any``, ``X | None``, ``X | Y`` (the first that fits),
``tuple[T, ...]`` / ``list[T]`` (any length), ``tuple[A, B]`` (that many elements),
``dict[str, T]``, and dataclasses (through the caller's ``table`` hook).
"""

from __future__ import annotations

import dataclasses
import math
import types
import typing
from collections.abc import Callable
from typing import Any

__all__ = ["ValueTypeError", "convert_value", "type_phrase"]


class ValueTypeError(ValueError):
    """A value does not fit its annotation.

    Attributes
    ----------
    key : str
        The key (``"width_m"``, ``"tracing.max_depth"``, ``"lane_fractions[1]"``).
    problem : str
        What is wrong, as a phrase following the key (``"must be a number, got 'wide'"``).
    """

    def __init__(self, key: str, problem: str):
        self.key = key
        self.problem = problem
        super().__init__(f"key {key!r} {problem}")


def _is_number(v) -> bool:
    return isinstance(v, (int, float)) and not isinstance(v, bool)


def type_phrase(tp: Any) -> str:
    """What a value of annotation ``tp`` must be, as a phrase: ``"a number"``, ``"an array"``."""
    origin = typing.get_origin(tp)
    if origin in (typing.Union, types.UnionType):
        return " or ".join(type_phrase(a) for a in typing.get_args(tp) if a is not type(None))
    if origin in (list, tuple):
        return "an array"
    if origin is typing.Literal:
        return "one of " + ", ".join(repr(a) for a in typing.get_args(tp))
    if origin is dict:
        args = typing.get_args(tp)
        return "a table of strings" if len(args) == 2 and args[1] is str else "a table"
    if dataclasses.is_dataclass(tp):
        return "a table"
    return {bool: "true or false", int: "an integer", float: "a number", str: "a string"}.get(
        tp, getattr(tp, "__name__", str(tp)))


def convert_value(value: Any, tp: Any, key: str, *, empty_is_none: bool = False,
                  table: Callable[[type, Any, str], Any] | None = None) -> Any:
    """Check ``value`` against the annotation ``tp`` and convert it.

    Parameters
    ----------
    value : object
        A parsed TOML value (or a Python value of the same kinds).
    tp : type annotation
        What it must be (see the module docstring).
    key : str
        Its key, for messages; array elements are named ``key[i]``.
    empty_is_none : bool
        ``""`` stands for ``None`` where ``tp`` allows ``None`` and is not string-like
        (TOML has no null).
    table : callable, optional
        ``table(cls, value, key)`` builds a dataclass ``cls`` from a table (the caller's
        own reader, with its own key checks); without it a dataclass annotation only
        accepts an instance.

    Returns
    -------
    object
        The converted value (tuples for arrays, floats for numbers of a float key).

    Raises
    ------
    ValueTypeError
        Naming the key, what it must be and the value received.
    """
    origin = typing.get_origin(tp)
    args = typing.get_args(tp)
    if origin in (typing.Union, types.UnionType):
        if value is None and type(None) in args:
            return None
        options = [a for a in args if a is not type(None)]
        if empty_is_none and value == "" and type(None) in args and str not in options:
            return None
        if len(options) == 1:
            return convert_value(value, options[0], key, empty_is_none=empty_is_none, table=table)
        for a in options:
            try:
                return convert_value(value, a, key, empty_is_none=empty_is_none, table=table)
            except ValueTypeError:
                continue
        raise ValueTypeError(key, f"must be {type_phrase(tp)}, got {value!r}")
    if origin is typing.Literal:
        if value not in args:
            raise ValueTypeError(key, f"must be {type_phrase(tp)}, got {value!r}")
        return value
    if origin in (list, tuple):
        if not isinstance(value, (list, tuple)):
            raise ValueTypeError(key, f"must be an array, got {value!r}")
        if any(_is_number(v) and not math.isfinite(v) for v in value):
            raise ValueTypeError(key, f"must hold finite numbers, got {list(value)!r}")
        inner = [a for a in args if a is not Ellipsis]
        if origin is tuple and len(args) >= 1 and Ellipsis not in args:  # fixed length
            if len(value) != len(args):
                raise ValueTypeError(key, f"must have {len(args)} elements, got {value!r}")
            kinds = list(args)
        else:
            kinds = [inner[0] if inner else Any] * len(value)
        return tuple(convert_value(v, a, f"{key}[{i}]", empty_is_none=empty_is_none, table=table)
                     for i, (v, a) in enumerate(zip(value, kinds, strict=True)))
    if origin is dict:
        vtype = args[1] if len(args) == 2 else Any
        bad = ValueTypeError(key, f"must be {type_phrase(tp)}, got {value!r}")
        if not isinstance(value, dict) or not all(isinstance(k, str) for k in value):
            raise bad
        try:
            return {k: convert_value(v, vtype, f"{key}.{k}") for k, v in value.items()}
        except ValueTypeError:
            raise bad from None
    if dataclasses.is_dataclass(tp) and isinstance(tp, type):
        if isinstance(value, tp):
            return value
        if table is None:
            raise ValueTypeError(key, f"must be a {tp.__name__}, got {value!r}")
        return table(tp, value, key)
    if tp is Any:
        return value
    if tp is bool:
        if not isinstance(value, bool):
            raise ValueTypeError(key, f"must be true or false, got {value!r}")
        return value
    if tp is int:
        if not isinstance(value, int) or isinstance(value, bool):
            raise ValueTypeError(key, f"must be an integer, got {value!r}")
        return value
    if tp is float:
        if not _is_number(value):
            raise ValueTypeError(key, f"must be a number, got {value!r}")
        if not math.isfinite(value):
            raise ValueTypeError(key, f"must be a finite number, got {value!r}")
        return float(value)
    if tp is str:
        if not isinstance(value, str):
            raise ValueTypeError(key, f"must be a string, got {value!r}")
        return value
    raise TypeError(f"unsupported annotation {tp!r} for key {key!r}")  # programming error
