"""Named sets of study keys the command line applies for a kind of input.

``<name>.toml`` (:func:`load_profile`); a scene source names the one a file of its own
runs with (:attr:`scenes.sources.SceneSource.run_profile`). ``map_scale.toml``: what
``rfidstudy run MAP.yaml`` sets for an occupancy-grid map given alone
(:func:`map_scale_profile`).
"""

from __future__ import annotations

import tomllib
from importlib.resources import files

__all__ = ["load_profile", "map_scale_profile"]


def load_profile(name: str) -> dict:
    """The study keys of profile ``name`` (``pipeline/apps/profiles/<name>.toml``), as a fresh
    nested dict the caller may change."""
    return tomllib.loads(files("pipeline.apps.profiles").joinpath(f"{name}.toml").read_text("utf-8"))


def map_scale_profile() -> dict:
    """The study keys ``rfidstudy run MAP.yaml`` sets for a map given alone
    (``pipeline/apps/profiles/map_scale.toml``: a building of 30 x 50 m in minutes), as a fresh
    nested dict the caller may change."""
    return load_profile("map_scale")
