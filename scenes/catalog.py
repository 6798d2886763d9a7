"""Building scenes from specs and loading them by bundled name or file path."""

from __future__ import annotations

from importlib import resources
from pathlib import Path

from scenes.generator import build_corridor
from scenes.importers import MESH_SUFFIXES, import_mesh, load_mitsuba_xml
from scenes.scene import Scene
from scenes.spec import SceneSpec, load_spec

__all__ = ["build", "load", "list_bundled", "bundled_path"]


def _data_dir() -> Path:
    return Path(str(resources.files("scenes") / "data"))


def list_bundled() -> list[str]:
    """Names of the bundled scenes (``scenes/data/<name>.toml``), sorted."""
    return sorted(p.stem for p in _data_dir().glob("*.toml") if not p.name.endswith(".tags.toml"))


def bundled_path(name: str) -> Path:
    """Path of bundled scene ``name``'s TOML spec.

    Raises
    ------
    ValueError
        If there is no such bundled scene (the known names are listed).
    """
    path = _data_dir() / f"{name}.toml"
    if not path.is_file():
        raise ValueError(f"unknown bundled scene {name!r}; bundled scenes: {', '.join(list_bundled())}")
    return path


def build(spec: SceneSpec) -> Scene:
    """Build the :class:`Scene` a :class:`~scenes.spec.SceneSpec` describes.

    A ``[corridor]`` spec is generated (:func:`scenes.generator.build_corridor`); a
    ``[mesh]`` or ``[mitsuba]`` spec loads its file (relative to the spec's folder) and
    places the spec's tags on it.
    """
    if spec.corridor is not None:
        return build_corridor(spec)
    base = Path(spec.base_dir)
    route = spec.route_m
    if spec.mesh is not None:
        return import_mesh(base / spec.mesh.path, material=spec.mesh.material,
                           material_map=spec.mesh.material_map, tags=spec.tags, name=spec.name,
                           route_m=route)
    return load_mitsuba_xml(base / spec.mitsuba.path, tags=spec.tags, route_m=route, name=spec.name)


def load(name_or_path: str | Path, **kwargs) -> Scene:
    """Load a scene by bundled name, scene TOML, Mitsuba XML or mesh file.

    Parameters
    ----------
    name_or_path : str or Path
        ``"corridor_lab"`` (see :func:`list_bundled`), ``*.toml`` spec, ``*.xml`` Mitsuba
        scene, or a mesh file (``.ply``, ``.obj``, ``.glb`` ...; pass ``material=`` or
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
        return build(load_spec(bundled_path(text)))
    if not path.is_file():
        raise FileNotFoundError(f"scene file {text!r} does not exist")
    if suffix == ".toml":
        return build(load_spec(path))
    if suffix == ".xml":
        return load_mitsuba_xml(path, **kwargs)
    if suffix in MESH_SUFFIXES:
        return import_mesh(path, **kwargs)
    raise ValueError(f"{text}: unsupported scene file type {suffix!r} (.toml, .xml, "
                     f"{', '.join(MESH_SUFFIXES)})")
