"""Corridor generator: solid slabs around a union of free-space rectangles, and their radio surfaces.

The walkable area is a union of axis-aligned rectangles (one for a straight
corridor, several for an L or T junction). Walls are the band of width
``wall_thickness_m`` around that union (the union grown by the thickness with square
corners, minus the union); floor and ceiling slabs cover the grown union. Every solid
is a closed box, so the robot's laser, collision and tag placement see a thickness.
The ray tracer sees the scene's radio surfaces instead (:mod:`scenes.corridor_radio`):
each physical layer once, a solid wall as one surface on its inner face carrying the
wall thickness, a stud partition as two leaves, floor and ceiling as one surface each,
hollow furniture as closed shells.

The plane is cut into cells on the compressed grid of all rectangle, wall and
opening coordinates; each wall cell carries a vertical profile (z-intervals and
their material and construction) that panels replace and doors open. Cells with equal profiles are
merged into as few boxes as possible: meshes stay coarse (12 triangles per box).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from scenes.corridor_radio import construction_of, slab_surface, wall_surfaces
from scenes.geometry import box_mesh, is_free, merge_meshes, points_in_boxes
from scenes.materials import get_material, resolve_material_name
from scenes.radio import RadioSurface, rectangle_mesh
from scenes.scene import Scene, TagSet
from scenes.spec import (
    BoxSpec,
    CabinetSpec,
    CorridorSpec,
    DoorSpec,
    PanelSpec,
    SceneSpec,
    SegmentSpec,
    TagSpec,
    check_spec,
    overrides_metadata,
    parse_item,
    spec_to_dict,
)
from scenes.tags import make_tags, validate_tags

__all__ = ["corridor", "build_corridor", "corridor_route"]

_EPS = 1e-9


@dataclass(frozen=True)
class _Edge:
    """A maximal straight piece of the free-space boundary (the inner face of a wall)."""

    along: int  # axis the wall runs along (0: x, 1: y)
    coord: float  # coordinate of the inner face on the other axis, m
    a0: float
    a1: float
    inward: int  # +1/-1: direction from the wall into free space along the other axis

    def wall_range(self, t: float) -> tuple[float, float]:
        return (self.coord - t, self.coord) if self.inward > 0 else (self.coord, self.coord + t)

    def describe(self) -> str:
        a, p = "xy"[self.along], "xy"[1 - self.along]
        return f"wall {p}={self.coord:.4g} m spanning {a} from {self.a0:.4g} to {self.a1:.4g} m"


def _cells(rooms: np.ndarray, xs: np.ndarray, ys: np.ndarray, grow: float = 0.0) -> np.ndarray:
    cx, cy = (xs[:-1] + xs[1:]) / 2, (ys[:-1] + ys[1:]) / 2
    x0, y0, x1, y1 = (rooms[:, k] for k in range(4))
    inx = (cx[:, None] > x0 - grow) & (cx[:, None] < x1 + grow)  # (nx, k)
    iny = (cy[:, None] > y0 - grow) & (cy[:, None] < y1 + grow)  # (ny, k)
    return np.einsum("ik,jk->ij", inx.astype(int), iny.astype(int)) > 0


def _boundary_edges(rooms: np.ndarray) -> list[_Edge]:
    xs, ys = np.unique(rooms[:, [0, 2]]), np.unique(rooms[:, [1, 3]])
    free = np.pad(_cells(rooms, xs, ys), 1)
    pieces: dict[tuple, list[tuple[float, float]]] = {}
    for i, x in enumerate(xs):  # vertical boundaries x = xs[i]
        left, right = free[i, 1:-1], free[i + 1, 1:-1]
        for j in np.flatnonzero(left != right):
            pieces.setdefault((1, float(x), 1 if right[j] else -1), []).append((ys[j], ys[j + 1]))
    for j, y in enumerate(ys):  # horizontal boundaries y = ys[j]
        below, above = free[1:-1, j], free[1:-1, j + 1]
        for i in np.flatnonzero(below != above):
            pieces.setdefault((0, float(y), 1 if above[i] else -1), []).append((xs[i], xs[i + 1]))
    edges = []
    for (along, coord, inward), spans in pieces.items():
        spans.sort()
        a0, a1 = spans[0]
        for b0, b1 in spans[1:]:
            if b0 <= a1 + _EPS:
                a1 = max(a1, b1)
            else:
                edges.append(_Edge(along, coord, float(a0), float(a1), inward))
                a0, a1 = b0, b1
        edges.append(_Edge(along, coord, float(a0), float(a1), inward))
    return edges


def _find_edge(edges: list[_Edge], p, t: float, label: str) -> _Edge:
    best, best_s = None, np.inf
    for e in edges:
        along, perp = p[e.along], p[1 - e.along]
        s = (e.coord - perp) * e.inward  # > 0 on the wall side of the inner face
        if e.a0 - _EPS <= along <= e.a1 + _EPS and -0.05 <= s <= t + _EPS and abs(s) < best_s:
            best, best_s = e, abs(s)
    if best is None:
        raise ValueError(f"{label} at ({p[0]:.4g}, {p[1]:.4g}) m is not on any wall; give the "
                         "position of the opening's centre on the wall's inner face")
    return best


def _opening_span(e: _Edge, p, width: float, label: str) -> tuple[float, float]:
    u = p[e.along]
    lo, hi = u - width / 2, u + width / 2
    if lo < e.a0 - _EPS or hi > e.a1 + _EPS:
        a = "xy"[e.along]
        raise ValueError(
            f"{label} (width_m = {width:.4g}) does not fit on its {e.describe()} "
            f"({e.a1 - e.a0:.4g} m long): the opening would span {a} from {lo:.4g} to {hi:.4g} m"
        )
    return lo, hi


def _set_interval(profile: tuple, z0: float, z1: float, mat: str | None) -> tuple:
    out = []
    for a, b, m in profile:
        if a < z0:
            out.append((a, min(b, z0), m))
        if b > z1:
            out.append((max(a, z1), b, m))
    if mat is not None:
        out.append((z0, z1, mat))
    return tuple(sorted(iv for iv in out if iv[1] - iv[0] > _EPS))


def _merge_cells(keys: np.ndarray) -> list[tuple[int, int, int, int, object]]:
    """Greedy merge of equal, non-None cells into rectangles (i0, i1, j0, j1, key)."""
    nx, ny = keys.shape
    done, active = [], {}
    for j in range(ny):
        runs, i = [], 0
        while i < nx:
            k = keys[i, j]
            if k is None:
                i += 1
                continue
            i0 = i
            while i < nx and keys[i, j] == k:
                i += 1
            runs.append((i0, i, k))
        new_active = {}
        for run in runs:
            rect = active.pop(run, None)
            new_active[run] = [run[0], run[1], rect[2] if rect else j, j + 1, run[2]]
        done += [tuple(r) for r in active.values()]
        active = new_active
    return done + [tuple(r) for r in active.values()]


def corridor_route(rooms: np.ndarray, margin_m: float = 0.6) -> np.ndarray:
    """Centre-line polyline through the rectangles in order, shape (n, 2), metres.

    Each rectangle contributes its centre line along its long side, stopped
    ``min(margin_m, width/2)`` short of its free ends; consecutive perpendicular lines
    are joined at their crossing.
    """
    lines = []
    for x0, y0, x1, y1 in rooms:
        if x1 - x0 >= y1 - y0:
            m = min(margin_m, (y1 - y0) / 2, (x1 - x0) / 2)
            y = (y0 + y1) / 2
            lines.append(np.array([[x0 + m, y], [x1 - m, y]]))
        else:
            m = min(margin_m, (x1 - x0) / 2, (y1 - y0) / 2)
            x = (x0 + x1) / 2
            lines.append(np.array([[x, y0 + m], [x, y1 - m]]))
    centres = [ln.mean(axis=0) for ln in lines]
    for k, ln in enumerate(lines):  # orient each line from the previous room to the next
        ref = centres[k + 1] if k + 1 < len(lines) else None
        if ref is not None and np.linalg.norm(ln[0] - ref) < np.linalg.norm(ln[1] - ref):
            lines[k] = ln[::-1]
        elif ref is None and k > 0 and np.linalg.norm(ln[1] - centres[k - 1]) < np.linalg.norm(ln[0] - centres[k - 1]):
            lines[k] = ln[::-1]
    pts = [lines[0][0]]
    for prev, cur in zip(lines[:-1], lines[1:], strict=True):
        dp, dc = prev[1] - prev[0], cur[1] - cur[0]
        if abs(dp[0] * dc[1] - dp[1] * dc[0]) > _EPS:  # perpendicular: join at the crossing
            pts.append(np.array([cur[0][0], prev[0][1]]) if abs(dp[0]) > abs(dp[1])
                       else np.array([prev[0][0], cur[0][1]]))
        else:
            pts += [prev[1], cur[0]]
    pts.append(lines[-1][1])
    route = np.array(pts, dtype=float)
    keep = np.r_[True, np.linalg.norm(np.diff(route, axis=0), axis=1) > _EPS]
    return route[keep]


def _rooms(spec: SceneSpec) -> np.ndarray:
    c = spec.corridor
    if spec.segments:
        return np.array([[*s.min_m, *s.max_m] for s in spec.segments], dtype=float)
    return np.array([[0.0, 0.0, c.length_m, c.width_m]])


def build_corridor(spec: SceneSpec) -> Scene:
    """Build the scene described by a corridor :class:`~scenes.spec.SceneSpec`.

    Raises
    ------
    ValueError
        A door or panel not on a wall or wider than its wall, an opening taller than
        the ceiling, a box reaching into a wall or through the ceiling, a tag inside a
        solid or away from every surface, a route through solid geometry.
    """
    c: CorridorSpec = spec.corridor
    src = spec.source or spec.name
    rooms = _rooms(spec)
    t, H = c.wall_thickness_m, c.height_m
    edges = _boundary_edges(rooms)

    # openings: (edge, along lo/hi, z0, z1, (material, construction) or None)
    openings, leaves, door_surfaces = [], [], []
    for i, p in enumerate(spec.panels):
        label = f"{src}: panel {p.id or '#' + str(i + 1)}"
        z1 = H if p.height_m is None else p.sill_m + p.height_m
        if z1 > H + _EPS or p.sill_m >= z1:
            raise ValueError(f"{label}: sill_m {p.sill_m} + height_m {p.height_m} exceeds the "
                             f"ceiling height {H} m")
        e = _find_edge(edges, p.position_m, t, label)
        mat = resolve_material_name(p.material)
        openings.append((e, _opening_span(e, p.position_m, p.width_m, label), p.sill_m, z1,
                         (mat, construction_of(c, mat, p.construction))))
    for i, d in enumerate(spec.doors):
        label = f"{src}: door {d.id or '#' + str(i + 1)}"
        if d.height_m > H + _EPS:
            raise ValueError(f"{label}: height_m {d.height_m} exceeds the ceiling height {H} m")
        e = _find_edge(edges, d.position_m, t, label)
        span = _opening_span(e, d.position_m, d.width_m, label)
        openings.append((e, span, 0.0, d.height_m, None))
        if d.closed:
            if d.recess_m + d.leaf_thickness_m > t + _EPS:
                raise ValueError(f"{label}: recess_m + leaf_thickness_m exceed the wall thickness {t} m")
            s0 = e.coord - e.inward * d.recess_m
            s1 = e.coord - e.inward * (d.recess_m + d.leaf_thickness_m)
            lo, hi = np.zeros(3), np.zeros(3)
            lo[e.along], hi[e.along] = span
            lo[1 - e.along], hi[1 - e.along] = min(s0, s1), max(s0, s1)
            hi[2] = d.height_m
            leaves.append((resolve_material_name(d.leaf_material), box_mesh(lo, hi)))
            lo[1 - e.along] = hi[1 - e.along] = s0  # the leaf's face towards the corridor
            normal = np.zeros(3)
            normal[1 - e.along] = e.inward
            door_surfaces.append(RadioSurface(d.leaf_material, d.leaf_thickness_m,
                                              rectangle_mesh(lo, hi, normal), "door"))

    xs = [rooms[:, [0, 2]].ravel(), rooms[:, [0, 2]].ravel() - t, rooms[:, [0, 2]].ravel() + t]
    ys = [rooms[:, [1, 3]].ravel(), rooms[:, [1, 3]].ravel() - t, rooms[:, [1, 3]].ravel() + t]
    for e, span, *_ in openings:
        (xs if e.along == 0 else ys).append(np.asarray(span))
    xs, ys = np.unique(np.round(np.concatenate(xs), 9)), np.unique(np.round(np.concatenate(ys), 9))
    free = _cells(rooms, xs, ys)
    grown = _cells(rooms, xs, ys, grow=t)
    wall = grown & ~free
    cx, cy = (xs[:-1] + xs[1:]) / 2, (ys[:-1] + ys[1:]) / 2
    keys = np.full(wall.shape, None, dtype=object)
    wall_mat = resolve_material_name(c.wall_material)
    base = ((0.0, H, (wall_mat, construction_of(c, wall_mat))),)
    for i, j in zip(*np.nonzero(wall), strict=True):
        keys[i, j] = base
    for e, (u0, u1), z0, z1, mat in openings:
        w0, w1 = e.wall_range(t)
        centre = (cx, cy)
        in_u = (centre[e.along] > u0) & (centre[e.along] < u1)
        in_w = (centre[1 - e.along] > w0) & (centre[1 - e.along] < w1)
        sel = (in_u[:, None] & in_w[None, :]) if e.along == 0 else (in_w[:, None] & in_u[None, :])
        for i, j in zip(*np.nonzero(sel & wall), strict=True):
            keys[i, j] = _set_interval(keys[i, j], z0, z1, mat)

    parts: dict[str, list] = {}
    for i0, i1, j0, j1, profile in _merge_cells(keys):
        for z0, z1, (mat, _) in profile:
            parts.setdefault(mat, []).append(box_mesh([xs[i0], ys[j0], z0], [xs[i1], ys[j1], z1]))
    slab = np.where(grown, True, None)
    rects = [(xs[i0], ys[j0], xs[i1], ys[j1]) for i0, i1, j0, j1, _ in _merge_cells(slab)]
    for x0, y0, x1, y1 in rects:
        parts.setdefault(resolve_material_name(c.floor_material), []).append(
            box_mesh([x0, y0, -c.floor_thickness_m], [x1, y1, 0.0]))
        parts.setdefault(resolve_material_name(c.ceiling_material), []).append(
            box_mesh([x0, y0, H], [x1, y1, H + c.ceiling_thickness_m]))
    for mat, mesh in leaves:
        parts.setdefault(mat, []).append(mesh)
    radio = wall_surfaces(xs, ys, free, grown, keys, t) + door_surfaces + [
        slab_surface(rects, 0.0, True, c.floor_material, c.floor_thickness_m, "floor"),
        slab_surface(rects, H, False, c.ceiling_material, c.ceiling_thickness_m, "ceiling")]

    free_space = np.stack([np.c_[rooms[:, :2], np.zeros(len(rooms))],
                           np.c_[rooms[:, 2:], np.full(len(rooms), H)]], axis=1)
    for kind, items in (("box", spec.boxes), ("cabinet", spec.cabinets)):
        for i, b in enumerate(items):
            label = f"{src}: {kind} {b.id or '#' + str(i + 1)}"
            yaw = np.deg2rad(b.yaw_deg)
            half = np.array(b.size_m[:2]) / 2
            rot = np.array([[np.cos(yaw), -np.sin(yaw)], [np.sin(yaw), np.cos(yaw)]])
            corners = np.array(b.center_m) + (np.array([[-1, -1], [1, -1], [1, 1], [-1, 1]]) * half) @ rot.T
            top = b.z_m + b.size_m[2]
            pts = np.c_[np.repeat(corners, 2, axis=0), np.tile([b.z_m, top], 4)]
            if not np.all(points_in_boxes(pts, free_space)):
                raise ValueError(f"{label} at center_m {b.center_m} with size_m {b.size_m} reaches "
                                 "outside the free space (into a wall, the floor or the ceiling)")
            lo = np.array([b.center_m[0] - half[0], b.center_m[1] - half[1], b.z_m])
            hi = np.array([b.center_m[0] + half[0], b.center_m[1] + half[1], top])
            shell = box_mesh(lo, hi, yaw)
            parts.setdefault(resolve_material_name(b.material), []).append(shell)
            radio.append(RadioSurface(b.material, get_material(b.material).thickness_m, shell, "shell"))

    meshes = {mat: merge_meshes(ms) for mat, ms in sorted(parts.items())}
    route = np.array(spec.route_m, dtype=float) if spec.route_m is not None else corridor_route(rooms)
    scene = Scene(
        name=spec.name,
        meshes=meshes,
        tags=TagSet(np.zeros(0, dtype=str), np.zeros((0, 3)), np.zeros((0, 3))),
        source=spec.source or "generated",
        metadata={"generator": "scenes.generator.build_corridor", "spec": spec_to_dict(spec),
                  **overrides_metadata(spec)},
        route_m=route,
        free_space_m=free_space,
        radio_surfaces=tuple(radio),
    )
    scene.tags = make_tags(scene, spec.tags, f"{src}: tag")
    validate_tags(scene)
    _check_route(scene)
    return scene


def _check_route(scene: Scene, step_m: float = 0.1) -> None:
    route = np.asarray(scene.route_m, dtype=float)
    pts = [route[:1]]
    for a, b in zip(route[:-1], route[1:], strict=True):
        n = max(1, int(np.ceil(np.linalg.norm(b - a) / step_m)))
        pts.append(a + (b - a) * (np.arange(1, n + 1) / n)[:, None])
    xy = np.concatenate(pts)
    for z in (0.05, 0.3):
        ok = is_free(scene, np.c_[xy, np.full(len(xy), z)])
        if not np.all(ok):
            x, y = xy[np.flatnonzero(~ok)[0]]
            raise ValueError(f"{scene.name}: the route passes through solid geometry or leaves the "
                             f"free space at ({x:.4g}, {y:.4g}) m")


def corridor(
    length_m: float = 25.0,
    width_m: float = 2.4,
    height_m: float = 3.0,
    wall_material: str = "plasterboard",
    floor_material: str = "concrete",
    ceiling_material: str = "ceiling_board",
    wall_thickness_m: float = 0.12,
    doors=(),
    glass_panels=(),
    boxes=(),
    cabinets=(),
    tags=(),
    name: str = "corridor",
    *,
    panels=(),
    segments=None,
    floor_thickness_m: float = 0.2,
    ceiling_thickness_m: float = 0.05,
    route_m=None,
    description: str = "",
    wall_construction: str | None = None,
    material_construction: dict[str, str] | None = None,
) -> Scene:
    """Generate a corridor scene.

    Straight by default: free space x in [0, length_m], y in [0, width_m], z in
    [0, height_m], with solid walls (and end walls) outside it. Give ``segments``
    (rectangles ``{"min_m": (x, y), "max_m": (x, y)}``) for an L or T junction; then
    ``length_m`` and ``width_m`` are ignored.

    Parameters
    ----------
    length_m, width_m, height_m : float
        Free-space size, metres.
    wall_material, floor_material, ceiling_material : str
        Library material names.
    wall_thickness_m : float
        Wall slab thickness, metres.
    doors : sequence of DoorSpec or dict
        Openings cut into walls, open or closed by a wooden leaf.
    glass_panels, panels : sequence of PanelSpec or dict
        Wall sections of another material (glass by default).
    boxes, cabinets : sequence of BoxSpec / CabinetSpec or dict
        Chipboard boxes and metal cabinets standing in the corridor.
    tags : sequence of TagSpec or dict
        Tags: point on a surface, optional normal, offset (5 mm).
    name : str
        Scene name.
    segments : sequence of SegmentSpec or dict, optional
        Free-space rectangles whose union is the walkable area.
    floor_thickness_m, ceiling_thickness_m : float
        Slab thicknesses, metres.
    route_m : array_like (n, 2), optional
        Robot route; default: the centre line (:func:`corridor_route`).
    description : str
        Free text stored in the metadata.
    wall_construction : str, optional
        Construction of the ``wall_material`` pieces (``"solid"``, ``"stud"``,
        ``"double"``, ``"single"``); default: plasterboard ``"stud"``, else ``"solid"``.
    material_construction : dict of str to str, optional
        Construction per material for every wall piece of it (panels' own
        ``construction`` wins).

    Returns
    -------
    Scene
        One solid mesh per material, radio surfaces (:mod:`scenes.corridor_radio`), tags,
        ``route_m``, ``free_space_m`` and the spec in ``metadata["spec"]``.
    """
    where = "corridor()"
    straight = segments is None
    cspec = parse_item(CorridorSpec, {
        "height_m": height_m, "length_m": length_m if straight else None,
        "width_m": width_m if straight else None, "wall_material": wall_material,
        "floor_material": floor_material, "ceiling_material": ceiling_material,
        "wall_thickness_m": wall_thickness_m, "floor_thickness_m": floor_thickness_m,
        "ceiling_thickness_m": ceiling_thickness_m, "wall_construction": wall_construction,
        "material_construction": dict(material_construction or {})}, where)

    def items(cls, seq, key):
        return tuple(parse_item(cls, it, f"{where}: {key} #{i + 1}") for i, it in enumerate(seq))

    spec = SceneSpec(
        name=name,
        description=description,
        source_tables={"corridor": cspec},
        segments=items(SegmentSpec, segments or (), "segments"),
        doors=items(DoorSpec, doors, "doors"),
        panels=items(PanelSpec, list(glass_panels) + list(panels), "panels"),
        boxes=items(BoxSpec, boxes, "boxes"),
        cabinets=items(CabinetSpec, cabinets, "cabinets"),
        tags=items(TagSpec, tags, "tags"),
        route_m=None if route_m is None else tuple(map(tuple, np.asarray(route_m, dtype=float).tolist())),
    )
    check_spec(spec, where)
    return build_corridor(spec)
