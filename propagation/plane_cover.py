"""Which parts of each large plane its triangles cover: a raster the completion's pre-test
looks reflection points up in.

:func:`propagation.chain_pretest._pretest` drops a (link, chain) pair whose reflection
point lies outside its plane's bounding box. A plane's box is a poor stand-in for its
triangles when the plane is made of pieces far apart: the faces of shelving-rack uprights
facing one way, coplanar across a 30 m x 50 m warehouse, cover 5 % of their box (2.8 m^2
of 53 m^2), the shelf boards at one height 27 %. Every pair whose reflection point fell
in such a box went to Sionna's image method, which then found no triangle there: on that
warehouse (64 positions x 656 tags, planes >= 0.1 m^2, order 2) 135 M candidates, half
of the tracing time.

:func:`plane_cover` rasters each plane, projected along its normal's largest axis, on a
grid of cells of at least :data:`MIN_CELL_M`; a cell is *covered* where the bounding
rectangle of one of the plane's triangles, widened by the box test's slack and one cell,
touches it. :func:`covered` tells, per reflection point, whether its cell is covered.
The raster over-covers (a triangle's bounding rectangle, whole cells, a cell more on
each side), never under-covers: a point on a triangle of the plane lies in a covered
cell. The triangles are the plane's own and every parallel one within Sionna's image
test (``completion.SAME_IMAGE_OFFSET_M``, 5 mm), whose hit Sionna takes for the plane's;
a ray meets such a triangle up to ``offset / tan(grazing angle)`` from the point on the
plane, within the extra cell (>= 5 cm) down to grazing angles of ~6 degrees.

Written here rather than with shapely or scikit-image: the test runs on hundreds of
millions of points per chunk (blocks of 2^18), as one NumPy gather per block; a polygon library's point-in-polygon
does not vectorise over a dense (link, chain) grid and rasterising triangles exactly is
not needed for a necessary condition.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

__all__ = ["MAX_CELLS", "MAX_CELLS_PER_PLANE", "MIN_CELL_M", "PlaneCover", "covered", "plane_cover"]

#: Smallest raster cell, m: rack uprights' faces are ~0.1 m wide; 5 cm cells keep their
#: over-cover to a cell or two on each side.
MIN_CELL_M = 0.05
#: Cells of one plane's raster, about (1 MiB of bool; the rounding up of its two sides
#: may add a row and a column): a 30 m x 50 m floor at 5 cm is 0.6 M cells; a larger
#: plane gets coarser cells.
MAX_CELLS_PER_PLANE = 1 << 20
#: Most cells of all rasters (256 MiB; warehouse_large at planes >= 0.1 m^2 has 6 M): a
#: plane past it gets one covered cell, i.e. its box alone, as with no raster.
MAX_CELLS = 1 << 28


@dataclass(frozen=True)
class PlaneCover:
    """Rasters of the cells each plane's triangles cover (:func:`plane_cover`).

    Attributes
    ----------
    cells : numpy.ndarray
        Every plane's raster, flattened and joined (N,), bool: ``True`` where covered.
    offset : numpy.ndarray
        Start of each plane's raster in ``cells`` (p,), int64.
    lo_m : numpy.ndarray
        Corner of each raster (p, 3), float64, metres (world coordinates).
    inv_cell_per_m : numpy.ndarray
        Inverse cell size of each raster (p,), float64, 1/m.
    dims : numpy.ndarray
        Cells along x, y, z (p, 3), int64: 1 along the axis the plane is projected on.
    strides : numpy.ndarray
        Flat-index step per cell along x, y, z (p, 3), int64 (0 along the projection axis).
    """

    cells: np.ndarray
    offset: np.ndarray
    lo_m: np.ndarray
    inv_cell_per_m: np.ndarray
    dims: np.ndarray
    strides: np.ndarray

    def __len__(self) -> int:
        return len(self.offset)

    def covered_fraction(self) -> np.ndarray:
        """Covered share of each plane's raster (p,): 1 for a plane its triangles fill."""
        ends = np.append(self.offset[1:], len(self.cells))
        return np.array([self.cells[a:b].mean() for a, b in zip(self.offset, ends, strict=True)])


def plane_cover(triangles: list[np.ndarray], normals, lo_m, hi_m, slack_m: float) -> PlaneCover:
    """Raster the triangles of each plane.

    Parameters
    ----------
    triangles : list of numpy.ndarray
        Per plane, its triangles (k, 3, 3), metres: every triangle the completion may
        take for the plane (``completion.plane_lookup``'s criterion), k >= 1.
    normals : array_like
        Unit normals (p, 3).
    lo_m, hi_m : array_like
        The planes' bounding boxes (p, 3), metres; the raster spans them plus ``slack_m``
        and a cell.
    slack_m : float
        Widening of each triangle's bounding rectangle, m (the box test's slack), besides
        one cell.

    Returns
    -------
    PlaneCover
    """
    normals, lo_m, hi_m = (np.asarray(a, float).reshape(-1, 3) for a in (normals, lo_m, hi_m))
    p = len(normals)
    if len(triangles) != p:
        raise ValueError(f"need one triangle array per plane: {len(triangles)} for {p} planes")
    cells, offset = [], np.zeros(p, np.int64)
    lo_out, inv, dims, strides = np.zeros((p, 3)), np.zeros(p), np.ones((p, 3), np.int64), np.zeros((p, 3), np.int64)
    start = 0
    for k in range(p):
        axis = int(np.argmax(np.abs(normals[k])))
        ab = [a for a in range(3) if a != axis]
        lo = lo_m[k] - slack_m
        ext = np.maximum(hi_m[k] - lo_m[k] + 2.0 * slack_m, 0.0)
        cell = max(MIN_CELL_M, float(np.sqrt((ext[ab[0]] + MIN_CELL_M) * (ext[ab[1]] + MIN_CELL_M)
                                             / MAX_CELLS_PER_PLANE)))
        n = [int(np.floor(ext[a] / cell)) + 1 for a in ab]  # the box's far side included
        offset[k], lo_out[k] = start, lo
        if start + n[0] * n[1] > MAX_CELLS:  # one covered cell: the box test alone
            cells.append(np.ones(1, bool))
            start += 1
            continue
        tri = np.asarray(triangles[k], float).reshape(-1, 3, 3)
        # per triangle the rows / columns of cells its widened bounding rectangle touches
        wide = slack_m + cell
        i0 = [np.clip(np.floor((tri[:, :, a].min(1) - wide - lo[a]) / cell), 0, m - 1).astype(np.int64)
              for a, m in zip(ab, n, strict=True)]
        i1 = [np.clip(np.floor((tri[:, :, a].max(1) + wide - lo[a]) / cell), 0, m - 1).astype(np.int64)
              for a, m in zip(ab, n, strict=True)]
        # rectangles summed in a difference array, then integrated along both axes
        diff = np.zeros((n[0] + 1, n[1] + 1), np.int64)
        np.add.at(diff, (i0[0], i0[1]), 1)
        np.add.at(diff, (i1[0] + 1, i0[1]), -1)
        np.add.at(diff, (i0[0], i1[1] + 1), -1)
        np.add.at(diff, (i1[0] + 1, i1[1] + 1), 1)
        grid = diff.cumsum(0).cumsum(1)[:n[0], :n[1]] > 0
        cells.append(grid.reshape(-1))
        inv[k] = 1.0 / cell
        dims[k, ab] = n
        strides[k, ab] = (n[1], 1)
        start += grid.size
    return PlaneCover(np.concatenate(cells) if cells else np.zeros(0, bool), offset, lo_out, inv, dims, strides)


def covered(cover: PlaneCover, plane: np.ndarray, point, origin_m) -> np.ndarray:
    """Whether each point lies in a covered cell of its plane's raster.

    Parameters
    ----------
    cover : PlaneCover
        The planes' rasters.
    plane : numpy.ndarray
        Plane of each point along the last axis (c,), int64: per column of (r, c)
        points, or per point of (c,) points.
    point : sequence of numpy.ndarray
        The points' x, y, z relative to ``origin_m``, each (..., c) (float32 in the
        pre-test).
    origin_m : array_like
        (3,), metres: what ``point`` is relative to.

    Returns
    -------
    numpy.ndarray
        (..., c) bool. A point outside its raster is looked up in the nearest edge cell:
        callers test the box first.
    """
    dtype = np.asarray(point[0]).dtype
    lo = (cover.lo_m[plane] - np.asarray(origin_m, float)).astype(dtype)
    inv = cover.inv_cell_per_m[plane].astype(dtype)
    # int32 indices (MAX_CELLS keeps the rasters under 2^31 cells): half the traffic
    flat = np.broadcast_to(cover.offset[plane].astype(np.int32), np.shape(point[0])).copy()
    for ax in range(3):
        stride = cover.strides[plane, ax].astype(np.int32)
        if not stride.any():
            continue  # every plane of these columns projected along this axis
        idx = ((point[ax] - lo[:, ax]) * inv).astype(np.int32)
        np.clip(idx, 0, (cover.dims[plane, ax] - 1).astype(np.int32), out=idx)
        idx *= stride
        flat += idx
    return cover.cells[flat]
