"""The large planes of a loaded Sionna scene, as the image-method completion uses them.

:func:`propagation.completion.large_planes` finds them; the completion
(:mod:`propagation.completion`) and its NumPy pre-test (:mod:`propagation.chain_pretest`)
both read them, so the type sits below both.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from propagation.plane_cover import PlaneCover

__all__ = ["Planes"]


@dataclass(frozen=True)
class Planes:
    """Large planes of a loaded Sionna scene (:func:`propagation.completion.large_planes`).

    Attributes
    ----------
    normal : numpy.ndarray
        Unit normals (p, 3), float64 (sign of the representative triangle).
    offset_m : numpy.ndarray
        Plane offsets ``normal . x`` (p,), float64, metres.
    area_m2 : numpy.ndarray
        Total triangle area of each plane (p,), m^2.
    lo_m, hi_m : numpy.ndarray
        Bounding box of each plane's triangles (p, 3), metres.
    shape : numpy.ndarray
        Representative shape, index into ``rt_scene.mi_scene.shapes()`` (p,), int64.
    primitive : numpy.ndarray
        Representative triangle (the plane's largest) of that shape (p,), int64.
    point_m : numpy.ndarray
        First vertex of the representative triangle (p, 3), float64, metres.
    shape_ids : tuple of tuple of str
        Per plane, the ids of the shapes whose triangles it holds.
    cover : PlaneCover or None
        Which cells of each plane its triangles cover (:mod:`propagation.plane_cover`),
        for the pre-test; ``None``: the bounding boxes alone.
    """

    normal: np.ndarray
    offset_m: np.ndarray
    area_m2: np.ndarray
    lo_m: np.ndarray
    hi_m: np.ndarray
    shape: np.ndarray
    primitive: np.ndarray
    point_m: np.ndarray
    shape_ids: tuple
    cover: PlaneCover | None = None

    def __len__(self) -> int:
        return len(self.offset_m)
