"""Building scenes from specs and loading them by bundled name or file path."""

from __future__ import annotations

from dataclasses import dataclass
from importlib import resources
from pathlib import Path

import numpy as np

from scenes.scene import Scene
from scenes.sources import SOURCES, file_suffixes, source_of_file, source_of_spec
from scenes.spec import SceneSpec
from scenes.spec_toml import load_spec, overrides_metadata, spec_to_dict

__all__ = ["SceneSummary", "build", "bundled_path", "check_source", "list_bundled", "load", "summarize"]


def _data_dir() -> Path:
    return Path(str(resources.files("scenes") / "data"))


def _bundled_suffixes() -> list[str]:
    """``.toml``, then the suffixes of the sources whose files are bundled scenes of their own."""
    return [".toml", *(row.bundled_suffix for row in SOURCES.values() if row.bundled_suffix)]


def list_bundled() -> list[str]:
    """Names of the bundled scenes (``scenes/data/<name>.toml``, and files of a source
    bundled on their own: ROS maps ``<name>.yaml``), sorted."""
    names = {p.stem for p in _data_dir().glob("*.toml") if not p.name.endswith(".tags.toml")}
    for suffix in _bundled_suffixes()[1:]:
        names |= {p.stem for p in _data_dir().glob(f"*{suffix}")}
    return sorted(names)


def bundled_path(name: str) -> Path:
    """Path of bundled scene ``name``'s TOML spec (or of its file, a bundled map's YAML).

    Raises
    ------
    ValueError
        If there is no such bundled scene (the known names are listed).
    """
    for suffix in _bundled_suffixes():
        path = _data_dir() / f"{name}{suffix}"
        if path.is_file():
            return path
    raise ValueError(f"unknown bundled scene {name!r}; bundled scenes: {', '.join(list_bundled())}")


def build(spec: SceneSpec) -> Scene:
    """Build the :class:`Scene` a :class:`~scenes.spec.SceneSpec` describes.

    Its source table's row of :data:`scenes.sources.SOURCES` builds it (a ``[corridor]``
    is generated, :func:`scenes.generator.build_corridor`; a ``[mesh]`` or ``[mitsuba]``
    file is loaded relative to the spec's folder and the spec's tags placed on it, its
    ``radio_geometry`` saying what the tracer sees; a ``[map]`` is extracted,
    :mod:`scenes.mapscene`); ``metadata`` gets the spec and its material overrides.
    """
    scene = source_of_spec(spec).build(spec)
    scene.metadata.update({"spec": spec_to_dict(spec), **overrides_metadata(spec)})
    return scene


def load(name_or_path: str | Path, **kwargs) -> Scene:
    """Load a scene by bundled name, scene TOML, or a file a scene source reads.

    Parameters
    ----------
    name_or_path : str or Path
        ``"corridor_lab"`` (see :func:`list_bundled`), ``*.toml`` spec, or a file with a
        suffix of a row of :data:`scenes.sources.SOURCES`: ``*.xml`` Mitsuba scene,
        ``*.yaml`` ROS map_server map (:mod:`scenes.mapscene`; ``kwargs`` go to
        :class:`scenes.mapspec.MapSpec`), or a mesh file (``.ply``, ``.obj``, ``.glb`` ...;
        pass ``material=`` or ``material_map=``).
    **kwargs
        Passed to the source's file loader (:func:`scenes.importers.import_mesh`,
        :func:`scenes.importers.load_mitsuba_xml`, e.g. ``tags=``).

    Raises
    ------
    FileNotFoundError
        A path (it has a suffix or a folder) that does not exist.
    ValueError
        A bare name that is not a bundled scene; a suffix no source reads.
    """
    text = str(name_or_path)
    path = Path(text)
    suffix = path.suffix.lower()
    looks_like_path = bool(suffix) or len(path.parts) > 1
    if not looks_like_path:
        path = bundled_path(text)
        if path.suffix == ".toml":
            return build(load_spec(path))
        return source_of_file(path).load_file(path, **kwargs)
    if not path.is_file():
        raise FileNotFoundError(f"scene file {text!r} "
                                + ("is a directory, not a file" if path.is_dir() else "does not exist"))
    if suffix == ".toml":
        return build(load_spec(path))
    source = source_of_file(path)
    if source is None or source.load_file is None:
        raise ValueError(f"{text}: unsupported scene file type {suffix!r} (.toml, "
                         f"{', '.join(file_suffixes())})")
    return source.load_file(path, **kwargs)


def check_source(name_or_path: str | Path) -> None:
    """Read the file behind a scene reference cheaply, if its source checks one: before a run.

    ``name_or_path`` as for :func:`scenes.load`; a file of a source with a
    :attr:`~scenes.sources.SceneSource.precheck` (a ``.yaml`` map), a scene TOML whose
    source table names such a file (``[map]``) or such a bundled scene has its TOML (if
    any) and its file read, so a bad map stops with its one-line error before anything is
    written. Other scenes pass.

    Raises
    ------
    scenes.rosmap.RosMapError, SpecError, FileNotFoundError
    """
    text = str(name_or_path)
    p = Path(text)
    if not p.suffix and len(p.parts) == 1:
        try:
            p = bundled_path(text)
        except ValueError:
            return
    if p.suffix.lower() == ".toml":
        if p.is_file():
            spec = load_spec(p)
            source = source_of_spec(spec)
            if source.precheck is not None and source.file_of(spec) is not None:
                source.precheck(source.file_of(spec))
        return
    source = source_of_file(p)
    if source is not None and source.precheck is not None:
        source.precheck(p)


@dataclass(frozen=True)
class SceneSummary:
    """A scene at a glance (for ``rfidstudy scenes list/show`` and reports).

    Attributes
    ----------
    name : str
        Scene name.
    source : str
        Where it came from.
    size_m : tuple of float
        Extent of all meshes along x, y, z, metres.
    n_tags : int
        Number of tags.
    n_triangles : int
        Triangles over all meshes.
    triangles_per_material : dict of str to int
        Triangles per material.
    route_length_m : float
        Length of the robot route, metres (0 if none).
    tag_height_range_m : tuple of float
        Lowest and highest tag centre, metres (NaN if no tags).
    """

    name: str
    source: str
    size_m: tuple[float, float, float]
    n_tags: int
    n_triangles: int
    triangles_per_material: dict[str, int]
    route_length_m: float
    tag_height_range_m: tuple[float, float]


def summarize(scene: Scene) -> SceneSummary:
    """The :class:`SceneSummary` of ``scene``."""
    lo, hi = scene.bounds_m
    tri = {name: len(scene.meshes[name].faces) for name in scene.materials}
    route = 0.0
    if scene.route_m is not None and len(scene.route_m) > 1:
        route = float(np.linalg.norm(np.diff(scene.route_m, axis=0), axis=1).sum())
    z = scene.tags.positions_m[:, 2]
    heights = (float(z.min()), float(z.max())) if len(z) else (float("nan"), float("nan"))
    return SceneSummary(scene.name, scene.source, tuple(float(v) for v in hi - lo), len(scene.tags),
                        sum(tri.values()), tri, route, heights)
