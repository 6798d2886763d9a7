"""A coverage route: through the free space, past every tag-bearing face within a standoff.

An inventory robot drives the aisles; the route it follows here is planned, not drawn:

1. tags are grouped into *faces* (:func:`tag_faces`): tags sharing a horizontal normal
   and a plane, split where neighbours along the face are more than ``gap_m`` apart or
   an obstacle of the collision map stands between them (a partition meeting a wall);
2. each face gets a *pass*: the face's span moved along its normal by an offset as close
   as it can be to ``min(standoff, half the free depth in front)`` (the aisle's middle in a
   narrow aisle: one pass then serves both sides), with every point of it in the free
   space inflated by the robot's turning radius plus a margin; a pass already within the
   standoff of every tag of a face covers it too (no second pass). Where no offset fits
   the whole span (a wall face running into a room's corners, ``[tags] walls = true``),
   the longest stretch of the pass that keeps the clearance serves the face if every tag
   is still within the standoff of it;
3. the passes are chained greedily (nearest free end next) by shortest paths on the
   8-connected grid of inflated free cells: scipy.sparse.csgraph's Dijkstra does the graph
   search, shapely simplifies the joined polyline within half a grid cell.

The collision map (:func:`pipeline.robot.trajectory.collision_map`: the scene's meshes
sliced over the robot's height, racks' shelves and uprights included; its largest
enclosed free region, the building's main floor) is what "free" means. A real map's
noise leaves faces no pass can serve (a rack corner in a 0.9 m gap, a face in a room the
robot cannot enter): such a face is *skipped*, not fatal. The route serves the others, and
:attr:`CoverageRoute.skipped` names each skipped face with its reason; passes in several
unconnected free regions keep the region holding the most tags and skip the rest. Only a
map where no face can be served stops the planning, with a message naming the map and
the reasons.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy import sparse
from scipy.sparse.csgraph import connected_components, dijkstra

from pipeline.robot.occupancy import _densify
from pipeline.robot.trajectory import collision_map
from scenes import is_free as scene_is_free

__all__ = ["CoverageRoute", "SkippedFace", "TagFace", "plan_coverage_route", "route_clearance_m", "tag_faces"]


@dataclass(frozen=True)
class TagFace:
    """Tags on one planar vertical face.

    Attributes
    ----------
    start_m, end_m : numpy.ndarray
        Ends (2,) [m] of the tags' span along the face (their horizontal positions).
    normal : numpy.ndarray
        Unit horizontal normal (2,) into free space.
    tag_index : numpy.ndarray
        Indices (k,) int of the face's tags in the tag arrays given to :func:`tag_faces`.
    """

    start_m: np.ndarray
    end_m: np.ndarray
    normal: np.ndarray
    tag_index: np.ndarray

    def describe(self) -> str:
        """``"face (x0, y0)-(x1, y1) m facing (nx, ny)"``."""
        a, b, n = self.start_m, self.end_m, self.normal
        return (f"tag face ({a[0]:.2f}, {a[1]:.2f})-({b[0]:.2f}, {b[1]:.2f}) m facing "
                f"({n[0]:.2f}, {n[1]:.2f}), {len(self.tag_index)} tags")


@dataclass(frozen=True)
class SkippedFace:
    """A tag face the route does not serve, and why.

    Attributes
    ----------
    face : TagFace
        The face.
    reason : str
        One line starting ``"no pass fits: "`` (no offset within the standoff keeps the
        robot's clearance), ``"cut off: "`` (its free space is not connected to the main
        free space) or ``"other region: "`` (its pass lies in a free region other than the
        route's), then the details.
    """

    face: TagFace
    reason: str

    def describe(self) -> str:
        """``"<face>: <reason>"``."""
        return f"{self.face.describe()}: {self.reason}"


@dataclass(frozen=True)
class CoverageRoute:
    """A planned coverage route.

    Attributes
    ----------
    route_m : numpy.ndarray
        Polyline (n, 2) [m] the robot follows.
    passes_m : numpy.ndarray
        Pass segments (p, 2, 2) [m], in driving order.
    faces : tuple of TagFace
        The tag faces.
    face_pass : numpy.ndarray
        (n_faces,) int: the pass that covers each face; -1 for a skipped face.
    standoff_m : float
        Every tag of a served face lies within this of the route (horizontal distance) [m].
    inflation_m : float
        Clearance every route point keeps from obstacles (robot radius + margin) [m].
    skipped : tuple of SkippedFace
        The faces no pass serves, with the reason (empty when every face is served).
    """

    route_m: np.ndarray
    passes_m: np.ndarray
    faces: tuple[TagFace, ...]
    face_pass: np.ndarray
    standoff_m: float
    inflation_m: float
    skipped: tuple[SkippedFace, ...] = ()

    @property
    def skipped_tag_index(self) -> np.ndarray:
        """Indices (k,) int of the tags on skipped faces, sorted."""
        if not self.skipped:
            return np.zeros(0, dtype=int)
        return np.sort(np.concatenate([s.face.tag_index for s in self.skipped]))

    @property
    def length_m(self) -> float:
        """Length of the route [m]."""
        return float(np.linalg.norm(np.diff(self.route_m, axis=0), axis=1).sum())


def tag_faces(positions_m, normals, gap_m: float = 1.0, plane_tol_m: float = 0.02,
              blocked=None) -> list[TagFace]:
    """Group tags into planar faces (see the module docstring).

    Parameters
    ----------
    positions_m : array_like
        Tag centres (n, 3) [m].
    normals : array_like
        Unit normals (n, 3); tags with a mostly vertical normal (floor, ceiling) are left out.
    gap_m : float
        Neighbours along a face farther apart than this start a new face [m].
    plane_tol_m : float
        Tags whose planes differ by less than this share a face [m].
    blocked : callable, optional
        ``blocked(points (k, 2)) -> bool (k,)``: occupied points. Neighbours along a face
        with an occupied point on the line between them, 0.1 m in front of the face (a
        partition abutting a wall between them), start a new face too.

    Returns
    -------
    list of TagFace
    """
    p = np.asarray(positions_m, dtype=float).reshape(-1, 3)
    n = np.asarray(normals, dtype=float).reshape(-1, 3)
    nh = n[:, :2]
    norm = np.linalg.norm(nh, axis=1)
    ok = norm > 0.5
    nh = np.where(ok[:, None], nh / np.where(norm > 0, norm, 1.0)[:, None], 0.0)
    key_dir = np.round(np.degrees(np.arctan2(nh[:, 1], nh[:, 0]))).astype(int)
    faces = []
    for d in np.unique(key_dir[ok]):
        idx = np.flatnonzero(ok & (key_dir == d))
        nrm = nh[idx].mean(axis=0)
        nrm /= np.linalg.norm(nrm)
        tan = np.array([-nrm[1], nrm[0]])
        off = p[idx, :2] @ nrm
        order = np.argsort(off, kind="stable")
        planes = np.split(idx[order], np.flatnonzero(np.diff(off[order]) > plane_tol_m) + 1)
        for plane in planes:
            s = p[plane, :2] @ tan
            o = np.argsort(s, kind="stable")
            cut = np.diff(s[o]) > gap_m
            if blocked is not None and len(o) > 1:
                q = p[plane[o], :2] + 0.1 * nrm
                f = np.linspace(0.0, 1.0, 9)[1:-1]
                between = q[:-1, None, :] + f[None, :, None] * (q[1:] - q[:-1])[:, None, :]
                cut |= np.asarray(blocked(between.reshape(-1, 2))).reshape(len(o) - 1, -1).any(axis=1)
            for run in np.split(plane[o], np.flatnonzero(cut) + 1):
                c = float(np.mean(p[run, :2] @ nrm))
                ss = p[run, :2] @ tan
                faces.append(TagFace(c * nrm + ss.min() * tan, c * nrm + ss.max() * tan, nrm,
                                     np.sort(run)))
    return faces


def _segment_distance(points: np.ndarray, a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Distance (n,) of points (n, 2) to the segment a-b [m]."""
    e = b - a
    t = np.clip(((points - a) @ e) / max(float(e @ e), 1e-12), 0.0, 1.0)
    return np.linalg.norm(points - (a + t[:, None] * e), axis=1)


def route_clearance_m(cmap, route_m, step_m: float = 0.05) -> np.ndarray:
    """Clearance [m] of the collision map along a polyline sampled every ``step_m``."""
    return cmap.clearance_m(_densify(np.asarray(route_m, dtype=float), step_m))


def plan_coverage_route(scene, robot, standoff_m: float = 1.0, *, margin_m: float = 0.25,
                        resolution_m: float = 0.1, gap_m: float = 1.0,
                        name: str | None = None) -> CoverageRoute:
    """Plan a coverage route past every tag face of ``scene`` (see the module docstring).

    Parameters
    ----------
    scene : scenes.Scene
        Its tags (positions, normals) define the faces; its meshes the free space.
    robot : pipeline.robot.Robot
        Its turning radius (``radius_m``) inflates the obstacles.
    standoff_m : float
        Largest horizontal distance from every tag to the route [m].
    margin_m : float
        Clearance kept beyond the robot's radius [m] (room for the tour's lanes and the
        smoothing of corners).
    resolution_m : float
        Cell size of the planning grid [m].
    gap_m : float
        Face splitting distance (:func:`tag_faces`) [m].
    name : str, optional
        The map's name in messages (default the scene's source).

    Returns
    -------
    CoverageRoute

    Raises
    ------
    ValueError
        No tags; no face any pass can serve (the map and the reasons are named).
    """
    label = name or str(scene.source or scene.name)
    if not standoff_m > 0:
        raise ValueError(f"{label}: route standoff_m must be positive, got {standoff_m!r}")
    if len(scene.tags) == 0:
        raise ValueError(f"{label}: no tags to plan a coverage route past (give [tags] or a route)")
    cmap = collision_map(scene, robot, route_m=np.zeros((0, 2)))
    faces = tag_faces(scene.tags.positions_m, scene.tags.normals, gap_m, blocked=cmap.is_occupied)
    infl = float(robot.radius_m + margin_m)
    if infl > standoff_m:
        raise ValueError(f"{label}: route standoff_m {standoff_m} m is below the robot's radius "
                         f"plus margin ({infl:.2f} m): no pass can be that close to a face")
    # planning grid over the collision map
    (x0, y0), (ny0, nx0) = cmap.origin_m, cmap.shape
    nx = int(np.floor(nx0 * cmap.resolution_m / resolution_m))
    ny = int(np.floor(ny0 * cmap.resolution_m / resolution_m))
    gx = x0 + (np.arange(nx) + 0.5) * resolution_m
    gy = y0 + (np.arange(ny) + 0.5) * resolution_m
    cx, cy = np.meshgrid(gx, gy)
    ok = cmap.clearance_m(np.stack([cx, cy], -1)) >= infl  # (ny, nx)

    def cell(p):
        col = np.clip(np.floor((p[..., 0] - x0) / resolution_m).astype(int), 0, nx - 1)
        row = np.clip(np.floor((p[..., 1] - y0) / resolution_m).astype(int), 0, ny - 1)
        return row, col

    def line_ok(a, b):
        k = max(2, int(np.ceil(np.linalg.norm(b - a) / (resolution_m / 2))) + 1)
        pts = a + np.linspace(0.0, 1.0, k)[:, None] * (b - a)
        return bool(np.all(cmap.clearance_m(pts) >= infl))

    passes: list[np.ndarray] = []
    skipped: list[SkippedFace] = []
    face_pass = np.full(len(faces), -1)
    xy = scene.tags.positions_m[:, :2]
    order = np.argsort([-np.linalg.norm(f.end_m - f.start_m) for f in faces], kind="stable")
    faces = list(faces)
    work = [int(i) for i in order]
    while work:
        fi = work.pop(0)
        f = faces[fi]
        for pi, (a, b) in enumerate(passes):
            if np.all(_segment_distance(xy[f.tag_index], a, b) <= standoff_m + 1e-9):
                face_pass[fi] = pi
                break
        if face_pass[fi] >= 0:
            continue
        mid = (f.start_m + f.end_m) / 2
        ray = mid + np.arange(1, 400)[:, None] * (cmap.resolution_m / 2) * f.normal
        occ = cmap.is_occupied(ray)
        first_free = int(np.argmax(~occ))  # the face's own cells (rasterised) come first
        hit = np.flatnonzero(occ[first_free:]) + first_free
        depth = (hit[0] + 1) * cmap.resolution_m / 2 if len(hit) else np.inf
        target = min(standoff_m, depth / 2)
        offsets = np.arange(infl, standoff_m + 1e-9, resolution_m / 2)
        chosen = best = None
        for d in offsets[np.argsort(np.abs(offsets - target), kind="stable")]:
            a, b = f.start_m + d * f.normal, f.end_m + d * f.normal
            if line_ok(a, b):
                chosen = np.stack([a, b])
                break
            run = _trimmed_pass(a, b, xy[f.tag_index], cmap, infl, standoff_m, resolution_m)
            if run is not None and (best is None or run[1].sum() > best[1].sum()):
                best = run
        if chosen is None and best is not None and best[1].any():
            chosen, covered = best
            if not covered.all():
                # an obstacle (a pillar in the aisle) blocks part of the pass: the tags the
                # longest clear stretch serves become a face of their own, the others go
                # back to the work list as the contiguous faces they form
                faces[fi] = _sub_face(f, f.tag_index[covered], xy)
                for part in _contiguous(f, f.tag_index[~covered], xy):
                    faces.append(_sub_face(f, part, xy))
                    face_pass = np.append(face_pass, -1)
                    work.append(len(faces) - 1)
        if chosen is None:
            front = (f.start_m + f.end_m) / 2 + infl * f.normal
            # free in the scene but not in the collision map's main region: cut off from it
            if scene_is_free(scene, [[front[0], front[1], 0.35]])[0] and cmap.is_occupied(front[None])[0]:
                skipped.append(SkippedFace(f, f"cut off: the free space in front of it, around "
                                              f"({front[0]:.2f}, {front[1]:.2f}) m, is not connected to "
                                              "the building's main free space"))
            else:
                skipped.append(SkippedFace(f, f"no pass fits: no robot pass within standoff_m = "
                                              f"{standoff_m} m keeps the robot's radius "
                                              f"{robot.radius_m:.2f} m + margin {margin_m} m"))
            continue
        passes.append(chosen)
        face_pass[fi] = len(passes) - 1

    # 8-connected graph of inflated free cells
    idx = -np.ones((ny, nx), dtype=np.int64)
    idx[ok] = np.arange(int(ok.sum()))
    rows, cols, w = [], [], []
    for dr, dc in ((0, 1), (1, 0), (1, 1), (1, -1)):
        a = idx[max(0, -dr):ny - max(0, dr), max(0, -dc):nx - max(0, dc)]  # cell (r, c)
        b = idx[max(0, dr):ny + min(0, dr), max(0, dc):nx + min(0, dc)]  # cell (r + dr, c + dc)
        m = (a >= 0) & (b >= 0)
        rows.append(a[m])
        cols.append(b[m])
        w.append(np.full(int(m.sum()), resolution_m * np.hypot(dr, dc)))
    n_nodes = int(ok.sum())
    graph = sparse.coo_matrix((np.concatenate(w), (np.concatenate(rows), np.concatenate(cols))),
                              shape=(n_nodes, n_nodes)).tocsr()
    _, comp = connected_components(graph, directed=False)
    ends = np.array(passes).reshape(-1, 2)
    er, ec = cell(ends)
    end_node = idx[er, ec]
    for k in np.flatnonzero(end_node < 0):  # a pass end whose cell centre lacks clearance:
        r0, c0 = er[k], ec[k]  # the nearest planning cell within two cells that has it
        win = idx[max(r0 - 2, 0):r0 + 3, max(c0 - 2, 0):c0 + 3]
        rr, cc = np.nonzero(win >= 0)
        if len(rr):
            j = int(np.argmin((rr + max(r0 - 2, 0) - r0) ** 2 + (cc + max(c0 - 2, 0) - c0) ** 2))
            end_node[k] = win[rr[j], cc[j]]
    # a pass in a free region other than the one with the most tags is skipped (map noise
    # pinches an aisle shut; a room behind a door narrower than the robot)
    n_pass = len(passes)
    pass_comp = np.full(n_pass, -1)
    for pi in range(n_pass):
        e0, e1 = end_node[2 * pi], end_node[2 * pi + 1]
        if e0 >= 0 and e1 >= 0 and comp[e0] == comp[e1]:
            pass_comp[pi] = comp[e0]
    tags_of_pass = np.zeros(n_pass)
    for fi, pi in enumerate(face_pass):
        if pi >= 0:
            tags_of_pass[pi] += len(faces[fi].tag_index)
    valid = pass_comp >= 0
    if valid.any():
        comps = np.unique(pass_comp[valid])
        weight = [tags_of_pass[pass_comp == c].sum() for c in comps]
        home = comps[int(np.argmax(weight))]
    else:
        home = -2
    keep = pass_comp == home
    for fi, pi in enumerate(face_pass):
        if pi < 0 or keep[pi]:
            continue
        # a face that took the first pass near it may be served by a kept one too
        other = [q for q in np.flatnonzero(keep) if np.all(
            _segment_distance(xy[faces[fi].tag_index], *passes[q]) <= standoff_m + 1e-9)]
        if other:
            face_pass[fi] = other[0]
            continue
        p = passes[pi].mean(axis=0)
        e0, e1 = end_node[2 * pi], end_node[2 * pi + 1]
        why = ("its pass ends off the planning grid's free cells" if min(e0, e1) < 0 else
               "its pass's two ends lie in unconnected free regions" if comp[e0] != comp[e1] else
               "its pass cannot be reached from the route's free region")
        skipped.append(SkippedFace(faces[fi], f"other region: {why} (around ({p[0]:.2f}, {p[1]:.2f}) m, "
                                              f"free space inflated by {infl:.2f} m)"))
    if not keep.any():
        reasons = sorted({s_.reason.split(":")[0] for s_ in skipped})
        raise ValueError(f"{label}: no route: none of the {len(faces)} tag faces can be served "
                         f"({', '.join(reasons)}); first: {skipped[0].describe() if skipped else '-'}")
    new_index = np.cumsum(keep) - 1
    face_pass = np.where((face_pass >= 0) & keep[np.maximum(face_pass, 0)], new_index[np.maximum(face_pass, 0)], -1)
    passes = [q for q, k_ in zip(passes, keep, strict=True) if k_]
    end_node = end_node.reshape(-1, 2)[keep].reshape(-1)

    centres = np.stack([cx[ok], cy[ok]], 1)
    todo = set(range(len(passes)))
    # start at the first kept pass (the longest face's served), at its first end
    route = [passes[0][0], passes[0][1]]
    driven = [passes[0]]
    driven_order = [0]
    todo.discard(0)
    node = end_node[1]
    while todo:
        dist, pred = dijkstra(graph, directed=False, indices=int(node), return_predecessors=True)
        cand = sorted((dist[end_node[2 * p + e]], p, e) for p in todo for e in (0, 1))
        _, cur_pass, cur_end = cand[0]
        target = int(end_node[2 * cur_pass + cur_end])
        path = []
        while target != node and target >= 0:
            path.append(target)
            target = pred[target]
        route += [centres[i] for i in path[::-1]]
        seg = passes[cur_pass] if cur_end == 0 else passes[cur_pass][::-1]
        route += [seg[0], seg[1]]
        driven.append(seg)
        driven_order.append(cur_pass)
        todo.discard(cur_pass)
        node = end_node[2 * cur_pass + (1 - cur_end)]
    route_m = _simplify(np.array(route), resolution_m / 2)
    clear = route_clearance_m(cmap, route_m)
    if np.any(clear < robot.radius_m):
        raise ValueError(f"{label}: the planned route leaves the free space (clearance "
                         f"{clear.min():.3f} m < robot radius {robot.radius_m:.3f} m)")
    rank = np.empty(len(passes), dtype=int)
    rank[driven_order] = np.arange(len(passes))
    face_rank = np.where(face_pass >= 0, rank[np.maximum(face_pass, 0)], -1)
    order = sorted(range(len(skipped)), key=lambda i: tuple(skipped[i].face.tag_index[:1]))
    return CoverageRoute(route_m, np.array(driven), tuple(faces), face_rank, float(standoff_m), infl,
                         tuple(skipped[i] for i in order))


def _trimmed_pass(a: np.ndarray, b: np.ndarray, tags_xy: np.ndarray, cmap, infl: float,
                  standoff_m: float, resolution_m: float) -> tuple[np.ndarray, np.ndarray] | None:
    """The longest stretch of the pass a-b in the inflated free space, and the tags it serves.

    A face whose pass cannot run its whole length (a wall face running into a room's
    corner, a pillar standing in the aisle) is served by the longest run of the pass,
    sampled every quarter planning cell, whose points all keep ``infl`` from obstacles.
    Returns the stretch (2, 2) [m] and which tags (k, 2) of the face lie within
    ``standoff_m`` of it (k,) bool, or None when no point of the pass is clear.
    """
    k = max(2, int(np.ceil(np.linalg.norm(b - a) / (resolution_m / 4))) + 1)
    t = np.linspace(0.0, 1.0, k)
    ok = cmap.clearance_m(a + t[:, None] * (b - a)) >= infl
    if not ok.any():
        return None
    edges = np.diff(np.r_[0, ok.astype(np.int8), 0])
    starts, stops = np.flatnonzero(edges == 1), np.flatnonzero(edges == -1) - 1
    j = int(np.argmax(stops - starts))
    seg = np.stack([a + t[starts[j]] * (b - a), a + t[stops[j]] * (b - a)])
    return seg, _segment_distance(tags_xy, seg[0], seg[1]) <= standoff_m + 1e-9


def _sub_face(face: TagFace, tag_index: np.ndarray, xy: np.ndarray) -> TagFace:
    """The part of ``face`` holding the tags ``tag_index`` (same plane and normal)."""
    tan = np.array([-face.normal[1], face.normal[0]])
    s = xy[tag_index] @ tan
    base = face.start_m - (face.start_m @ tan) * tan
    return TagFace(base + s.min() * tan, base + s.max() * tan, face.normal, np.sort(tag_index))


def _contiguous(face: TagFace, tag_index: np.ndarray, xy: np.ndarray) -> list[np.ndarray]:
    """``tag_index`` split into the runs that are contiguous along ``face`` (by its tag order)."""
    tan = np.array([-face.normal[1], face.normal[0]])
    all_s = xy[face.tag_index] @ tan
    rank = {int(t): r for r, t in enumerate(face.tag_index[np.argsort(all_s, kind="stable")])}
    ranks = np.array(sorted(rank[int(t)] for t in tag_index))
    by_rank = {r: t for t, r in rank.items()}
    groups = np.split(ranks, np.flatnonzero(np.diff(ranks) > 1) + 1)
    return [np.array([by_rank[int(r)] for r in g]) for g in groups if len(g)]


def _simplify(route: np.ndarray, tol_m: float) -> np.ndarray:
    """Polyline without repeated points, simplified within ``tol_m`` (shapely)."""
    from shapely.geometry import LineString

    keep = np.r_[True, np.linalg.norm(np.diff(route, axis=0), axis=1) > 1e-9]
    route = route[keep]
    if len(route) < 3:
        return route
    return np.asarray(LineString(route).simplify(tol_m, preserve_topology=False).coords, dtype=float)
