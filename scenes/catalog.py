"""Building scenes from specs and loading them by bundled name or file path."""

from __future__ import annotations

from dataclasses import dataclass
from importlib import resources
from pathlib import Path

import numpy as np

from scenes.generator import build_corridor
from scenes.importers import MESH_SUFFIXES, import_mesh, load_mitsuba_xml
from scenes.mapscene import build_map_scene, load_map
from scenes.rosmap import read_map
from scenes.scene import Scene
from scenes.spec import SceneSpec
from scenes.spec_toml import load_spec, overrides_metadata, spec_to_dict

__all__ = ["SceneSummary", "build", "bundled_path", "check_map_source", "list_bundled", "load", "summarize"]


def _data_dir() -> Path:
    return Path(str(resources.files("scenes") / "data"))


def list_bundled() -> list[str]:
    """Names of the bundled scenes (``scenes/data/<name>.toml`` and ROS maps ``<name>.yaml``), sorted."""
    names = {p.stem for p in _data_dir().glob("*.toml") if not p.name.endswith(".tags.toml")}
    return sorted(names | {p.stem for p in _data_dir().glob("*.yaml")})


def bundled_path(name: str) -> Path:
    """Path of bundled scene ``name``'s TOML spec.

    Raises
    ------
    ValueError
        If there is no such bundled scene (the known names are listed).
    """
    path = _data_dir() / f"{name}.toml"
    if not path.is_file():
        path = _data_dir() / f"{name}.yaml"
    if not path.is_file():
        raise ValueError(f"unknown bundled scene {name!r}; bundled scenes: {', '.join(list_bundled())}")
    return path


def build(spec: SceneSpec) -> Scene:
    """Build the :class:`Scene` a :class:`~scenes.spec.SceneSpec` describes.

    A ``[corridor]`` spec is generated (:func:`scenes.generator.build_corridor`); a
    ``[mesh]`` or ``[mitsuba]`` spec loads its file (relative to the spec's folder) and
    places the spec's tags on it; its ``radio_geometry`` says what the tracer sees.
    """
    if spec.corridor is not None:
        return build_corridor(spec)
    if spec.map is not None:
        scene = build_map_scene(spec.map, name=spec.name, base_dir=spec.base_dir, tags=spec.tags,
                                tag_layout=spec.tag_layout, route_m=spec.route_m,
                                source=spec.source or spec.name,
                                material_overrides=overrides_metadata(spec).get("material_overrides"))
        scene.metadata["spec"] = spec_to_dict(spec)
        return scene
    base = Path(spec.base_dir)
    route = spec.route_m
    src = spec.mesh if spec.mesh is not None else spec.mitsuba
    radio = {"radio_geometry": src.radio_geometry, "thin_box_max_m": src.thin_box_max_m,
             "thin_box_face": src.thin_box_face}
    if spec.mesh is not None:
        scene = import_mesh(base / spec.mesh.path, material=spec.mesh.material,
                            material_map=spec.mesh.material_map, tags=spec.tags, name=spec.name,
                            route_m=route, **radio)
    else:
        scene = load_mitsuba_xml(base / spec.mitsuba.path, tags=spec.tags, route_m=route,
                                 name=spec.name, **radio)
    scene.metadata.update({"spec": spec_to_dict(spec), **overrides_metadata(spec)})
    return scene


def load(name_or_path: str | Path, **kwargs) -> Scene:
    """Load a scene by bundled name, scene TOML, Mitsuba XML or mesh file.

    Parameters
    ----------
    name_or_path : str or Path
        ``"corridor_lab"`` (see :func:`list_bundled`), ``*.toml`` spec, ``*.xml`` Mitsuba
        scene, ``*.yaml`` ROS map_server map (:mod:`scenes.mapscene`; ``kwargs`` go to
        :class:`scenes.mapspec.MapSpec`), or a mesh file (``.ply``, ``.obj``, ``.glb`` ...; pass ``material=`` or
        ``material_map=``).
    **kwargs
        Passed to :func:`scenes.importers.import_mesh` or
        :func:`scenes.importers.load_mitsuba_xml` (e.g. ``tags=``).

    Raises
    ------
    FileNotFoundError
        A path (it has a suffix or a folder) that does not exist.
    ValueError
        A bare name that is not a bundled scene.
    """
    text = str(name_or_path)
    path = Path(text)
    suffix = path.suffix.lower()
    looks_like_path = bool(suffix) or len(path.parts) > 1
    if not looks_like_path:
        path = bundled_path(text)
        if path.suffix == ".yaml":
            return load_map(path, **kwargs)
        return build(load_spec(path))
    if not path.is_file():
        raise FileNotFoundError(f"scene file {text!r} "
                                + ("is a directory, not a file" if path.is_dir() else "does not exist"))
    if suffix == ".toml":
        return build(load_spec(path))
    if suffix == ".xml":
        return load_mitsuba_xml(path, **kwargs)
    if suffix in (".yaml", ".yml"):
        return load_map(path, **kwargs)
    if suffix in MESH_SUFFIXES:
        return import_mesh(path, **kwargs)
    raise ValueError(f"{text}: unsupported scene file type {suffix!r} (.toml, .xml, .yaml, "
                     f"{', '.join(MESH_SUFFIXES)})")


def check_map_source(name_or_path: str | Path) -> None:
    """Read the map behind a scene reference, if there is one: a cheap check before a run.

    ``name_or_path`` as for :func:`scenes.load`; a ``.yaml`` map, a scene TOML with
    ``[map]`` or a bundled map scene has its TOML (if any) and its map read, so a bad map
    stops with its one-line error before anything is written. Other scenes pass.

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
    if p.suffix.lower() in (".yaml", ".yml"):
        read_map(p)
    elif p.suffix.lower() == ".toml" and p.is_file():
        spec = load_spec(p)
        if spec.map is not None:
            base = Path(spec.base_dir)
            read_map(Path(spec.map.path) if Path(spec.map.path).is_absolute() else base / spec.map.path)


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
