"""A real SLAM map's cells made ready for extraction: outline gaps closed, enclosed outlines filled.

A map a robot made draws a rack, a pallet or a shelving unit as its laser saw it: a closed
black outline (one or two cells wide) around an interior that is unknown (grey: never
seen) or free (the laser passed between the shelves), often with a gap of a cell or two
in the outline (a missed return, an upright's notch). Read as given, the interior is free
floor and the outline a thin partition: no rack. Two operations of scipy.ndimage (the
same library scikit-image builds its morphology on), in this order, make the outline
the solid it stands for:

1. *gaps closed*: a binary closing of the obstacle cells with a disc ``gap_close_m``
   across closes every gap up to that width (and merges obstacles closer than that);
2. *enclosed regions filled*: every region of non-obstacle cells that the obstacles
   enclose (:func:`scipy.ndimage.binary_fill_holes`, 4-connected) becomes obstacle when
   its largest inscribed disc (a Euclidean distance transform) is at most
   ``fill_max_width_m`` across and most of its cells are unknown (the unseen inside of
   a rack or pallet outline), or at most ``fill_free_max_width_m`` across whatever it
   holds (a free sliver the laser saw between shelves). A wider enclosed region is a
   room, or the building's floor, and stays.

Both are reported (:class:`CleaningReport`): the cells each changed and every filled
region, with its centre, area and width, so ``rfidstudy scenes show`` can say what was
decided. ``gap_close_m = 0`` turns the closing off; ``fill_max_width_m = 0`` and
``fill_free_max_width_m = 0`` together turn the filling off. Speckle (an
obstacle under ``min_area_m2``) is dropped later, by the extraction
(:mod:`scenes.mapextract`).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy import ndimage

from scenes.rosmap import OBSTACLE, UNKNOWN

__all__ = ["CleaningReport", "FilledRegion", "clean_cell_class"]


@dataclass(frozen=True)
class FilledRegion:
    """One enclosed region made obstacle.

    Attributes
    ----------
    centre_m : tuple of float
        Centroid (x, y) of its cells [m].
    area_m2 : float
        Its area [m^2].
    width_m : float
        Diameter of its largest inscribed disc [m].
    unknown_share : float
        Share of its cells that were unknown (the rest free) [1].
    """

    centre_m: tuple[float, float]
    area_m2: float
    width_m: float
    unknown_share: float


@dataclass(frozen=True)
class CleaningReport:
    """What :func:`clean_cell_class` changed.

    Attributes
    ----------
    gap_cells : int
        Cells made obstacle by the closing of gaps.
    filled : tuple of FilledRegion
        Enclosed regions made obstacle, largest first.
    kept_enclosed : int
        Enclosed regions left as they were: wider than ``fill_max_width_m``, or mostly
        free and wider than ``fill_free_max_width_m`` (rooms, free pockets).
    """

    gap_cells: int
    filled: tuple[FilledRegion, ...]
    kept_enclosed: int

    def describe(self) -> str:
        """One line: ``"closed 12 gap cells; filled 5 enclosed regions (41.3 m^2); kept 2 ..."``."""
        area = sum(f.area_m2 for f in self.filled)
        return (f"closed {self.gap_cells} gap cells; filled {len(self.filled)} enclosed regions "
                f"({area:.1f} m^2); kept {self.kept_enclosed} enclosed regions")


def _disc(radius_cells: float) -> np.ndarray:
    r = int(np.ceil(radius_cells))
    y, x = np.mgrid[-r:r + 1, -r:r + 1]
    return (x * x + y * y) <= radius_cells * radius_cells + 1e-9


def clean_cell_class(cell_class: np.ndarray, resolution_m: float, origin_m, *,
                     gap_close_m: float, fill_max_width_m: float,
                     fill_free_max_width_m: float) -> tuple[np.ndarray, CleaningReport]:
    """Cell classes with outline gaps closed and narrow enclosed regions filled.

    Parameters
    ----------
    cell_class : numpy.ndarray
        Shape (ny, nx), int8, :data:`scenes.rosmap.OBSTACLE` / ``FREE`` / ``UNKNOWN``
        (the map as given, row 0 at ``origin_m``'s y).
    resolution_m : float
        Cell size [m].
    origin_m : array_like
        World (x, y) of the lower-left corner of cell (0, 0) [m].
    gap_close_m : float
        Widest outline gap closed [m]; 0 closes none.
    fill_max_width_m : float
        Widest enclosed region, mostly unknown, filled (diameter of its largest inscribed
        disc) [m]; 0 fills none.
    fill_free_max_width_m : float
        Widest enclosed region filled whatever its cells [m]; 0 fills none.

    Returns
    -------
    cell_class : numpy.ndarray
        Shape (ny, nx), int8: the same classes, changed cells made ``OBSTACLE``.
    report : CleaningReport
    """
    cls = np.asarray(cell_class, dtype=np.int8).copy()
    obstacle = cls == OBSTACLE
    gap_cells = 0
    if gap_close_m > 0:
        # a disc d cells across bridges gaps of up to d cells; padding keeps the closing from
        # eroding obstacles at the image border
        d = gap_close_m / resolution_m
        pad = int(np.ceil(d)) + 1
        closed = ndimage.binary_closing(np.pad(obstacle, pad, mode="edge"),
                                        structure=_disc((d + 1) / 2))[pad:-pad, pad:-pad]
        gap_cells = int((closed & ~obstacle).sum())
        obstacle = closed
    filled: list[FilledRegion] = []
    kept = 0
    if fill_max_width_m > 0 or fill_free_max_width_m > 0:
        holes = ndimage.binary_fill_holes(obstacle) & ~obstacle
        labels, n = ndimage.label(holes)  # 4-connected: a diagonal step is no door
        if n:
            half = ndimage.distance_transform_edt(holes)
            width = 2.0 * np.asarray(ndimage.maximum(half, labels, np.arange(1, n + 1))) * resolution_m
            sizes = np.bincount(labels.ravel(), minlength=n + 1)[1:]
            unknown = np.bincount(labels.ravel(), weights=(cls == UNKNOWN).ravel().astype(float),
                                  minlength=n + 1)[1:]
            fill = (((width <= fill_max_width_m + 1e-9) & (unknown >= 0.5 * sizes))
                    | (width <= fill_free_max_width_m + 1e-9))
            kept = int((~fill).sum())
            take = np.concatenate([[False], fill])[labels]
            centres = ndimage.center_of_mass(holes, labels, np.arange(1, n + 1))
            ox, oy = float(origin_m[0]), float(origin_m[1])
            for k in np.flatnonzero(fill):
                r, c = centres[k]
                filled.append(FilledRegion(
                    (round(float(ox + (c + 0.5) * resolution_m), 4), round(float(oy + (r + 0.5) * resolution_m), 4)),
                    round(float(sizes[k]) * resolution_m ** 2, 4), round(float(width[k]), 4),
                    round(float(unknown[k] / sizes[k]), 4)))
            obstacle = obstacle | take
    filled.sort(key=lambda f: -f.area_m2)
    out = np.where(obstacle, np.int8(OBSTACLE), cls).astype(np.int8)
    return out, CleaningReport(gap_cells, tuple(filled), kept)

