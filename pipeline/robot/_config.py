"""Typed-config helper: build a dataclass from a mapping, rejecting unknown keys by name."""

from __future__ import annotations

import dataclasses
from collections.abc import Mapping
from typing import Any, TypeVar

__all__ = ["config_from_dict"]

T = TypeVar("T")


def config_from_dict(cls: type[T], data: Mapping[str, Any], where: str = "") -> T:
    """Instantiate the dataclass ``cls`` from ``data``.

    Parameters
    ----------
    cls : type
        A dataclass type.
    data : Mapping[str, Any]
        Keys are field names of ``cls``.
    where : str
        Context for error messages (file name or TOML table).

    Raises
    ------
    ValueError
        If ``data`` holds a key that is not a field of ``cls``; the message names the key,
        the class and ``where``.
    """
    names = {f.name for f in dataclasses.fields(cls)}
    unknown = sorted(set(data) - names)
    if unknown:
        ctx = f" in {where}" if where else ""
        raise ValueError(
            f"unknown key(s) {unknown} for {cls.__name__}{ctx}; valid keys are {sorted(names)}"
        )
    return cls(**dict(data))
