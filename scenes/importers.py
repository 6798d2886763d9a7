"""Scenes from files: mesh import (PLY, OBJ, GLB/GLTF, STL) and Mitsuba/Sionna XML scenes.

Both group every surface by material into one mesh per material (Sionna assigns one
radio material per shape). Mitsuba XML is read with :mod:`xml.etree` only: this
package never imports sionna, mitsuba or drjit. Materials named like Sionna's ITU
materials (``itu_concrete``, ``mat-itu_concrete``, an ``itu-radio-material`` whose
``type`` is ``concrete``) and our own export ids (``uhf-concrete``) map onto the UHF
library through :func:`scenes.materials.resolve_material_name` (a thickness suffix such
as ``uhf-brick-t0p120`` is dropped).

What a closed mesh means to the ray tracer
------------------------------------------
Sionna RT applies the ITU-R P.2040 slab model (a slab of the radio material's
thickness) at *every* face a path crosses. An imported wall modelled as a closed box is
crossed twice, so its material counts twice (0.12 m of brick: -7.5 dB instead of
-3.7 dB at 865 MHz), and its back face adds a ghost reflection. ``radio_geometry=``
chooses what is traced (:mod:`scenes.radio_import`, ``docs/radio_geometry.md``):

- ``"as_is"`` (default): the meshes as they are, each face with its material's library
  thickness; ``Scene.radio_surfaces`` is ``None``. Right for files that model each layer
  as one surface; a closed box counts twice.
- ``"single"``: a declaration that the file holds one surface per physical layer; each
  part is traced with its material's thickness (for Mitsuba XML, the ``thickness`` of
  its radio material when given, e.g. a file written by :func:`scenes.export_mitsuba`).
- ``"thin_boxes"``: closed axis-aligned boxes whose smallest extent is below
  ``thin_box_max_m`` become one rectangle on ``thin_box_face`` carrying that extent as
  thickness; rotated boxes, thick boxes (furniture) and any other shape stay as they are.

Geometric queries (tags, free space, the robot's laser) always use the meshes as loaded.
"""

from __future__ import annotations

import logging
import re
import xml.etree.ElementTree as ET
from pathlib import Path

import numpy as np
import trimesh

from scenes.geometry import merge_meshes
from scenes.materials import UnknownMaterialError, resolve_material_name
from scenes.radio_import import imported_radio_surfaces
from scenes.scene import Scene, TagSet
from scenes.spec import SpecError, TagSpec, convert_value, item_where, parse_item
from scenes.tags import make_tags, validate_tags

try:  # Python >= 3.11
    import tomllib
except ModuleNotFoundError:  # pragma: no cover - Python 3.10
    import tomli as tomllib

__all__ = ["MESH_SUFFIXES", "import_mesh", "load_mitsuba_xml", "read_sidecar"]

logger = logging.getLogger(__name__)

#: File suffixes :func:`import_mesh` reads through trimesh.
MESH_SUFFIXES = (".ply", ".obj", ".glb", ".gltf", ".stl", ".off")


def _require_file(path: Path, what: str) -> None:
    if path.is_dir():
        raise FileNotFoundError(f"{what} {str(path)!r} is a directory, not a file")
    if not path.is_file():
        raise FileNotFoundError(f"{what} {str(path)!r} does not exist")


def _load_mesh_file(path: Path, where: str, **kwargs):
    """``trimesh.load`` whose failures name the file (an empty or garbage file raises
    anything from ``IndexError`` to ``ValueError('Not a ply file!')`` inside trimesh)."""
    try:
        return trimesh.load(str(path), **kwargs)
    except Exception as exc:  # noqa: BLE001 - a file trimesh cannot parse, whatever it raises
        what = f"{path}: cannot read it as a mesh" if where == str(path) else \
            f"{where}: cannot read mesh file {path}"
        raise ValueError(f"{what} ({type(exc).__name__}: {exc}); is it empty or not a mesh?") from None


def _require_triangles(mesh, path: Path, where: str):
    """``mesh`` if it is a triangle mesh with finite vertices and at least one face."""
    if not isinstance(mesh, trimesh.Trimesh) or len(mesh.faces) == 0:
        raise ValueError(f"{where}: mesh file {path} holds no triangles (an empty mesh)")
    if not np.all(np.isfinite(mesh.vertices)):
        raise ValueError(f"{where}: mesh file {path} has vertices that are NaN or inf")
    return mesh


def _finish(name, items, source, tags, route_m, metadata, where, radio) -> Scene:
    """Scene from ``items`` = [(material, thickness_m or None, mesh)] and radio options."""
    parts: dict[str, list] = {}
    for mat, _, mesh in items:
        parts.setdefault(mat, []).append(mesh)
    meshes = {mat: merge_meshes(ms) for mat, ms in sorted(parts.items())}
    if not meshes:
        raise ValueError(f"{where}: no triangle geometry found")
    if route_m is not None:
        route = np.asarray(route_m, dtype=float)
        if route.ndim != 2 or route.shape[1] != 2 or len(route) < 2 or not np.all(np.isfinite(route)):
            raise ValueError(f"{where}: route_m must be at least 2 finite (x, y) points, got "
                             f"{np.asarray(route_m).tolist()}")
    try:
        surfaces = imported_radio_surfaces(items, **radio)
    except ValueError as exc:
        raise ValueError(f"{where}: {exc}") from None
    metadata = {**metadata, "radio_geometry": radio["radio_geometry"]}
    if radio["radio_geometry"] == "thin_boxes":
        metadata.update(thin_box_max_m=radio["thin_box_max_m"], thin_box_face=radio["thin_box_face"])
    scene = Scene(
        name=name,
        meshes=meshes,
        tags=TagSet(np.zeros(0, dtype=str), np.zeros((0, 3)), np.zeros((0, 3))),
        source=source,
        metadata=metadata,
        route_m=None if route_m is None else np.asarray(route_m, dtype=float).reshape(-1, 2),
        radio_surfaces=surfaces,
    )
    scene.tags = make_tags(scene, list(tags or ()), f"{where}: tag")
    validate_tags(scene)
    return scene


def import_mesh(
    path: str | Path,
    material: str | None = None,
    material_map: dict[str, str] | None = None,
    tags=(),
    name: str | None = None,
    route_m=None,
    radio_geometry: str = "as_is",
    thin_box_max_m: float = 0.3,
    thin_box_face: str = "inner",
) -> Scene:
    """Import a mesh file as a scene, one mesh per material.

    Parameters
    ----------
    path : str or Path
        PLY, OBJ, GLB/GLTF, STL or OFF file (metres, z up).
    material : str, optional
        Material of every geometry not named in ``material_map``.
    material_map : dict of str to str, optional
        Geometry name or scene-graph node name (a GLB's meshes, an OBJ's objects, a
        single-mesh file's stem) to material name.
    tags : sequence of TagSpec or dict
        Tags on the imported surfaces (see :func:`scenes.tags.make_tags`).
    name : str, optional
        Scene name (default: the file stem).
    route_m : array_like (n, 2), optional
        Robot route polyline.
    radio_geometry : {"as_is", "single", "thin_boxes"}
        What the ray tracer sees (see the module docstring): the meshes as they are
        (default), the meshes declared single surfaces per layer, or thin closed boxes
        turned into one surface each.
    thin_box_max_m : float
        ``"thin_boxes"``: boxes whose smallest extent is below this are converted, m.
    thin_box_face : {"inner", "lower", "upper", "mid"}
        ``"thin_boxes"``: the face carrying the surface (``"inner"``: the one nearer the
        centre of the scene's bounds).

    Raises
    ------
    FileNotFoundError
        If ``path`` does not exist (named).
    UnknownMaterialError
        If a material name is not in the library (named).
    ValueError
        If a geometry has no material, or a ``material_map`` key matches nothing.
    """
    path = Path(path)
    _require_file(path, "mesh file")
    material_map = dict(material_map or {})
    mats = {k: resolve_material_name(v) for k, v in material_map.items()}
    default = resolve_material_name(material) if material is not None else None
    loaded = _load_mesh_file(path, str(path), process=False)
    items: list[tuple[str, str, trimesh.Trimesh]] = []  # (node, geometry, mesh)
    if isinstance(loaded, trimesh.Scene):
        for node in loaded.graph.nodes_geometry:
            transform, geom_name = loaded.graph[node]
            geom = loaded.geometry[geom_name]
            if isinstance(geom, trimesh.Trimesh) and len(geom.faces):
                items.append((node, geom_name, geom.copy().apply_transform(transform)))
    elif isinstance(loaded, trimesh.Trimesh) and len(loaded.faces):
        items.append((path.stem, path.stem, loaded))
    if not items:
        raise ValueError(f"{path}: mesh file holds no triangles (an empty mesh)")
    for _, geom_name, mesh in items:
        if not np.all(np.isfinite(mesh.vertices)):
            raise ValueError(f"{path}: geometry {geom_name!r} has vertices that are NaN or inf")
    used, parts = set(), []
    for node, geom_name, mesh in items:
        key = node if node in mats else geom_name if geom_name in mats else None
        mat = mats[key] if key is not None else default
        if key is not None:
            used.add(key)
        if mat is None:
            raise ValueError(
                f"{path}: geometry {geom_name!r} (node {node!r}) has no material; pass "
                "material=... or a material_map entry for it"
            )
        parts.append((mat, None, mesh))
    unused = sorted(set(mats) - used)
    if unused:
        names = sorted({n for n, _, _ in items} | {g for _, g, _ in items})
        raise ValueError(f"{path}: material_map key {unused[0]!r} matches no geometry or node; "
                         f"names in the file: {', '.join(names)}")
    metadata = {"importer": "scenes.importers.import_mesh", "file": str(path),
                "material": default or "", "material_map": mats}
    radio = {"radio_geometry": radio_geometry, "thin_box_max_m": thin_box_max_m,
             "thin_box_face": thin_box_face}
    return _finish(name or path.stem, parts, str(path), tags, route_m, metadata, str(path), radio)


def _floats(text: str) -> np.ndarray:
    return np.array([float(v) for v in text.replace(",", " ").split()])


def _transform(elem: ET.Element | None, where: str) -> np.ndarray:
    """The 4x4 matrix of a Mitsuba ``<transform>`` (operations apply in document order)."""
    m = np.eye(4)
    if elem is None:
        return m
    for op in elem:
        a = op.attrib
        if op.tag == "matrix":
            step = _floats(a["value"]).reshape(4, 4)
        elif op.tag in ("translate", "scale"):
            if "value" in a:
                v = _floats(a["value"])
                v = np.repeat(v, 3) if v.size == 1 else v
            else:
                dflt = 1.0 if op.tag == "scale" else 0.0
                v = np.array([float(a.get(k, dflt)) for k in "xyz"])
            step = np.eye(4)
            if op.tag == "translate":
                step[:3, 3] = v
            else:
                step[:3, :3] = np.diag(v)
        elif op.tag == "rotate":
            axis = [float(a.get(k, 0.0)) for k in "xyz"]
            if "value" in a:
                axis = _floats(a["value"]).tolist()
            step = trimesh.transformations.rotation_matrix(np.deg2rad(float(a["angle"])), axis)
        else:
            raise ValueError(f"{where}: unsupported transform operation <{op.tag}>")
        m = step @ m
    return m


_THICKNESS_SUFFIX = re.compile(r"-t\d+p\d+$")


def _bsdf_material(bsdf: ET.Element, where: str) -> str:
    type_elem = bsdf.find("string[@name='type']")
    candidates = []
    if type_elem is not None:
        candidates.append(type_elem.get("value", ""))
    if bsdf.get("id"):
        candidates.append(bsdf.get("id"))
        stripped = _THICKNESS_SUFFIX.sub("", bsdf.get("id"))
        if stripped != bsdf.get("id"):
            candidates.append(stripped)
    for cand in candidates:
        try:
            return resolve_material_name(cand)
        except UnknownMaterialError:
            continue
    raise UnknownMaterialError(
        f"{where}: material of <bsdf id={bsdf.get('id')!r} type={bsdf.get('type')!r}> "
        f"({', '.join(repr(c) for c in candidates)}) is not in the UHF library; known "
        "materials come from scenes.materials.MATERIALS (ITU names accepted)"
    )


def _bsdf_thickness(bsdf: ET.Element, where: str = "") -> float | None:
    """The ``thickness`` float of a radio material, metres (``None`` if not given)."""
    elem = bsdf.find("float[@name='thickness']")
    if elem is None:
        return None
    try:
        t = float(elem.get("value"))
    except (TypeError, ValueError):
        t = float("nan")
    if not (np.isfinite(t) and t > 0):
        raise ValueError(f"{where}: <bsdf id={bsdf.get('id')!r}> thickness must be a positive "
                         f"number, got {elem.get('value')!r}")
    return t


def read_sidecar(path: str | Path) -> tuple[list[TagSpec], list | None]:
    """Read a tag sidecar TOML: ``route_m = [[x, y], ...]`` and ``[[tag]]`` tables only.

    Returns
    -------
    (tags, route_m) : list of TagSpec, list or None
    """
    path = Path(path)
    _require_file(path, "tag sidecar")
    try:
        data = tomllib.loads(path.read_text())
    except tomllib.TOMLDecodeError as exc:
        raise SpecError(f"{path}: invalid TOML: {exc}") from None
    unknown = sorted(set(data) - {"tag", "route_m"})
    if unknown:
        raise SpecError(f"{path}: unknown key {unknown[0]!r} at top level; known keys: route_m, tag")
    tags = [parse_item(TagSpec, t, item_where(f"{path}: [[tag]] #{i + 1}", t))
            for i, t in enumerate(data.get("tag", []))]
    route = data.get("route_m")
    if route is not None:
        route = [list(p) for p in convert_value(route, tuple[tuple[float, float], ...], str(path), "route_m")]
    return tags, route


def load_mitsuba_xml(path: str | Path, tags=None, route_m=None, sidecar: str | Path | None = None,
                     name: str | None = None, radio_geometry: str = "as_is",
                     thin_box_max_m: float = 0.3, thin_box_face: str = "inner") -> Scene:
    """Load a Mitsuba 3 / Sionna RT XML scene (``ply`` and ``obj`` shapes, plus rectangles).

    Parameters
    ----------
    path : str or Path
        XML file; mesh file names resolve relative to it.
    tags : sequence of TagSpec or dict, optional
        Tags; default: those of the sidecar, if any.
    route_m : array_like (n, 2), optional
        Robot route; default: the sidecar's, if any.
    sidecar : str or Path, optional
        Tag sidecar TOML (see :func:`read_sidecar`); default ``<xml stem>.tags.toml``
        next to the XML when that file exists.
    name : str, optional
        Scene name (default: the XML stem).
    radio_geometry, thin_box_max_m, thin_box_face
        As in :func:`import_mesh`; ``"single"`` and the parts ``"thin_boxes"`` leaves as
        they are take each shape's thickness from the ``thickness`` of its radio material
        when the XML gives one (a file written by :func:`scenes.export_mitsuba` loads
        back with ``radio_geometry="single"`` as the radio geometry it was exported from).

    Raises
    ------
    FileNotFoundError
        If the XML or a mesh file it references does not exist (named).
    UnknownMaterialError
        If a ``<bsdf>`` maps onto no library material (its id named).
    """
    path = Path(path)
    _require_file(path, "Mitsuba scene")
    try:
        root = ET.parse(path).getroot()
    except ET.ParseError as exc:
        raise ValueError(f"{path}: invalid XML: {exc}") from None
    bsdfs = {b.get("id"): b for b in root.iter("bsdf") if b.get("id")}
    parts: list = []
    for k, shape in enumerate(root.iter("shape")):
        sid = shape.get("id") or f"shape #{k + 1}"
        where = f"{path}: <shape id={sid!r}>"
        ref = shape.find("ref")
        inline = shape.find("bsdf")
        if inline is not None:
            mat, thickness = _bsdf_material(inline, where), _bsdf_thickness(inline, where)
        elif ref is not None and ref.get("id") in bsdfs:
            bsdf = bsdfs[ref.get("id")]
            mat, thickness = _bsdf_material(bsdf, where), _bsdf_thickness(bsdf, where)
        elif ref is not None:
            raise ValueError(f"{where}: references undefined bsdf {ref.get('id')!r}")
        else:
            raise ValueError(f"{where}: has no material (<ref> or <bsdf>)")
        stype = shape.get("type")
        if stype in ("ply", "obj"):
            fname = shape.find("string[@name='filename']")
            if fname is None:
                raise ValueError(f"{where}: has no filename")
            mesh_path = path.parent / fname.get("value")
            _require_file(mesh_path, f"mesh file of {where}:")
            mesh = _require_triangles(_load_mesh_file(mesh_path, where, force="mesh", process=False),
                                      mesh_path, where)
        elif stype == "rectangle":
            mesh = trimesh.Trimesh([[-1, -1, 0], [1, -1, 0], [1, 1, 0], [-1, 1, 0]],
                                   [[0, 1, 2], [0, 2, 3]], process=False)
        elif stype == "cube":
            mesh = trimesh.creation.box(extents=[2, 2, 2])
        else:
            raise ValueError(f"{where}: unsupported shape type {stype!r} (ply, obj, rectangle, cube)")
        m4 = _transform(shape.find("transform"), where)
        if not np.all(np.isfinite(m4)):
            raise ValueError(f"{where}: its <transform> holds NaN or inf ({m4.tolist()})")
        mesh.apply_transform(m4)
        parts.append((mat, thickness, mesh))
    if sidecar is None:
        default = path.with_suffix(".tags.toml")
        sidecar = default if default.is_file() else None
    if sidecar is not None:
        side_tags, side_route = read_sidecar(sidecar)
        tags = side_tags if tags is None else tags
        route_m = side_route if route_m is None else route_m
    metadata = {"importer": "scenes.importers.load_mitsuba_xml", "file": str(path),
                "sidecar": "" if sidecar is None else str(sidecar)}
    logger.debug("loaded %s: materials %s", path, sorted({m for m, _, _ in parts}))
    radio = {"radio_geometry": radio_geometry, "thin_box_max_m": thin_box_max_m,
             "thin_box_face": thin_box_face}
    return _finish(name or path.stem, parts, str(path), tags, route_m, metadata, str(path), radio)
