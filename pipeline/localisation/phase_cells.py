"""The cells the phase estimator's candidates stand for (:mod:`.phase`): the grid step
and the midpoint-rule sub-points of a candidate's cell."""

from __future__ import annotations

import numpy as np

__all__ = ["cell_points"]


def _grid_step(cand: np.ndarray) -> float:
    """Median nearest-neighbour distance of the candidates [m] (0 for one candidate)."""
    from scipy.spatial import cKDTree

    if len(cand) < 2:
        return 0.0
    d, _ = cKDTree(cand).query(cand, k=2)
    return float(np.median(d[:, 1]))


def cell_points(cand, cell_m: float, normals=None) -> np.ndarray:
    """The sub-cell centres of each candidate's cell, offsets -cell/3, 0, +cell/3 per
    axis (the midpoint rule): with ``normals`` (C, 3) (horizontal: the candidates lie on
    vertical faces), the 9 of the square of side `cell_m` in the face's plane, axes
    ``u = z x n`` (horizontal along the face) and ``v = z``, (C, 9, 3); without, the 27 of
    the cube of side `cell_m` about the candidate, (C, 27, 3)."""
    o = np.array([-1.0, 0.0, 1.0]) * float(cell_m) / 3.0
    c = np.asarray(cand, dtype=np.float64).reshape(-1, 3)
    if normals is None:
        off = np.stack(np.meshgrid(o, o, o, indexing="ij"), axis=-1).reshape(-1, 3)
        return c[:, None, :] + off[None]
    n = np.asarray(normals, dtype=np.float64).reshape(-1, 3)
    u = np.cross([0.0, 0.0, 1.0], n)
    norm = np.linalg.norm(u, axis=1, keepdims=True)
    if not np.all(norm > 1e-9):
        raise ValueError("cell_points: normals must be horizontal (candidates on vertical faces)")
    u /= norm
    ou, ov = (g.ravel() for g in np.meshgrid(o, o, indexing="ij"))  # (9,)
    return (c[:, None, :] + ou[None, :, None] * u[:, None, :]
            + ov[None, :, None] * np.array([0.0, 0.0, 1.0]))
