"""Occupancy grid and likelihood field cut from the scene meshes.

The grid is the planar map a robot navigates and localises in: the meshes are sliced
by horizontal planes (:func:`scenes.floor_plan_segments`), the cut segments are rasterised, and every cell not
reachable from the walkable route (wall interiors, the outside of the building, the
inside of cabinets) is marked occupied. Euclidean distance transforms (scipy.ndimage)
give the clearance field used for collision checks and the likelihood field of the
laser model (Thrun, Burgard & Fox, *Probabilistic Robotics*, 2005, sec. 6.4).
"""

from __future__ import annotations

import logging
from dataclasses import dataclass, replace

import numpy as np
from scipy import ndimage

from scenes import floor_plan_segments
from scenes.rosmap import boundary_segments
from scenes.sources import traits_of

__all__ = ["OccupancyMap", "map_boundary_segments", "slice_heights"]

logger = logging.getLogger(__name__)


def slice_heights(z_range: tuple[float, float], n_slices: int = 5) -> list[float]:
    """Heights [m] of the cutting planes :meth:`OccupancyMap.from_scene` slices the meshes at.

    ``n_slices`` planes spread over ``z_range`` (one when the range is a point), each
    raised by 1 um so that no plane lies exactly on a horizontal face.
    """
    z0, z1 = (float(v) for v in z_range)
    heights = [z0] if z1 - z0 < 1e-9 else np.linspace(z0, z1, max(2, int(n_slices)))
    return [float(h) + 1e-6 for h in heights]


def _rasterise(segments: np.ndarray, origin: np.ndarray, res: float, shape) -> np.ndarray:
    """Boolean grid (ny, nx) with every cell touched by a segment set (sampled at res/4)."""
    grid = np.zeros(shape, dtype=bool)
    if len(segments) == 0:
        return grid
    a, b = segments[:, 0], segments[:, 1]
    n = np.maximum(2, np.ceil(np.linalg.norm(b - a, axis=1) / (res / 4)).astype(int) + 1)
    idx = np.repeat(np.arange(len(segments)), n)
    starts = np.cumsum(n) - n
    frac = (np.arange(n.sum()) - np.repeat(starts, n)) / np.repeat(n - 1, n)
    pts = a[idx] + frac[:, None] * (b[idx] - a[idx])
    col = np.floor((pts[:, 0] - origin[0]) / res).astype(int)
    row = np.floor((pts[:, 1] - origin[1]) / res).astype(int)
    ok = (row >= 0) & (row < shape[0]) & (col >= 0) & (col < shape[1])
    grid[row[ok], col[ok]] = True
    return grid


@dataclass(frozen=True)
class OccupancyMap:
    """A 2-D occupancy grid with its clearance and likelihood fields.

    Cell (row, col) covers x in [origin_x + col*res, origin_x + (col+1)*res) and
    y in [origin_y + row*res, ...). Points outside the grid count as occupied.

    Attributes
    ----------
    origin_m : numpy.ndarray
        World (x, y) of the grid's lower-left corner, shape (2,) [m].
    resolution_m : float
        Cell size [m].
    occupied : numpy.ndarray
        (ny, nx) bool, True where an obstacle (or unreachable space) is.
    distance_m : numpy.ndarray
        (ny, nx) float64: distance from each cell centre to the nearest occupied cell
        centre [m] (0 on occupied cells).
    boundary_distance_m : numpy.ndarray
        (ny, nx) float64: exact distance from each cell centre to the nearest cut
        segment that faces free space (an obstacle surface the laser can see; the
        outer faces of walls are left out so that a beam ending behind a wall is not
        rewarded) [m], capped at 2 m: the likelihood field of the laser model,
        interpolated bilinearly by :meth:`surface_distance_m`.
    z_range_m : tuple[float, float]
        Heights between which the meshes were sliced [m].
    """

    origin_m: np.ndarray
    resolution_m: float
    occupied: np.ndarray
    distance_m: np.ndarray
    boundary_distance_m: np.ndarray
    z_range_m: tuple[float, float]

    @classmethod
    def from_scene(
        cls,
        scene,
        resolution_m: float = 0.05,
        z_range: tuple[float, float] = (0.05, 1.0),
        n_slices: int = 5,
        route_m: np.ndarray | None = None,
        margin_m: float = 0.5,
        extra_segments: np.ndarray | None = None,
    ) -> OccupancyMap:
        """Build the map from the scene meshes.

        Parameters
        ----------
        scene : scenes.Scene
        resolution_m : float
            Cell size [m].
        z_range : tuple[float, float]
            Heights [m] between which obstacles matter (low: above the floor; high: the
            robot's height for collision maps; a single height ``(h, h)`` for a laser map).
        n_slices : int
            Number of cutting planes spread over ``z_range`` (1 when the range is a point).
        route_m : numpy.ndarray, optional
            Polyline (k, 2) in walkable space; default ``scene.route_m``. Free space is the
            set of cells 4-connected to it; everything else is occupied. Without a route
            the largest free component not touching the grid border is used.
        margin_m : float
            Extra border around the scene bounds [m].
        extra_segments : numpy.ndarray, optional
            Further obstacle outlines (k, 2, 2) [m] (a map scene's building edge).

        Raises
        ------
        ValueError
            On a non-positive resolution, an empty or inverted ``z_range``, or when no
            route point lies in free space.
        """
        if not resolution_m > 0:
            raise ValueError(f"OccupancyMap: resolution_m={resolution_m} must be > 0")
        z0, z1 = (float(v) for v in z_range)
        if not z1 >= z0:
            raise ValueError(
                f"OccupancyMap: z_range={z_range} must be (low, high) with low <= high"
            )
        heights = slice_heights((z0, z1), n_slices)
        origin, shape = cls.scene_grid(scene, resolution_m, margin_m)
        cut = np.concatenate([floor_plan_segments(scene, h) for h in heights]
                             + ([] if extra_segments is None else
                                [np.asarray(extra_segments, dtype=float).reshape(-1, 2, 2)]))
        route = scene.route_m if route_m is None else route_m
        return cls.from_segments(cut, origin, shape, resolution_m, route_m=route,
                                 z_range=(z0, z1), name=scene.name)

    @staticmethod
    def scene_grid(
        scene, resolution_m: float = 0.05, margin_m: float = 0.5
    ) -> tuple[np.ndarray, tuple[int, int]]:
        """Origin (2,) [m] and shape (ny, nx) of the grid :meth:`from_scene` lays over a scene.

        The scene's horizontal bounds grown by ``margin_m`` on every side, in cells of
        ``resolution_m``.
        """
        if not resolution_m > 0:
            raise ValueError(f"OccupancyMap: resolution_m={resolution_m} must be > 0")
        bounds = scene.bounds_m
        origin = np.asarray(bounds[0, :2], dtype=float) - margin_m
        extent = np.asarray(bounds[1, :2], dtype=float) + margin_m - origin
        shape = (int(np.ceil(extent[1] / resolution_m)), int(np.ceil(extent[0] / resolution_m)))
        return origin, shape

    @classmethod
    def from_segments(
        cls,
        segments: np.ndarray,
        origin_m: np.ndarray,
        shape: tuple[int, int],
        resolution_m: float = 0.05,
        route_m: np.ndarray | None = None,
        z_range: tuple[float, float] = (0.0, 0.0),
        name: str = "map",
    ) -> OccupancyMap:
        """Build the map from 2-D obstacle outlines (what :meth:`from_scene` cuts).

        Used directly for a map that is not the scene: the robot's map with its walls
        displaced (:func:`pipeline.robot.robotmap.draw_robot_map`).

        Parameters
        ----------
        segments : numpy.ndarray
            Obstacle outline segments (k, 2, 2) [m] (every slice's cut, concatenated).
        origin_m : numpy.ndarray
            World (x, y) of the grid's lower-left corner (2,) [m].
        shape : tuple[int, int]
            Grid shape (ny, nx).
        resolution_m : float
            Cell size [m].
        route_m : numpy.ndarray, optional
            Polyline (k, 2) [m] in walkable space; free space is the set of cells
            4-connected to it. Without one, the largest free component not touching the
            grid border.
        z_range : tuple[float, float]
            Heights the outlines were cut between [m] (recorded only).
        name : str
            Used in error messages.

        Raises
        ------
        ValueError
            When no route point lies in free space, or there is no enclosed free space.
        """
        if not resolution_m > 0:
            raise ValueError(f"OccupancyMap: resolution_m={resolution_m} must be > 0")
        seg = np.asarray(segments, dtype=float).reshape(-1, 2, 2)
        origin = np.asarray(origin_m, dtype=float)
        shape = (int(shape[0]), int(shape[1]))
        walls = _rasterise(seg, origin, resolution_m, shape)
        labels, n_labels = ndimage.label(~walls)  # 4-connectivity: diagonal gaps do not leak
        route = route_m
        if route is not None and len(route):
            pts = _densify(np.asarray(route, dtype=float), resolution_m / 2)
            col = np.floor((pts[:, 0] - origin[0]) / resolution_m).astype(int)
            row = np.floor((pts[:, 1] - origin[1]) / resolution_m).astype(int)
            ok = (row >= 0) & (row < shape[0]) & (col >= 0) & (col < shape[1])
            seeds = np.unique(labels[row[ok], col[ok]])
            seeds = seeds[seeds > 0]
            if len(seeds) == 0:
                raise ValueError(
                    f"OccupancyMap: no point of the route of {name!r} lies in "
                    f"free space at z in {tuple(z_range)}"
                )
        else:
            border = np.unique(np.concatenate([labels[0], labels[-1], labels[:, 0], labels[:, -1]]))
            sizes = ndimage.sum_labels(np.ones(shape), labels, np.arange(1, n_labels + 1))
            sizes[np.isin(np.arange(1, n_labels + 1), border)] = 0
            if not np.any(sizes > 0):
                raise ValueError(f"OccupancyMap: {name!r} has no enclosed free space")
            seeds = np.array([int(np.argmax(sizes)) + 1])
        free = np.isin(labels, seeds)
        logger.debug("OccupancyMap %s: %s cells, %.1f%% free", name, shape, 100 * free.mean())
        return cls.from_grid(free, origin, resolution_m, seg, z_range)

    @classmethod
    def from_grid(
        cls,
        free: np.ndarray,
        origin_m: np.ndarray,
        resolution_m: float,
        segments: np.ndarray,
        z_range: tuple[float, float] = (0.0, 0.0),
    ) -> OccupancyMap:
        """Build the map from a grid of free cells and the obstacle outlines it was drawn with.

        Used directly for a map given as a grid (a ROS map, :mod:`scenes.rosmap`).

        Parameters
        ----------
        free : numpy.ndarray
            (ny, nx) bool, True where the robot may be.
        origin_m : numpy.ndarray
            World (x, y) of the grid's lower-left corner (2,) [m].
        resolution_m : float
            Cell size [m].
        segments : numpy.ndarray
            Obstacle outline segments (k, 2, 2) [m]; those facing free space make the
            likelihood field.
        z_range : tuple[float, float]
            Heights the outlines stand for [m] (recorded only).
        """
        free = np.asarray(free, dtype=bool)
        origin = np.asarray(origin_m, dtype=float)
        seg = np.asarray(segments, dtype=float).reshape(-1, 2, 2)
        distance = ndimage.distance_transform_edt(free) * resolution_m
        faces = _free_facing(seg, free, origin, resolution_m)
        boundary = _segment_distance_field(faces, origin, resolution_m, free.shape)
        z0, z1 = (float(v) for v in z_range)
        return cls(origin, float(resolution_m), ~free, distance, boundary, (z0, z1))

    @property
    def shape(self) -> tuple[int, int]:
        """Grid shape (ny, nx)."""
        return self.occupied.shape

    def cell_index(self, points: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Row and column of the cell holding each point, and whether it is inside the grid.

        ``points`` is (..., 2) [m]; returns three arrays of shape (...): row, col (int,
        clipped into the grid) and inside (bool).
        """
        p = np.asarray(points, dtype=float)
        col = np.floor((p[..., 0] - self.origin_m[0]) / self.resolution_m).astype(np.int64)
        row = np.floor((p[..., 1] - self.origin_m[1]) / self.resolution_m).astype(np.int64)
        ny, nx = self.shape
        inside = (row >= 0) & (row < ny) & (col >= 0) & (col < nx)
        return np.clip(row, 0, ny - 1), np.clip(col, 0, nx - 1), inside

    def is_occupied(self, points: np.ndarray) -> np.ndarray:
        """True where a point (..., 2) [m] lies in an occupied cell or outside the grid."""
        row, col, inside = self.cell_index(points)
        return self.occupied[row, col] | ~inside

    def clearance_m(self, points: np.ndarray) -> np.ndarray:
        """Approximate distance from each point (..., 2) to the nearest obstacle [m].

        Nearest-cell lookup of ``distance_m`` minus half a cell (the obstacle cell's edge);
        accurate to about one cell. Negative inside obstacles and outside the grid.
        """
        row, col, inside = self.cell_index(points)
        d = self.distance_m[row, col] - self.resolution_m / 2
        return np.where(inside, d, -self.resolution_m / 2)

    def surface_distance_m(self, points: np.ndarray, max_distance_m: float = 2.0) -> np.ndarray:
        """Likelihood-field lookup: distance to the nearest obstacle surface [m], capped.

        Bilinear interpolation of ``boundary_distance_m`` between cell centres (the
        field is 1-Lipschitz, so the error is well below a cell). Points outside the
        grid get ``max_distance_m``.
        """
        p = np.asarray(points, dtype=float)
        fx = (p[..., 0] - self.origin_m[0]) / self.resolution_m - 0.5
        fy = (p[..., 1] - self.origin_m[1]) / self.resolution_m - 0.5
        ny, nx = self.shape
        inside = (fx >= -0.5) & (fx <= nx - 0.5) & (fy >= -0.5) & (fy <= ny - 0.5)
        fx, fy = np.clip(fx, 0, nx - 1), np.clip(fy, 0, ny - 1)
        x0 = np.minimum(fx.astype(np.int64), nx - 2) if nx > 1 else np.zeros_like(fx, int)
        y0 = np.minimum(fy.astype(np.int64), ny - 2) if ny > 1 else np.zeros_like(fy, int)
        x1, y1 = np.minimum(x0 + 1, nx - 1), np.minimum(y0 + 1, ny - 1)
        tx, ty = fx - x0, fy - y0
        f = self.boundary_distance_m
        d = (
            f[y0, x0] * (1 - tx) * (1 - ty)
            + f[y0, x1] * tx * (1 - ty)
            + f[y1, x0] * (1 - tx) * ty
            + f[y1, x1] * tx * ty
        )
        return np.where(inside, np.minimum(d, max_distance_m), max_distance_m)

    def with_surface_error(
        self, rng: np.random.Generator, sigma_m: float, correlation_m: float = 1.0
    ) -> OccupancyMap:
        """A copy whose likelihood field has its surfaces displaced by a smooth random field.

        The unsigned, smooth part of the difference between the robot's map and the
        world (surface roughness, clutter; the ``map_noise_m`` of
        :func:`pipeline.robot.robotmap.draw_robot_map`, whose systematic part, whole walls
        off, is :func:`pipeline.robot.robotmap.displace_wall_lines`): a Gaussian random field delta (std ``sigma_m``, Gaussian correlation
        length ``correlation_m``) shifts every surface, ``field' = |field - delta|``
        (the field is a distance, so subtracting delta moves its zero set by delta).

        Parameters
        ----------
        rng : numpy.random.Generator
        sigma_m : float
            Standard deviation of the surface displacement [m]; 0 returns ``self``.
        correlation_m : float
            Correlation length of the displacement along the surfaces [m].
        """
        if sigma_m < 0 or correlation_m <= 0:
            raise ValueError(
                f"with_surface_error: sigma_m={sigma_m} must be >= 0 and "
                f"correlation_m={correlation_m} > 0"
            )
        if sigma_m == 0:
            return self
        noise = ndimage.gaussian_filter(
            rng.standard_normal(self.shape), correlation_m / self.resolution_m, mode="wrap"
        )
        noise *= sigma_m / max(float(noise.std()), 1e-300)
        return replace(self, boundary_distance_m=np.abs(self.boundary_distance_m - noise))

    def free_cell_centres(self) -> np.ndarray:
        """World coordinates (n_free, 2) [m] of the centres of all free cells."""
        row, col = np.nonzero(~self.occupied)
        return self.origin_m + (np.stack([col, row], 1) + 0.5) * self.resolution_m


def _free_facing(segments: np.ndarray, free: np.ndarray, origin, res: float) -> np.ndarray:
    """Segments with free space on at least one side (probed 1.5 cells off, 9 places)."""
    if len(segments) == 0:
        return segments
    a, b = segments[:, 0], segments[:, 1]
    e = b - a
    nrm = np.stack([-e[:, 1], e[:, 0]], 1) / np.linalg.norm(e, axis=1, keepdims=True)
    f = np.linspace(0.1, 0.9, 9)
    pts = a[:, None] + f[None, :, None] * e[:, None]  # (m, 9, 2)
    probe = np.concatenate([pts + 1.5 * res * nrm[:, None], pts - 1.5 * res * nrm[:, None]], 1)
    col = np.floor((probe[..., 0] - origin[0]) / res).astype(int)
    row = np.floor((probe[..., 1] - origin[1]) / res).astype(int)
    ok = (row >= 0) & (row < free.shape[0]) & (col >= 0) & (col < free.shape[1])
    hit = np.zeros(probe.shape[:2], dtype=bool)
    hit[ok] = free[row[ok], col[ok]]
    return segments[hit.any(axis=1)]


def _segment_distance_field(
    segments: np.ndarray, origin: np.ndarray, res: float, shape, cap_m: float = 2.0,
    tile: int = 16,
) -> np.ndarray:
    """Exact distance (ny, nx) from every cell centre to the nearest segment, capped [m].

    Brute force over (cell, segment) pairs, tile by tile: a tile sees only the segments
    whose bounding box comes within the cap of its cells, the others being farther than the
    cap from every cell of it. The value of each pair does not depend on which others share
    its batch, so the tiling changes no value, only the work: a building-sized map's field
    costs its walls' neighbourhoods, not cells x all segments. Written here rather than
    with a KD-tree of segment samples because this is exact.

    Parameters
    ----------
    segments : numpy.ndarray
        (k, 2, 2) segment end points [m].
    origin : numpy.ndarray
        World (x, y) of the grid's lower-left corner (2,) [m].
    res : float
        Cell size [m].
    shape : tuple of int
        (ny, nx).
    cap_m : float
        Largest distance returned [m].
    tile : int
        Tile side in cells (>= 1).
    """
    if int(tile) < 1:
        raise ValueError(f"_segment_distance_field: tile must be >= 1, got {tile!r}")
    ny, nx = shape
    out = np.full(shape, cap_m)
    if len(segments) == 0:
        return out
    xs = origin[0] + (np.arange(nx) + 0.5) * res
    ys = origin[1] + (np.arange(ny) + 0.5) * res
    # x and y kept apart: a sum over a last axis of length 2 is a slow reduction, and
    # ``px * ex + py * ey`` is the same two products added in the same order (same bits)
    ax, ay = segments[:, 0, 0], segments[:, 0, 1]
    ex, ey = segments[:, 1, 0] - ax, segments[:, 1, 1] - ay
    ee = np.maximum(ex * ex + ey * ey, 1e-300)
    seg_lo, seg_hi = segments.min(1), segments.max(1)
    for r0 in range(0, ny, tile):
        for c0 in range(0, nx, tile):
            tx, ty = xs[c0 : c0 + tile], ys[r0 : r0 + tile]
            lo = np.array([tx[0], ty[0]]) - cap_m
            hi = np.array([tx[-1], ty[-1]]) + cap_m
            near = np.flatnonzero(np.all((seg_hi >= lo) & (seg_lo <= hi), axis=1))
            if not len(near):
                continue
            gx, gy = np.meshgrid(tx, ty)
            cx, cy = gx.ravel(), gy.ravel()
            axn, ayn, exn, eyn, een = ax[near], ay[near], ex[near], ey[near], ee[near]
            d2 = np.full(len(cx), cap_m**2)
            step = max(1, 4_000_000 // len(near))
            for i in range(0, len(cx), step):
                px = cx[i : i + step, None] - axn[None]
                py = cy[i : i + step, None] - ayn[None]
                t = np.clip((px * exn[None] + py * eyn[None]) / een[None], 0.0, 1.0)
                dx = px - t * exn[None]
                dy = py - t * eyn[None]
                d2[i : i + step] = np.minimum(d2[i : i + step], np.min(dx * dx + dy * dy, 1))
            out[r0 : r0 + tile, c0 : c0 + tile] = np.sqrt(d2).reshape(len(ty), len(tx))
    return out


def _densify(polyline: np.ndarray, step_m: float) -> np.ndarray:
    """Points along a polyline (k, 2) spaced at most ``step_m`` apart (vertices kept)."""
    if len(polyline) < 2:
        return polyline
    out = [polyline[:1]]
    for a, b in zip(polyline[:-1], polyline[1:], strict=True):
        n = max(1, int(np.ceil(np.linalg.norm(b - a) / step_m)))
        t = np.arange(1, n + 1)[:, None] / n
        out.append(a + t * (b - a))
    return np.concatenate(out)


def map_boundary_segments(scene) -> np.ndarray:
    """Edges (k, 2, 2) [m] of a map scene's building: where its cells meet the outside.

    A real map's outer wall has gaps (a window, a missed return, an unmapped doorway):
    the robot may not drive through them into the unmapped outside, so its collision map
    closes them. Empty for a scene not made from an occupancy grid (its source's
    :attr:`scenes.sources.SceneTraits.grid`).
    """
    rm = traits_of(scene).grid(scene)
    boxes = getattr(scene, "free_space_m", None)
    if rm is None or boxes is None or not len(boxes):
        return np.zeros((0, 2, 2))

    inside = np.zeros(rm.shape, dtype=bool)
    res = rm.resolution_m
    for lo, hi in np.asarray(boxes)[:, :, :2]:
        c0, r0 = np.round((lo - rm.origin_m) / res).astype(int)
        c1, r1 = np.round((hi - rm.origin_m) / res).astype(int)
        inside[max(r0, 0):r1, max(c0, 0):c1] = True
    return boundary_segments(inside, rm.origin_m, res)
