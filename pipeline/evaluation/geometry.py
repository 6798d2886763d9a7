"""Antenna-frame geometry for the comparisons: (d, alpha) of points seen from antenna poses.

The frame convention and the arithmetic are :func:`propagation.antenna_frame_angles`
(pose (x, y, z, yaw, pitch, roll), boresight local +x, ``Rz(yaw) Ry(-pitch) Rx(roll)``,
alpha = atan2(y_local, x_local) in (-pi, pi]). This module only adds per-pose point
sets (n, k, 3), which the Fig. 7 neighbourhoods need, and the neighbourhood lattice.
"""

from __future__ import annotations

import numpy as np

from propagation import AntennaFrameAngles, antenna_frame_angles

__all__ = ["antenna_frame_geometry", "lattice_offsets"]


def antenna_frame_geometry(antenna_poses, points) -> AntennaFrameAngles:
    """(d, alpha, elevation) of `points` in the frames of `antenna_poses`.

    Parameters
    ----------
    antenna_poses : array_like, shape (n, 4) or (n, 6)
        [x_m, y_m, z_m, yaw_rad(, pitch_rad, roll_rad)], world frame.
    points : array_like, shape (n, k, 3) or (k, 3)
        World points [m]; (k, 3) is seen from every pose, (n, k, 3) gives each
        pose its own k points.

    Returns
    -------
    propagation.AntennaFrameAngles
        ``d_m``, ``alpha_rad``, ``elevation_rad`` of shape (n, k).
    """
    p = np.asarray(antenna_poses, dtype=np.float64)
    if p.ndim == 1:
        p = p[None, :]
    if p.ndim != 2 or p.shape[1] not in (4, 6):
        raise ValueError(f"antenna_poses must have shape (n, 4) or (n, 6), got {p.shape}")
    if not np.all(np.isfinite(p)):
        raise ValueError("antenna_poses contains NaN or inf")
    pts = np.asarray(points, dtype=np.float64)
    if pts.ndim == 2 and pts.shape[1] == 3:
        return antenna_frame_angles(p, pts)
    if pts.ndim != 3 or pts.shape[0] != p.shape[0] or pts.shape[2] != 3:
        raise ValueError(
            f"points must have shape (k, 3) or ({p.shape[0]}, k, 3), got {np.shape(points)}"
        )
    # per-pose point sets: one call per distinct pose (reads of one cycle share a pose)
    k = pts.shape[1]
    out = {name: np.empty(pts.shape[:2]) for name in ("d_m", "alpha_rad", "elevation_rad")}
    uniq, inverse = np.unique(p, axis=0, return_inverse=True)
    inverse = inverse.ravel()
    for i in range(uniq.shape[0]):
        sel = inverse == i
        geo = antenna_frame_angles(uniq[i : i + 1], pts[sel].reshape(-1, 3))
        for name, arr in out.items():
            arr[sel] = getattr(geo, name).reshape(-1, k)
    return AntennaFrameAngles(**out)


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
