"""Obstacles of an occupancy-grid map: outlines, centre lines and a construction by rule.

Libraries do the image work: scikit-image labels the connected obstacles
(``measure.label``, 8-connected) and thins each to its centre line
(``morphology.skeletonize``); shapely traces the outlines (the union of each obstacle's
row runs of cells: the exact outline along the cell edges, holes included), simplifies
them (Douglas-Peucker within ``tolerance_m``, topology preserved) and gives the minimum
rotated rectangle the rules use; ``measure.approximate_polygon`` straightens the centre
lines within the same tolerance.

Connected obstacles are first split into their thick part (an opening with a square
``thin_wall_max_m`` wide, scipy.ndimage) and the thin lines left over, so a partition
that joins the outer wall is an obstacle of its own. Obstacles smaller than
``min_area_m2`` are laser noise (a person, a stray return) and
make no geometry; the robot's map keeps them. Rules, first match wins
(:class:`ExtractionRules`, each threshold a field):

1. *outer*: the obstacle touches the outside of the building (the image border or an
   unknown region connected to it): a wall of ``outer_material`` (concrete), solid;
2. *pillar*: the long side of its minimum rotated rectangle is at most
   ``pillar_max_m``: a pillar of ``pillar_material`` (concrete);
3. *rack*: it fills at least ``rack_min_fill`` of its minimum rotated rectangle, whose
   short side is at least ``rack_min_depth_m`` and long side at least
   ``rack_min_length_m``: a free-standing metal shelving rack;
4. *partition*: its mean thickness (area / centre-line length) is below
   ``thin_wall_max_m``: a plasterboard stud wall;
5. otherwise a thick wall of ``thick_material`` (brick), solid.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np
import shapely
from scipy import ndimage
from shapely.geometry import Point, Polygon

from scenes.mapclean import clean_cell_class
from scenes.radio import default_construction
from scenes.rosmap import OBSTACLE, OUTSIDE, RosMap, resolve_unknown

__all__ = ["KINDS", "LASER_BAND_M", "ExtractionRules", "MapObstacle", "apply_override", "extract_obstacles",
           "map_cells"]

#: What an obstacle is: a wall (its material and construction decide the radio surfaces),
#: a shelving rack (shelf boards and uprights) or a pillar (a closed shell).
KINDS = ("wall", "rack", "pillar")


@dataclass(frozen=True)
class ExtractionRules:
    """Thresholds of the construction rules (see the module docstring).

    Attributes
    ----------
    outer_material : str
        Material of obstacles touching the outside (default concrete).
    thick_material : str
        Material of thick inner walls (default brick).
    thin_material : str
        Material of thin partitions (default plasterboard, construction ``"stud"``).
    thin_wall_max_m : float
        Mean thickness below which a wall is a thin partition [m].
    pillar_max_m : float
        Largest long side of a pillar's minimum rotated rectangle [m].
    pillar_material : str
        Material of pillars.
    rack_min_fill : float
        Smallest area fraction of its minimum rotated rectangle a rack fills [1].
    rack_min_depth_m, rack_min_length_m : float
        Smallest short and long side of a rack's rectangle [m].
    min_area_m2 : float
        Obstacles of less area are noise: no geometry [m^2].
    gap_close_m : float
        Outline gaps up to this wide are closed before extraction [m]
        (:mod:`scenes.mapclean`); 0: none.
    fill_max_width_m : float
        Enclosed regions, mostly unknown, at most this wide become obstacle (the unseen
        inside of a rack's or pallet's outline) [m] (:mod:`scenes.mapclean`); 0: none.
    fill_free_max_width_m : float
        Enclosed regions at most this wide become obstacle whatever they hold [m]; 0: none.
    """

    outer_material: str = "concrete"
    thick_material: str = "brick"
    thin_material: str = "plasterboard"
    thin_wall_max_m: float = 0.15
    pillar_max_m: float = 0.8
    pillar_material: str = "concrete"
    rack_min_fill: float = 0.85
    rack_min_depth_m: float = 0.35
    rack_min_length_m: float = 1.0
    min_area_m2: float = 0.02
    # a real map's outline gaps are a cell or two (3-5 cm maps: up to 0.1 m); door gaps are
    # 0.7 m and up, so they stay open
    gap_close_m: float = 0.1
    # racks are 0.8-1.2 m deep, back-to-back rows up to 2.5 m (two 1.1 m rows and a flue); an
    # enclosed region is one the robot cannot enter, so a narrow closed room is lost, not a
    # route
    fill_max_width_m: float = 2.5
    # a free enclosed region narrower than the robot (0.8 m) is laser seen between shelves
    fill_free_max_width_m: float = 0.8


def map_cells(rosmap: RosMap, rules: ExtractionRules | None = None):
    """The map's cell classes as the extraction reads them, and what cleaning changed.

    :func:`scenes.mapclean.clean_cell_class` (gaps closed, enclosed outlines filled), then
    :func:`scenes.rosmap.resolve_unknown`.

    Returns
    -------
    cells : numpy.ndarray
        Shape (ny, nx), int8: ``OBSTACLE`` / ``FREE`` / ``OUTSIDE``.
    report : scenes.mapclean.CleaningReport
    """
    rules = ExtractionRules() if rules is None else rules
    cleaned, report = clean_cell_class(rosmap.cell_class, rosmap.resolution_m, rosmap.origin_m,
                                       gap_close_m=rules.gap_close_m,
                                       fill_max_width_m=rules.fill_max_width_m,
                                       fill_free_max_width_m=rules.fill_free_max_width_m)
    return resolve_unknown(cleaned), report


@dataclass(frozen=True)
class MapObstacle:
    """One connected obstacle of a map, with what it is made of.

    Attributes
    ----------
    index : int
        Position in the list :func:`extract_obstacles` returns (0-based).
    polygon : shapely.geometry.Polygon
        Simplified outline (holes included), world frame [m].
    area_m2 : float
        Area of the obstacle's cells [m^2].
    thickness_m : float
        Mean thickness [m]: the short side of a rectangular obstacle (one that fills
        ``rack_min_fill`` of its rectangle), else cell area / centre-line length.
    centre_lines_m : numpy.ndarray
        Centre line, segments (k, 2, 2) [m]: a rectangular obstacle's mid-line along its
        long side, else its straightened skeleton.
    rectangle_m : numpy.ndarray
        Corners of the minimum rotated rectangle, shape (4, 2) [m], counter-clockwise.
    fill : float
        ``area_m2`` / rectangle area [1].
    outer : bool
        Whether it touches the outside of the building.
    kind : str
        One of :data:`KINDS`.
    material : str
        Library material name.
    construction : str or None
        Wall construction (:data:`scenes.radio.CONSTRUCTIONS`) for walls, else None.
    rule : str
        Which rule (or ``"override"``) decided ``kind`` and ``material``.
    """

    index: int
    polygon: Polygon
    area_m2: float
    thickness_m: float
    centre_lines_m: np.ndarray
    rectangle_m: np.ndarray
    fill: float
    outer: bool
    kind: str
    material: str
    construction: str | None
    rule: str

    @property
    def rectangle_sides_m(self) -> tuple[float, float]:
        """(long, short) side of the minimum rotated rectangle [m]."""
        e = np.linalg.norm(np.diff(np.vstack([self.rectangle_m, self.rectangle_m[:1]]), axis=0), axis=1)
        return float(max(e[0], e[1])), float(min(e[0], e[1]))


def _polygon(mask: np.ndarray, rosmap: RosMap, r0: int, c0: int, tol: float) -> Polygon:
    """Outline of one obstacle mask (cropped at row r0, col c0) as a simplified polygon.

    The union (shapely) of the mask's row runs, one rectangle each: the exact outline
    along the cell edges, holes included; then Douglas-Peucker within ``tol``.
    """
    res = rosmap.resolution_m
    boxes = []
    for r in np.flatnonzero(mask.any(axis=1)):
        d = np.diff(np.concatenate([[0], mask[r].astype(np.int8), [0]]))
        y0 = rosmap.origin_m[1] + (r + r0) * res
        for a, b in zip(np.flatnonzero(d == 1), np.flatnonzero(d == -1), strict=True):
            x0 = rosmap.origin_m[0] + (a + c0) * res
            boxes.append(shapely.box(x0, y0, x0 + (b - a) * res, y0 + res))
    poly = shapely.unary_union(boxes)
    if not isinstance(poly, Polygon):  # 8-connected cells touching at a corner only
        parts = [g for g in getattr(poly, "geoms", [poly]) if isinstance(g, Polygon)]
        poly = shapely.unary_union([g.buffer(res * 1e-3, join_style="mitre") for g in parts])
        if not isinstance(poly, Polygon):
            poly = max(poly.geoms, key=lambda g: g.area)
    return poly.simplify(tol, preserve_topology=True)


#: Default simplification tolerance of outlines and centre lines [m], at least half a cell:
#: a SLAM map draws a wall as the band its laser returns fell in, two or three cells of
#: 2-5 cm wide, so a straight wall's cells zigzag by about this much.
LASER_BAND_M = 0.05

#: Rectangles within this of the map's axes are snapped to them [rad] (about 2 degrees: the
#: tilt a one-cell step over 30 cells gives a rectangle fitted to chamfered corners).
_SNAP_RAD = 0.035


def _rectangle(poly: Polygon) -> np.ndarray:
    """Minimum rotated rectangle (4, 2), counter-clockwise, snapped to the axes when nearly so.

    A snapped rectangle is the polygon's bounds, so its sides lie on the map's cell edges.
    """
    rect = np.asarray(poly.minimum_rotated_rectangle.exterior.coords, dtype=float)[:4]
    e = rect[1] - rect[0]
    ang = float(np.arctan2(e[1], e[0])) % (np.pi / 2)
    ang = ang - np.pi / 2 if ang > np.pi / 4 else ang
    if abs(ang) <= _SNAP_RAD:
        x0, y0, x1, y1 = poly.bounds
        rect = np.array([[x0, y0], [x1, y0], [x1, y1], [x0, y1]])
    elif not shapely.LinearRing(rect).is_ccw:
        rect = rect[::-1]
    return rect


def _skeleton_paths(skel: np.ndarray) -> list[np.ndarray]:
    """Pixel paths (k_i, 2) [row, col] of a one-pixel-wide skeleton, split at its junctions.

    Each path runs between two key pixels (ends, degree 1, or junctions, degree > 2);
    closed loops without a key pixel start anywhere on them.
    """
    pix = set(zip(*np.nonzero(skel), strict=True))
    steps = [(-1, -1), (-1, 0), (-1, 1), (0, -1), (0, 1), (1, -1), (1, 0), (1, 1)]

    def nbrs(p):
        return [(p[0] + a, p[1] + b) for a, b in steps if (p[0] + a, p[1] + b) in pix]

    key = {p for p in pix if len(nbrs(p)) != 2}
    seen: set = set()
    paths = []

    def walk(start, nxt):
        path = [start, nxt]
        seen.add(frozenset((start, nxt)))
        prev, cur = start, nxt
        while cur not in key:
            cand = [q for q in nbrs(cur) if q != prev and frozenset((cur, q)) not in seen]
            if not cand:
                break
            prev, cur = cur, cand[0]
            seen.add(frozenset((prev, cur)))
            path.append(cur)
            if cur == start:
                break
        return np.array(path, dtype=float)

    for k in sorted(key):
        for q in nbrs(k):
            if frozenset((k, q)) not in seen:
                paths.append(walk(k, q))
    for p in sorted(pix):  # loops without a key pixel (a ring wall)
        for q in nbrs(p):
            if frozenset((p, q)) not in seen:
                key.add(p)
                paths.append(walk(p, q))
    if not paths and pix:  # a lone pixel
        p = next(iter(pix))
        paths.append(np.array([p, p], dtype=float))
    return paths


def _centre_lines(mask: np.ndarray, rosmap: RosMap, r0: int, c0: int, tol: float) -> np.ndarray:
    """Centre-line segments (k, 2, 2) [m] of one obstacle: its skeleton, spurs pruned.

    Spurs (branches to a free end no longer than the obstacle's half-width at their root)
    are removed and the skeleton traced again, so the branches they split are whole; free
    ends are then extended by the half-width there (a skeleton stops that short of the
    obstacle's end, and a ray passing the gap would cross no surface).
    """
    from skimage import measure, morphology

    padded = np.pad(mask, 1)
    skel = morphology.skeletonize(padded)
    half_width = ndimage.distance_transform_edt(padded)
    paths = _skeleton_paths(skel)
    if not paths:
        return np.zeros((0, 2, 2))

    def degree(img):
        return ndimage.convolve(img.astype(int), np.ones((3, 3), int), mode="constant") - 1

    deg = degree(skel)
    keep = []
    for p in paths:
        length = np.linalg.norm(np.diff(p, axis=0), axis=1).sum()
        ends_free = [deg[int(q[0]), int(q[1])] == 1 for q in (p[0], p[-1])]
        root = p[-1] if ends_free[0] else p[0]
        if len(paths) > 1 and sum(ends_free) == 1 and length <= half_width[int(root[0]), int(root[1])] + 1:
            continue
        keep.append(p)
    if len(keep) < len(paths):  # trace the pruned skeleton again: whole branches
        pruned = np.zeros_like(skel)
        for p in keep:
            pruned[p[:, 0].astype(int), p[:, 1].astype(int)] = True
        skel, paths = pruned, _skeleton_paths(pruned)
        deg = degree(skel)
    segs = []
    for p in paths:
        p = p.copy()
        for end, inner in ((0, min(3, len(p) - 1)), (len(p) - 1, max(len(p) - 4, 0))):
            q = p[end]
            if deg[int(q[0]), int(q[1])] == 1 and len(p) > 1:
                d = q - p[inner]
                if np.linalg.norm(d) > 0:
                    p[end] = q + d / np.linalg.norm(d) * (half_width[int(q[0]), int(q[1])] - 0.5)
        q = measure.approximate_polygon(p, tolerance=tol / rosmap.resolution_m)
        xy = rosmap.cell_centres(q[:, 0] - 1 + r0, q[:, 1] - 1 + c0)
        segs += [[a, b] for a, b in zip(xy[:-1], xy[1:], strict=True) if np.linalg.norm(b - a) > 1e-9]
    return np.asarray(segs, dtype=float).reshape(-1, 2, 2)


def _mid_line(rect: np.ndarray) -> np.ndarray:
    """The centre line (1, 2, 2) [m] of a rectangle (4, 2) along its long side."""
    e0, e1 = rect[1] - rect[0], rect[2] - rect[1]
    if np.linalg.norm(e0) >= np.linalg.norm(e1):
        return np.array([[(rect[0] + rect[3]) / 2, (rect[1] + rect[2]) / 2]])
    return np.array([[(rect[0] + rect[1]) / 2, (rect[3] + rect[2]) / 2]])


def _classify(area: float, thickness: float, long_side: float, short_side: float, fill: float,
              outer: bool, rules: ExtractionRules) -> tuple[str, str, str | None, str]:
    """(kind, material, construction, rule) of an obstacle by the module's rules."""
    if outer:
        return "wall", rules.outer_material, "solid", "outer"
    if long_side <= rules.pillar_max_m:
        return "pillar", rules.pillar_material, None, "pillar"
    if (fill >= rules.rack_min_fill and short_side >= rules.rack_min_depth_m
            and long_side >= rules.rack_min_length_m):
        return "rack", "metal", None, "rack"
    if thickness < rules.thin_wall_max_m:
        return "wall", rules.thin_material, "stud", "partition"
    return "wall", rules.thick_material, "solid", "thick wall"


#: Square sides [m] of the openings that look for a rack inside a larger obstacle, after
#: ``rack_min_depth_m``: a rack touching a wall or another unit is found at the first
#: side that cuts the thinner part off it (walls 0.1-0.5 m, racks 0.35-2.5 m deep).
_SPLIT_SIDES_M = (0.5, 0.8, 1.2, 1.8)


def _cell_rectangle(mask: np.ndarray, res: float) -> tuple[float, float, float]:
    """(fill, long side, short side) [1, m, m] of a cell mask's minimum rotated rectangle."""
    n_cells = int(mask.sum())
    edge = mask & ~ndimage.binary_erosion(mask)  # the hull is the edge cells' corners' hull
    r, c = np.nonzero(edge)
    corners = np.concatenate([np.stack([c + dx, r + dy], 1) for dx in (0, 1) for dy in (0, 1)])
    hull = shapely.multipoints(corners.astype(float)).convex_hull
    rect = np.asarray(hull.minimum_rotated_rectangle.exterior.coords)[:4]
    e = np.linalg.norm(np.diff(np.vstack([rect, rect[:1]]), axis=0), axis=1)
    long_c, short_c = float(max(e[0], e[1])), float(min(e[0], e[1]))
    return min(1.0, n_cells / max(long_c * short_c, 1.0)), long_c * res, short_c * res


def _split_rectangles(labels: np.ndarray, res: float, rules: ExtractionRules,
                      drawn: np.ndarray) -> np.ndarray:
    """Labels with rack-shaped rectangles cut out of the obstacles they touch.

    A rack standing against a wall, or two pallets touching, are one connected obstacle
    whose outline is no rectangle, so no rule would call it a rack. For every obstacle that
    is not itself a rectangle (fill below ``rack_min_fill``), openings with squares of
    ``rack_min_depth_m`` and then :data:`_SPLIT_SIDES_M` (odd cell counts) keep its parts at
    least that thick;
    a part that is a rack-sized rectangle (fill, depth, length as the rack rule asks, depth
    at most ``fill_max_width_m`` or 2.5 m) and an outline the map drew (at least half its
    cells were not occupied in the map as given, ``drawn`` (ny, nx) bool being the occupied
    cells: the inside the cleaning filled) becomes an obstacle of its own, the rest of the
    obstacle another. The last condition keeps a solid thick wall joined to thinner ones a
    wall: a SLAM map draws a rack as the outline its laser saw, a wall as a solid band.
    scipy.ndimage openings, shapely rectangles.
    """
    out = labels.copy()
    nxt = int(labels.max()) + 1
    max_depth = max(rules.fill_max_width_m, 2.5)
    for k, sl in enumerate(ndimage.find_objects(labels), start=1):
        if sl is None:
            continue
        sl = tuple(slice(max(s.start - 1, 0), s.stop + 1) for s in sl)
        mask = labels[sl] == k
        if mask.sum() * res * res < rules.rack_min_depth_m * rules.rack_min_length_m:
            continue
        fill, _, _ = _cell_rectangle(mask, res)
        if fill >= rules.rack_min_fill:
            continue
        rest = mask.copy()
        for side in (rules.rack_min_depth_m, *_SPLIT_SIDES_M):
            n = max(1, int(round(side / res))) | 1  # odd: min and max filters share a centre
            if n > min(rest.shape):
                break
            # an opening with an n x n square, as separable minimum and maximum filters (the
            # outer wall's box is the whole map: a 2-D structure of 60 x 60 cells took seconds)
            opened = ndimage.maximum_filter(ndimage.minimum_filter(rest, size=n, mode="constant", cval=0),
                                            size=n, mode="constant", cval=0)
            parts, n_parts = ndimage.label(opened, structure=np.ones((3, 3)))
            for j in range(1, n_parts + 1):
                piece = parts == j
                if piece.sum() == rest.sum():
                    continue  # the whole obstacle: not a split
                f, long_m, short_m = _cell_rectangle(piece, res)
                if (f >= rules.rack_min_fill and rules.rack_min_depth_m <= short_m <= max_depth
                        and long_m >= rules.rack_min_length_m
                        and not drawn[sl][piece].mean() > 0.5):
                    out[sl][piece] = nxt
                    nxt += 1
                    rest &= ~piece
            if not rest.any():
                break
        if rest.sum() < mask.sum():  # what is left of the obstacle, one label per piece
            pieces, n_pieces = ndimage.label(rest, structure=np.ones((3, 3)))
            view = out[sl]
            view[rest] = 0
            for j in range(1, n_pieces + 1):
                view[pieces == j] = nxt
                nxt += 1
    return out


def extract_obstacles(rosmap: RosMap, tolerance_m: float | None = None,
                      rules: ExtractionRules | None = None, cells: np.ndarray | None = None,
                      dropped: list | None = None) -> list[MapObstacle]:
    """The connected obstacles of a map, outlined, thinned and classified.

    Parameters
    ----------
    rosmap : RosMap
    tolerance_m : float, optional
        Simplification tolerance of outlines and centre lines [m]; default
        :data:`LASER_BAND_M` (0.05 m) or half a cell, whichever is larger.
    rules : ExtractionRules, optional
        Construction rules (default :class:`ExtractionRules`).
    cells : numpy.ndarray, optional
        The cell classes of :func:`map_cells` (computed when not given).
    dropped : list, optional
        Receives ``(x, y, area_m2)`` of every obstacle dropped as noise (under ``min_area_m2``).

    Returns
    -------
    list of MapObstacle
        In label order (scikit-image's raster order of their first cell).
    """
    from skimage import measure

    rules = ExtractionRules() if rules is None else rules
    res = rosmap.resolution_m
    tol = max(0.5 * res, LASER_BAND_M) if tolerance_m is None else float(tolerance_m)
    if not tol >= 0:
        raise ValueError(f"{rosmap.path}: tolerance_m must be >= 0, got {tolerance_m!r}")
    cls = map_cells(rosmap, rules)[0] if cells is None else cells
    obstacle = cls == OBSTACLE
    outside = np.pad(cls == OUTSIDE, 1, constant_values=True)
    near_outside = ndimage.binary_dilation(outside, structure=np.ones((3, 3)))[1:-1, 1:-1]
    # walls meet: a partition joined to the outer wall is one connected obstacle. An
    # opening with a square as wide as thin_wall_max_m keeps what is at least that thick
    # (rectangles exactly) and removes thinner lines, which become obstacles of their own.
    k = max(1, int(np.ceil(rules.thin_wall_max_m / res - 1e-9)))
    thick = ndimage.binary_opening(obstacle, structure=np.ones((k, k), bool))
    labels = _split_rectangles(measure.label(thick, connectivity=2), res, rules,
                               rosmap.cell_class == OBSTACLE)
    thin_labels = measure.label(obstacle & ~thick, connectivity=2)
    labels = np.where(thin_labels > 0, thin_labels + labels.max(), labels)
    out = []
    for k, sl in enumerate(ndimage.find_objects(labels), start=1):
        if sl is None:
            continue
        mask = labels[sl] == k
        if float(mask.sum()) * res * res < rules.min_area_m2:
            if dropped is not None:
                r, c = np.nonzero(mask)
                xy = rosmap.cell_centres(r.mean() + sl[0].start, c.mean() + sl[1].start)
                dropped.append((round(float(xy[0]), 3), round(float(xy[1]), 3),
                                round(float(mask.sum()) * res * res, 5)))
            continue
        r0, c0 = sl[0].start, sl[1].start
        poly = _polygon(mask, rosmap, r0, c0, tol)
        lines = _centre_lines(mask, rosmap, r0, c0, tol)
        area = float(mask.sum()) * res * res
        rect = _rectangle(poly)
        e = np.linalg.norm(np.diff(np.vstack([rect, rect[:1]]), axis=0), axis=1)
        long_side, short_side = float(max(e[0], e[1])), float(min(e[0], e[1]))
        rect_area = max(long_side * short_side, res * res)
        fill = min(1.0, area / rect_area)
        if fill >= rules.rack_min_fill:  # a rectangle (a straight wall): its mid-line, whole
            lines = _mid_line(rect)
            thickness = max(short_side, res)
        else:
            length = float(np.linalg.norm(lines[:, 1] - lines[:, 0], axis=1).sum()) if len(lines) else 0.0
            # a centre line shorter than the cells' extent (a blob): thickness = short side
            thickness = area / length if length > short_side else max(short_side, res)
        outer = bool(np.any(near_outside[sl][mask]))
        kind, mat, cons, rule = _classify(area, thickness, long_side, short_side, fill, outer, rules)
        out.append(MapObstacle(len(out), poly, area, float(thickness), lines, rect, fill, outer,
                               kind, mat, cons, rule))
    return out


def apply_override(obstacles: list[MapObstacle], where: str, *, point_m=None, polygon_m=None,
                   kind: str | None = None, material: str | None = None,
                   construction: str | None = None, snap_m: float = 0.0) -> list[MapObstacle]:
    """Obstacles with one override applied: by a point inside (or within ``snap_m`` of) an
    obstacle, or to every obstacle whose representative point lies in a polygon.

    A wall given a new material without a construction gets that material's default
    (plasterboard ``"stud"``, else ``"solid"``); a new kind ``"rack"`` is metal.

    Raises
    ------
    ValueError
        Naming ``where`` when the override matches no obstacle.
    """
    if point_m is not None:
        pt = Point(point_m)
        hit = [o.index for o in obstacles if o.polygon.distance(pt) <= snap_m + 1e-9]
        what = f"point_m {list(point_m)}"
    else:
        area = Polygon(polygon_m)
        if not area.is_valid or area.area <= 0:
            raise ValueError(f"{where}: polygon_m {polygon_m} is not a simple polygon with area")
        hit = [o.index for o in obstacles if area.contains(o.polygon.representative_point())]
        what = "polygon_m"
    if not hit:
        raise ValueError(f"{where}: {what} matches no obstacle of the map")
    out = list(obstacles)
    for i in hit:
        o = out[i]
        new_kind = kind or o.kind
        new_mat = material or ({"rack": "metal"}.get(new_kind, o.material) if kind else o.material)
        if new_kind != "wall":
            new_cons = None
        elif construction is not None:
            new_cons = construction
        elif material is None and o.kind == "wall":
            new_cons = o.construction
        else:  # a new material (or a new wall): that material's default construction
            new_cons = default_construction(new_mat)
        out[i] = replace(o, kind=new_kind, material=new_mat, construction=new_cons, rule="override")
    return out
