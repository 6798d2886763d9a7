"""A scene from a ROS occupancy-grid map: extracted obstacles as solids and radio surfaces.

The map (:mod:`scenes.rosmap`) gives the obstacles and their constructions
(:mod:`scenes.mapextract`); here they become the two geometries of a
:class:`~scenes.scene.Scene`, following the one-surface-per-physical-layer rule of the
generated corridors (:mod:`scenes.corridor_radio`):

- walls: the outline extruded to ``height_m`` is the solid (collision, laser, tags;
  triangulated by shapely's constrained Delaunay, extruded by trimesh). A ``"solid"``
  wall is one traced surface carrying a construction thickness
  (``MapSpec.solid_wall_thickness_m``; by default the material's library thickness,
  not the map's occupied band, which in a SLAM map is the laser's spread): at the
  wall's *inside face* where the map says which side is inside (free space on one side
  of a segment, outside or obstacle on the other: the outer walls), else on its centre
  line (a wall between two rooms has two faces and one crossing).
  ``"stud"``/``"double"``: one leaf of the material's library thickness on each face
  (the centre line offset by half the map's thickness); ``"single"``: one leaf on the
  centre line;
- pillars: the extruded outline, traced as a closed shell whose faces each carry half
  the pillar's short side (a ray through it crosses two faces: the whole width);
- racks (the minimum rotated rectangle of the obstacle): per shelf level a board (one
  horizontal metal surface) with a front and a back beam (``beam_height_m`` high,
  vertical metal surfaces, the solids tags sit on), and square uprights at both ends and
  at most ``bay_length_m`` apart (closed metal shells): not a solid block, so rays pass
  between the shelves;
- floor and ceiling: one slab each over the building's bounding rectangle.

Free space (``Scene.free_space_m``) is every cell not outside the building, as boxes
(runs of cells merged row by row, rows with equal runs merged). The map itself travels
with the scene (``Scene.rosmap``): the robot localises in it as it is
(:func:`pipeline.robot.robotmap.draw_robot_map`).
"""

from __future__ import annotations

import csv
import dataclasses
from pathlib import Path

import numpy as np
import shapely
import trimesh
from shapely.geometry.polygon import orient

from scenes.corridor_radio import slab_surface
from scenes.geometry import box_mesh, merge_meshes
from scenes.mapextract import MapObstacle, apply_override, extract_obstacles, map_cells
from scenes.mapspec import MapSpec, TagLayoutSpec, parse_map_table, rules_of
from scenes.materials import UnknownMaterialError, get_material, resolve_material_name
from scenes.radio import RadioSurface, default_construction
from scenes.rosmap import FREE, OUTSIDE, RosMap, file_state, read_map, short_repr
from scenes.scene import Scene, TagSet
from scenes.spec import SpecError, TagSpec
from scenes.tags import MAX_TAGS, make_tags, validate_tags

__all__ = ["BARE_MAP_TAG_SPACING_M", "bare_map_tags", "build_map_scene", "load_map",
           "rack_frames", "shelf_tags", "wall_tags"]


def _extrude(poly, z0: float, z1: float) -> trimesh.Trimesh:
    """Closed prism over a shapely polygon (holes kept) from z0 to z1."""
    tris = shapely.constrained_delaunay_triangles(poly)
    pts = np.array([np.asarray(t.exterior.coords)[:3] for t in tris.geoms if t.area > 1e-12])
    verts, inv = np.unique(pts.reshape(-1, 2).round(9), axis=0, return_inverse=True)
    mesh = trimesh.creation.extrude_triangulation(verts, inv.reshape(-1, 3), z1 - z0)
    mesh.apply_translation([0.0, 0.0, z0])
    return trimesh.Trimesh(np.asarray(mesh.vertices), np.asarray(mesh.faces), process=False)


def _vertical_quad(a, b, z0: float, z1: float) -> trimesh.Trimesh:
    """A vertical rectangle over the segment a -> b, normal to its left."""
    a, b = np.asarray(a, float), np.asarray(b, float)
    v = np.array([[*a, z0], [*b, z0], [*b, z1], [*a, z1]])
    return trimesh.Trimesh(v, np.array([[0, 2, 1], [0, 3, 2]]), process=False)


def _solid_thickness(o: MapObstacle, spec: MapSpec) -> float:
    """Traced slab thickness of a solid wall [m] (``MapSpec.solid_wall_thickness_m``)."""
    if spec.solid_wall_thickness_m is None:
        return float(get_material(o.material).thickness_m)
    if spec.solid_wall_thickness_m == 0:
        return round(max(o.thickness_m, 1e-3), 3)
    return float(spec.solid_wall_thickness_m)


#: How far behind the map's inside face a solid wall's traced face is set [cells] (plus
#: 1 cm): the centre line is a skeleton that leans by up to a cell.
FACE_SETBACK_CELLS = 1.0


def inside_side(a, b, half_m: float, cls: np.ndarray, rosmap: RosMap) -> float:
    """Which side of the wall segment a -> b (2,) [m] is the building's inside: +1 (its
    left normal), -1, or 0 when the map does not tell (free on both sides: a wall between
    two rooms; free on neither). The cells probed lie ``half_m`` plus 1.5 cells off the
    segment's midpoint."""
    a, b = np.asarray(a, float), np.asarray(b, float)
    d = (b - a) / np.linalg.norm(b - a)
    n = np.array([-d[1], d[0]])
    off = half_m + 1.5 * rosmap.resolution_m
    mid = (a + b) / 2
    free = [_is_free_cell(cls, rosmap, mid + s * off * n) for s in (1.0, -1.0)]
    return 0.0 if free[0] == free[1] else (1.0 if free[0] else -1.0)


def _wall_surfaces(o: MapObstacle, height_m: float, spec: MapSpec, cls: np.ndarray,
                   rosmap: RosMap) -> tuple[list[RadioSurface], int]:
    """The wall's radio surfaces, and how many solid segments sit at the inside face."""
    out, at_face = [], 0
    t = round(max(o.thickness_m, 1e-3), 3)
    lib = get_material(o.material).thickness_m
    for a, b in o.centre_lines_m:
        d = (b - a) / np.linalg.norm(b - a)
        n = np.array([-d[1], d[0]])
        if o.construction == "solid":
            side = inside_side(a, b, t / 2, cls, rosmap)
            # the inside face, set back by a cell and a tag's offset: the skeleton leans
            # by up to a cell and wall tags sit 5 mm off the outline, so the traced face
            # stays behind every tag on it; 0: the centre line
            shift = max(0.0, t / 2 - FACE_SETBACK_CELLS * rosmap.resolution_m - 0.01)
            off = side * shift * n
            # each segment lengthened by its shift at both ends: shifted alone, the two
            # segments of an inner corner would no longer meet, and rays would pass
            # between them
            ext = d * abs(side) * shift
            at_face += side != 0
            out.append(RadioSurface(o.material, _solid_thickness(o, spec),
                                    _vertical_quad(a + off - ext, b + off + ext, 0.0, height_m),
                                    "wall"))
        elif o.construction == "single":
            out.append(RadioSurface(o.material, lib, _vertical_quad(a, b, 0.0, height_m), "leaf"))
        else:  # stud, double: a leaf on each face
            for s in (-1.0, 1.0):
                off = s * t / 2 * n
                q = _vertical_quad(a + off, b + off, 0.0, height_m) if s > 0 else \
                    _vertical_quad(b + off, a + off, 0.0, height_m)
                out.append(RadioSurface(o.material, lib, q, "leaf"))
    return out, at_face


def rack_frames(o) -> tuple[np.ndarray, np.ndarray, np.ndarray, float, float]:
    """A rack's frame: centre (2,), long axis u (2,), depth axis v (2,), length and depth [m].

    ``o`` is a :class:`MapObstacle`, or the corners (4, 2) [m] of its rectangle (as a
    scene's ``metadata["map"]["obstacles"][i]["rectangle_m"]`` holds them).
    """
    r = np.asarray(getattr(o, "rectangle_m", o), dtype=float)
    e0, e1 = r[1] - r[0], r[2] - r[1]
    long_e, short_e = (e0, e1) if np.linalg.norm(e0) >= np.linalg.norm(e1) else (e1, e0)
    u = long_e / np.linalg.norm(long_e)
    if u[0] < -1e-9 or (abs(u[0]) <= 1e-9 and u[1] < 0):
        u = -u
    v = np.array([-u[1], u[0]])
    return r.mean(axis=0), u, v, float(np.linalg.norm(long_e)), float(np.linalg.norm(short_e))


def _rack(o: MapObstacle, spec: MapSpec) -> tuple[list, list[RadioSurface]]:
    """Solids and radio surfaces of one shelving rack."""
    c, u, v, length, depth = rack_frames(o)
    yaw = float(np.arctan2(u[1], u[0]))
    rot = np.array([[np.cos(yaw), -np.sin(yaw)], [np.sin(yaw), np.cos(yaw)]])
    metal = "metal"
    t_metal = get_material(metal).thickness_m

    def box(centre_local, size, z0, z1):
        cw = c + rot @ np.asarray(centre_local, float)
        half = np.array([size[0] / 2, size[1] / 2])
        return box_mesh([cw[0] - half[0], cw[1] - half[1], z0], [cw[0] + half[0], cw[1] + half[1], z1], yaw)

    solids, radio = [], []
    bh = spec.beam_height_m
    corners = [c + s * length / 2 * u + w * depth / 2 * v for s, w in ((-1, -1), (1, -1), (1, 1), (-1, 1))]
    for z in spec.shelf_levels_m:
        solids.append(box((0.0, 0.0), (length, depth), z, z + bh))
        top = np.array([[*p, z + bh] for p in corners])
        radio.append(RadioSurface(metal, t_metal, trimesh.Trimesh(top, [[0, 1, 2], [0, 2, 3]],
                                                                  process=False), "shelf"))
        for w in (-1.0, 1.0):  # front and back beams: vertical faces on the long sides
            a = c - length / 2 * u + w * depth / 2 * v
            b = c + length / 2 * u + w * depth / 2 * v
            q = _vertical_quad(b, a, z, z + bh) if w < 0 else _vertical_quad(a, b, z, z + bh)
            radio.append(RadioSurface(metal, t_metal, q, "shelf"))
    n_bays = max(1, int(np.ceil(length / spec.bay_length_m - 1e-9)))
    pw = min(spec.post_width_m, depth / 2, length / 2)
    for s in np.linspace(-length / 2 + pw / 2, length / 2 - pw / 2, n_bays + 1):
        for w in (-depth / 2 + pw / 2, depth / 2 - pw / 2):
            post = box((s, w), (pw, pw), 0.0, spec.rack_height_m)
            solids.append(post)
            radio.append(RadioSurface(metal, t_metal, post, "shell"))
    return solids, radio


def _free_boxes(cls: np.ndarray, rosmap: RosMap, height_m: float) -> np.ndarray:
    """Boxes (k, 2, 3) [m] covering every cell that is not outside the building."""
    inside = cls != OUTSIDE
    rects, active = [], {}
    for r in range(inside.shape[0] + 1):
        runs = set()
        if r < inside.shape[0]:
            d = np.diff(np.concatenate([[0], inside[r].astype(np.int8), [0]]))
            runs = set(zip(np.flatnonzero(d == 1).tolist(), np.flatnonzero(d == -1).tolist(), strict=True))
        for run in list(active):
            if run not in runs:
                rects.append((active.pop(run), r, *run))
        for run in runs:
            active.setdefault(run, r)
    res, o = rosmap.resolution_m, rosmap.origin_m
    return np.array([[[o[0] + c0 * res, o[1] + r0 * res, 0.0], [o[0] + c1 * res, o[1] + r1 * res, height_m]]
                     for r0, r1, c0, c1 in sorted(rects)], dtype=float).reshape(-1, 2, 3)


def _walls_tagged(layout: TagLayoutSpec, obstacles: list[MapObstacle]) -> bool:
    """``[tags] walls``, its default (None) decided: walls are tagged where no rack is."""
    if layout.walls is None:
        return not any(o.kind == "rack" for o in obstacles)
    return bool(layout.walls)


def _is_free_cell(cls: np.ndarray, rosmap: RosMap, xy) -> bool:
    """Whether the map cell holding the point (2,) [m] is free."""
    col, row = np.floor((np.asarray(xy) - rosmap.origin_m) / rosmap.resolution_m).astype(int)
    return bool(0 <= row < cls.shape[0] and 0 <= col < cls.shape[1] and cls[row, col] == FREE)


def shelf_tags(obstacles: list[MapObstacle], cls: np.ndarray, rosmap: RosMap, spec: MapSpec,
               layout: TagLayoutSpec, where: str) -> list[TagSpec]:
    """Tags on the front beams of every rack face that looks onto free space.

    A tag is placed where the map cells in front of it are free (just beyond a cell, 0.15 m
    and 0.3 m out): a face against a wall or another rack keeps its open part.
    Tags run along the face from ``margin_m`` to the other end, ``spacing_m`` apart
    (centred), at ``heights_m`` (default: the middle of every beam). Ids
    ``R<rack>-<side><level>-<k>`` (side A: +v, B: -v of :func:`rack_frames`).
    """
    bh = spec.beam_height_m
    heights = layout.heights_m or tuple(z + bh / 2 for z in spec.shelf_levels_m)
    has_racks = any(o.kind == "rack" for o in obstacles)
    for h in heights:
        if (has_racks or not _walls_tagged(layout, obstacles)) and not any(
                z - 1e-9 <= h <= z + bh + 1e-9 for z in spec.shelf_levels_m):
            raise SpecError(f"{where}: [tags] key 'heights_m': {h} m is on no front beam (beams at "
                            f"{list(spec.shelf_levels_m)} m, {bh} m high)")
    out = []
    for k, o in enumerate(x for x in obstacles if x.kind == "rack"):
        c, u, v, length, depth = rack_frames(o)
        usable = length - 2 * layout.margin_m
        n = max(1, int(np.floor(usable / layout.spacing_m)) + 1) if usable > 0 else 1
        s = (np.arange(n) - (n - 1) / 2) * layout.spacing_m
        for side, w in (("A", 1.0), ("B", -1.0)):
            # each tag's own front: free from just beyond a cell to 0.3 m out (a rack whose
            # face is partly against a wall or another rack keeps the tags of the open part)
            front = np.array([[_is_free_cell(cls, rosmap, c + si * u + w * (depth / 2 + d) * v)
                               for d in (1.5 * rosmap.resolution_m, 0.15, 0.3)] for si in s]).all(axis=1)
            if not front.any():
                continue
            for j, h in enumerate(heights):
                for i, si in enumerate(s):
                    if not front[i]:
                        continue
                    p = c + si * u + w * depth / 2 * v
                    out.append(TagSpec(f"R{k + 1:02d}-{side}{j + 1}-{i + 1:03d}", (float(p[0]), float(p[1]), float(h)),
                                       (float(w * v[0]), float(w * v[1]), 0.0), layout.offset_m))
    return out


def wall_tags(obstacles: list[MapObstacle], cls: np.ndarray, rosmap: RosMap, spec: MapSpec,
              layout: TagLayoutSpec, where: str) -> list[TagSpec]:
    """Tags on the faces of wall obstacles that look onto free space (``[tags] walls = true``).

    Every straight edge of a wall's outline (outer ring and holes: the outer wall's inner
    face is the edge of its hole) is a candidate face, its normal pointing out of the wall.
    Tags run along it as on a shelf front: from ``margin_m`` to the other end,
    ``spacing_m`` apart (centred), at the shelf tags' heights; an edge shorter than
    ``2 margin_m`` (a wall's end, a door jamb) carries none. A tag is kept only where
    the map as given is free (not unknown, not occupied) at every half cell from one cell to
    0.3 m along the normal, and no other obstacle's outline is within ``margin_m`` of it
    (a partition abutting the wall, a rack in front of it). A door gap is free space, not a
    wall face: no tag sits in it. Ids ``W<wall>-<face><level>-<k>`` (walls counted in the
    obstacle order, faces along the outlines).

    Raises
    ------
    SpecError
        A tag height not strictly between the floor and ``height_m``.
    """
    bh = spec.beam_height_m
    heights = layout.heights_m or tuple(z + bh / 2 for z in spec.shelf_levels_m)
    for h in heights:
        if not 0 < h < spec.height_m:
            raise SpecError(f"{where}: [tags] key 'heights_m': {h} m is not between the floor and "
                            f"the ceiling ([map] height_m {spec.height_m} m) for wall tags")
    raw = rosmap.cell_class
    res = rosmap.resolution_m
    probe_d = np.arange(res, 0.3 + 1e-9, res / 2)
    out = []
    walls = [o for o in obstacles if o.kind == "wall"]
    for k, o in enumerate(walls):
        others = [x.polygon for x in obstacles if x is not o]
        near = shapely.union_all(others) if others else None
        poly = orient(o.polygon, 1.0)  # material on each ring's left
        face = 0
        for ring in (poly.exterior, *poly.interiors):
            xy = np.asarray(ring.coords)[:, :2]
            for a, b in zip(xy[:-1], xy[1:], strict=True):
                length = float(np.linalg.norm(b - a))
                usable = length - 2 * layout.margin_m
                if usable < 0:
                    continue
                u = (b - a) / length
                n = np.array([u[1], -u[0]])  # right of the edge: out of the wall
                m = int(np.floor(usable / layout.spacing_m + 1e-9)) + 1
                s = length / 2 + (np.arange(m) - (m - 1) / 2) * layout.spacing_m
                pts = a + s[:, None] * u
                probes = pts[:, None, :] + probe_d[None, :, None] * n
                col, row = np.floor((probes - rosmap.origin_m) / res).astype(int).transpose(2, 0, 1)
                inside = (row >= 0) & (row < raw.shape[0]) & (col >= 0) & (col < raw.shape[1])
                free = np.zeros(row.shape, dtype=bool)
                free[inside] = raw[row[inside], col[inside]] == FREE
                keep = free.all(axis=1)
                # the tag itself inside the building (a simplified outline may cut a corner
                # of the outside)
                tc, tr = np.floor((pts + layout.offset_m * n - rosmap.origin_m) / res).astype(int).T
                ok = (tr >= 0) & (tr < cls.shape[0]) & (tc >= 0) & (tc < cls.shape[1])
                keep &= ok & (cls[np.clip(tr, 0, cls.shape[0] - 1), np.clip(tc, 0, cls.shape[1] - 1)] != OUTSIDE)
                if near is not None:
                    tag_xy = shapely.points(pts + layout.offset_m * n)
                    keep &= shapely.distance(near, tag_xy) >= layout.margin_m
                if not keep.any():
                    continue
                face += 1
                for j, h in enumerate(heights):
                    for i in np.flatnonzero(keep):
                        p = pts[i]
                        out.append(TagSpec(f"W{k + 1:02d}-{face:02d}{j + 1}-{i + 1:03d}",
                                           (float(p[0]), float(p[1]), float(h)),
                                           (float(n[0]), float(n[1]), 0.0), layout.offset_m))
    return out


def csv_tags(path: Path, offset_m: float, where: str) -> list[TagSpec]:
    """Tags from a CSV with header ``id, x_m, y_m, z_m, nx, ny, nz``.

    Parameters
    ----------
    path : Path
        The CSV file.
    offset_m : float
        Every tag's offset off its surface [m].
    where : str
        The scene file naming it (for messages).

    Returns
    -------
    list of TagSpec

    Raises
    ------
    FileNotFoundError
        ``path`` does not exist.
    SpecError
        Not a regular file (a FIFO, a device, a folder), not UTF-8 text, not CSV, a wrong
        header, a row that is not numbers, more rows than :data:`scenes.tags.MAX_TAGS`.
        A message quotes at most 60 characters of what it read (``/etc/passwd`` given as
        the CSV is not printed).
    """
    state = file_state(path)
    if state == "missing":
        raise FileNotFoundError(f"{where}: [tags] key 'csv': file {short_repr(str(path), 200)} does not exist")
    if state != "regular":  # a FIFO would wait for a writer; /dev/zero never ends
        raise SpecError(f"{where}: [tags] key 'csv': {short_repr(str(path), 200)} {state}")
    need = ["id", "x_m", "y_m", "z_m", "nx", "ny", "nz"]
    i = 1
    try:
        with open(path, newline="", encoding="utf-8") as fh:
            reader = csv.DictReader(fh)
            cols = [c.strip() for c in reader.fieldnames or []]
            if cols != need:
                raise SpecError(f"{path}: header must be {','.join(need)}, got "
                                f"{short_repr(','.join(cols))}")
            out = []
            for i, row in enumerate(reader, start=2):
                if len(out) >= MAX_TAGS:
                    raise SpecError(f"{path}: more than {MAX_TAGS:,} tags (MAX_TAGS)")
                vals = []
                for k in need[1:]:
                    try:
                        vals.append(float(row[k]))
                    except (TypeError, ValueError):
                        raise SpecError(f"{path}: line {i}: {k} must be a number, got "
                                        f"{short_repr(row[k])}") from None
                out.append(TagSpec(row["id"].strip(), tuple(vals[:3]), tuple(vals[3:]), offset_m))
    except UnicodeDecodeError:
        raise SpecError(f"{path}: not a UTF-8 text file (a tag CSV is text)") from None
    except csv.Error as exc:
        raise SpecError(f"{path}: line {i + 1}: not a CSV row ({short_repr(str(exc))})") from None
    return out


def build_map_scene(spec: MapSpec, *, name: str | None = None, base_dir: str | Path = ".",
                    tags=(), tag_layout: TagLayoutSpec | None = None, route_m=None,
                    source: str = "", material_overrides: dict | None = None) -> Scene:
    """Build the scene of a ROS map (see the module docstring).

    Parameters
    ----------
    spec : MapSpec
        The ``[map]`` table (``path`` relative to ``base_dir``).
    name : str, optional
        Scene name (default: the YAML's stem).
    base_dir : str or Path
        Folder ``spec.path`` and a tag CSV resolve against.
    tags : sequence of TagSpec or dict
        Extra tags (``[[tag]]`` items).
    tag_layout : TagLayoutSpec, optional
        ``[tags]``; default ``layout = "shelves"``.
    route_m : array_like (k, 2), optional
        A waypoint list; None: the pipeline plans a coverage route
        (:func:`pipeline.robot.coverage.plan_coverage_route`).
    source : str
        The file the spec came from (for messages).
    material_overrides : dict, optional
        ``Scene.metadata["material_overrides"]`` (a scene TOML's ``[material_overrides]``).

    Returns
    -------
    Scene
        With ``rosmap`` set and ``metadata["map"]`` describing every obstacle.

    Raises
    ------
    scenes.rosmap.RosMapError, SpecError, ValueError
        A bad map, a bad override (one that matches nothing), tags off every surface.
    """
    base = Path(base_dir)
    yaml_path = Path(spec.path) if Path(spec.path).is_absolute() else base / spec.path
    where = source or str(yaml_path)
    rosmap = read_map(yaml_path)
    for key in ("outer_material", "thick_material", "thin_material", "pillar_material",
                "floor_material", "ceiling_material"):
        try:
            resolve_material_name(getattr(spec, key))
        except UnknownMaterialError as exc:
            raise UnknownMaterialError(f"{where}: [map] key {key!r}: {exc}") from None
    cls, cleaning = map_cells(rosmap, rules_of(spec))
    noise: list = []
    obstacles = extract_obstacles(rosmap, spec.tolerance_m, rules_of(spec), cells=cls, dropped=noise)
    for i, ov in enumerate(spec.override):
        label = f"{where}: [[map.override]] #{i + 1}" + (f" (id {ov.id!r})" if ov.id else "")
        obstacles = apply_override(obstacles, label, point_m=ov.point_m, polygon_m=ov.polygon_m,
                                   kind=ov.kind, material=ov.material, construction=ov.construction,
                                   snap_m=rosmap.resolution_m)
    obstacles = [o if o.kind != "wall" or o.construction else
                 _with_construction(o) for o in obstacles]
    H = spec.height_m
    parts: dict[str, list] = {}
    radio: list[RadioSurface] = []
    walls_at_face = 0  # solid wall segments traced at their inside face
    for o in obstacles:
        if o.kind == "rack":
            solids, surf = _rack(o, spec)
            parts.setdefault("metal", []).extend(solids)
            radio += surf
            continue
        prism = _extrude(o.polygon, 0.0, H)
        parts.setdefault(resolve_material_name(o.material), []).append(prism)
        if o.kind == "pillar":
            radio.append(RadioSurface(o.material, max(o.rectangle_sides_m[1] / 2, 1e-3), prism, "shell"))
        else:
            surf, n_face = _wall_surfaces(o, H, spec, cls, rosmap)
            radio += surf
            walls_at_face += n_face
    inside = np.argwhere(cls != OUTSIDE)
    lo = rosmap.origin_m + inside.min(axis=0)[::-1] * rosmap.resolution_m
    hi = rosmap.origin_m + (inside.max(axis=0)[::-1] + 1) * rosmap.resolution_m
    rect = [(lo[0], lo[1], hi[0], hi[1])]
    floor_mat, ceil_mat = resolve_material_name(spec.floor_material), resolve_material_name(spec.ceiling_material)
    parts.setdefault(floor_mat, []).append(box_mesh([lo[0], lo[1], -spec.floor_thickness_m], [hi[0], hi[1], 0.0]))
    parts.setdefault(ceil_mat, []).append(box_mesh([lo[0], lo[1], H], [hi[0], hi[1], H + spec.ceiling_thickness_m]))

    radio += [slab_surface(rect, 0.0, True, floor_mat, spec.floor_thickness_m, "floor"),
              slab_surface(rect, H, False, ceil_mat, spec.ceiling_thickness_m, "ceiling")]
    meshes = {mat: merge_meshes(ms) for mat, ms in sorted(parts.items())}
    summary = [{"index": o.index, "kind": o.kind, "material": o.material,
                "construction": o.construction, "rule": o.rule,
                "centroid_m": [round(float(v), 4) for v in o.polygon.centroid.coords[0]],
                "area_m2": round(o.area_m2, 4), "thickness_m": round(o.thickness_m, 4),
                "rectangle_m": np.round(o.rectangle_m, 6).tolist()}
               for o in obstacles]
    metadata = {"generator": "scenes.mapscene.build_map_scene",
                "map": {"yaml": str(yaml_path), "image": rosmap.image_path, "digest": rosmap.digest(),
                        "resolution_m": rosmap.resolution_m, "mode": rosmap.mode,
                        "route_standoff_m": spec.route_standoff_m, "obstacles": summary,
                        "solid_walls_at_inside_face": int(walls_at_face),
                        "shelf_levels_m": list(spec.shelf_levels_m), "beam_height_m": spec.beam_height_m,
                        "cleaning": {"gap_cells": cleaning.gap_cells, "kept_enclosed": cleaning.kept_enclosed,
                                     "filled": [dataclasses.asdict(f) for f in cleaning.filled]},
                        "noise_dropped": len(noise),
                        "noise_dropped_m2": round(sum(a for _, _, a in noise), 4)}}
    if material_overrides:
        metadata["material_overrides"] = material_overrides
    route = None if route_m is None else np.asarray(route_m, dtype=float).reshape(-1, 2)
    scene = Scene(name=name or yaml_path.stem, meshes=meshes,
                  tags=TagSet(np.zeros(0, dtype=str), np.zeros((0, 3)), np.zeros((0, 3))),
                  source=where, metadata=metadata, route_m=route,
                  free_space_m=_free_boxes(cls, rosmap, H), radio_surfaces=tuple(radio), rosmap=rosmap,
                  source_digest=rosmap.digest())
    layout = TagLayoutSpec() if tag_layout is None else tag_layout
    specs = list(tags)
    if layout.layout == "shelves":
        specs += shelf_tags(obstacles, cls, rosmap, spec, layout, where)
        if _walls_tagged(layout, obstacles):
            if layout.walls is None:
                import logging

                logging.getLogger("scenes").warning(
                    "%s: no rack recognised in the map: tags go on the walls ([tags] walls = true; "
                    "set walls = false, or override an obstacle's kind to 'rack', to change it)", where)
            specs += wall_tags(obstacles, cls, rosmap, spec, layout, where)
    elif layout.layout == "csv":
        p = Path(layout.csv) if Path(layout.csv).is_absolute() else base / layout.csv
        specs += csv_tags(p, layout.offset_m, where)
    scene.tags = make_tags(scene, specs, f"{where}: tag")
    validate_tags(scene)
    return scene


def _with_construction(o: MapObstacle) -> MapObstacle:
    from dataclasses import replace


    return replace(o, construction=default_construction(o.material))


def load_map(path: str | Path, **kwargs) -> Scene:
    """``scenes.load("site.yaml")``: the scene of a map_server YAML with default rules.

    ``kwargs`` go to :class:`MapSpec` (``height_m=4.0``, ``rack_height_m=...``). The tags
    are one row (:func:`bare_map_tags`): a scene TOML's ``[tags]`` sets more.
    """
    p = Path(path)
    spec = parse_map_table({"path": str(p.resolve()), **kwargs}, f"{p}: [map]")
    return build_map_scene(spec, name=p.stem, source=str(p), tag_layout=bare_map_tags(spec))


#: Tag spacing along a face of a map given without a scene TOML [m]: one tag per bay-sized
#: metre, as on the bundled warehouse_large.
BARE_MAP_TAG_SPACING_M = 1.0


def bare_map_tags(spec: MapSpec) -> TagLayoutSpec:
    """The tag layout of a map given as a bare YAML: one row, 1 m apart.

    One tag per metre of every rack face (or wall face, where the map has no rack), at
    the middle of the front beam nearest 1 m above the floor (0.85 m with the default
    shelf levels): a building of 30 x 50 m gets a few hundred tags, which a study traces
    in minutes; four rows 0.5 m apart (the ``[tags]`` table's default) are eight times as
    many links.
    """
    mids = np.asarray(spec.shelf_levels_m, dtype=float) + spec.beam_height_m / 2
    h = float(mids[int(np.argmin(np.abs(mids - 1.0)))])
    return TagLayoutSpec(heights_m=(h,), spacing_m=BARE_MAP_TAG_SPACING_M)
