"""Antenna-frame geometry for the comparisons: (d, alpha) of points seen from an antenna pose.

Follows the project's frame contract: an antenna pose is (x, y, z, yaw, pitch,
roll) in the world frame (z up), the boresight is the local +x axis, positive
pitch tilts the boresight up; ``world_from_local = Rz(yaw) Ry(-pitch) Rx(roll)``.
d is the distance antenna -> point [m]; alpha = atan2(y_local, x_local) wrapped
to (-pi, pi] [rad].

This module holds the NumPy arithmetic only so that evaluation does not import
the ray tracer; ``tests/pipeline/evaluation`` checks it against
``propagation.patterns.antenna_frame_angles``. It differs in taking per-pose
point sets (n, k, 3), which the Fig. 7 neighbourhoods need.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

__all__ = ["FrameGeometry", "antenna_frame_geometry", "lattice_offsets"]


@dataclass(frozen=True)
class FrameGeometry:
    """Points expressed in antenna frames.

    Attributes
    ----------
    d_m : numpy.ndarray, float64
        Distance antenna -> point [m], shape of the broadcast (n, k).
    alpha_rad : numpy.ndarray, float64
        Bearing atan2(y_local, x_local) in (-pi, pi] [rad], same shape.
    elevation_rad : numpy.ndarray, float64
        Elevation above the local x-y plane, asin(z_local / d) [rad], same shape.
    """

    d_m: np.ndarray
    alpha_rad: np.ndarray
    elevation_rad: np.ndarray


def _poses6(antenna_poses) -> np.ndarray:
    p = np.asarray(antenna_poses, dtype=np.float64)
    if p.ndim == 1:
        p = p[None, :]
    if p.ndim != 2 or p.shape[1] not in (4, 6):
        raise ValueError(f"antenna_poses must have shape (n, 4) or (n, 6), got {p.shape}")
    if p.shape[1] == 4:
        p = np.column_stack([p, np.zeros((p.shape[0], 2))])
    if not np.all(np.isfinite(p)):
        raise ValueError("antenna_poses contains NaN or inf")
    return p


def antenna_frame_geometry(antenna_poses, points) -> FrameGeometry:
    """(d, alpha, elevation) of `points` in the frames of `antenna_poses`.

    Parameters
    ----------
    antenna_poses : array_like, shape (n, 4) or (n, 6)
        [x_m, y_m, z_m, yaw_rad(, pitch_rad, roll_rad)], world frame.
    points : array_like, shape (n, k, 3) or (k, 3)
        World points [m]; (k, 3) is seen from every pose.

    Returns
    -------
    FrameGeometry
        Arrays of shape (n, k).
    """
    p = _poses6(antenna_poses)
    pts = np.asarray(points, dtype=np.float64)
    if pts.ndim == 2:
        pts = np.broadcast_to(pts[None], (p.shape[0],) + pts.shape)
    if pts.ndim != 3 or pts.shape[0] != p.shape[0] or pts.shape[2] != 3:
        raise ValueError(
            f"points must have shape (k, 3) or ({p.shape[0]}, k, 3), got {np.shape(points)}"
        )
    rel = pts - p[:, None, :3]
    cy, sy = np.cos(p[:, 3]), np.sin(p[:, 3])
    cp, sp = np.cos(-p[:, 4]), np.sin(-p[:, 4])
    cr, sr = np.cos(p[:, 5]), np.sin(p[:, 5])
    # R = Rz(yaw) Ry(-pitch) Rx(roll); local = R^T rel
    n = p.shape[0]
    rz = np.zeros((n, 3, 3))
    rz[:, 0, 0], rz[:, 0, 1], rz[:, 1, 0], rz[:, 1, 1], rz[:, 2, 2] = cy, -sy, sy, cy, 1.0
    ry = np.zeros((n, 3, 3))
    ry[:, 0, 0], ry[:, 0, 2], ry[:, 2, 0], ry[:, 2, 2], ry[:, 1, 1] = cp, sp, -sp, cp, 1.0
    rx = np.zeros((n, 3, 3))
    rx[:, 1, 1], rx[:, 1, 2], rx[:, 2, 1], rx[:, 2, 2], rx[:, 0, 0] = cr, -sr, sr, cr, 1.0
    rot = rz @ ry @ rx
    local = np.einsum("nji,nkj->nki", rot, rel)
    d = np.linalg.norm(local, axis=2)
    alpha = np.arctan2(local[..., 1], local[..., 0])
    alpha = np.where(alpha <= -np.pi, alpha + 2.0 * np.pi, alpha)
    with np.errstate(invalid="ignore", divide="ignore"):
        elev = np.arcsin(np.clip(np.where(d > 0, local[..., 2] / d, 0.0), -1.0, 1.0))
    return FrameGeometry(d_m=d, alpha_rad=alpha, elevation_rad=elev)


def lattice_offsets(radius_m: float, shape: str = "disc", n_per_radius: int = 4) -> np.ndarray:
    """Regular lattice of offsets within `radius_m` of the origin.

    A cubic (or square, for ``"disc"``) lattice of step ``radius_m /
    n_per_radius`` clipped to the ball (disc) of radius `radius_m`; symmetric
    under x -> -x, y -> -y (and z -> -z), contains the origin. Deterministic, so
    the neighbourhood averages of Fig. 7 need no random generator.

    Parameters
    ----------
    radius_m : float
        Radius [m], >= 0 (0 gives the single offset (0, 0, 0)).
    shape : {"disc", "ball"}
        ``"disc"``: horizontal disc (z offset 0), the chapter's 2-D neighbourhood;
        ``"ball"``: 3-D ball.
    n_per_radius : int
        Lattice points per radius (>= 1).

    Returns
    -------
    numpy.ndarray, shape (k, 3), float64, metres
    """
    r = float(radius_m)
    if not (np.isfinite(r) and r >= 0):
        raise ValueError(f"radius_m must be finite and >= 0, got {radius_m!r}")
    if shape not in ("disc", "ball"):
        raise ValueError(f"shape must be 'disc' or 'ball', got {shape!r}")
    if int(n_per_radius) < 1:
        raise ValueError(f"n_per_radius must be >= 1, got {n_per_radius!r}")
    if r == 0.0:
        return np.zeros((1, 3))
    m = int(n_per_radius)
    ticks = np.arange(-m, m + 1) * (r / m)
    zs = ticks if shape == "ball" else np.zeros(1)
    g = np.stack(np.meshgrid(ticks, ticks, zs, indexing="ij"), axis=-1).reshape(-1, 3)
    keep = np.linalg.norm(g, axis=1) <= r * (1.0 + 1e-12)
    return g[keep]
