"""Antenna-frame geometry of the sensor model: distance d and bearing alpha of tags.

The sensor model of Cicirelli, Milella and Di Paola (2011) is a function of the
distance ``d`` from the reader antenna to the tag and of the bearing ``alpha`` of the
tag in the antenna frame. This module computes both from antenna poses and tag
positions; it is pure NumPy geometry, kept here so the acquisition stage does not
depend on the ray tracer for it (``propagation.antenna_frame_angles`` computes the
same quantities under the same convention, see ``/work/shared`` contracts).

Convention (project contract): an antenna pose is ``(x, y, z, yaw, pitch, roll)`` in
the world frame, metres and radians; ``(n, 4)`` ``[x, y, z, yaw]`` means pitch = roll
= 0. The boresight is the antenna's local +x axis; positive pitch (tilt) turns the
boresight up. The world-from-antenna rotation is ``R = Rz(yaw) Ry(-pitch) Rx(roll)``.
A tag at world point ``p`` has local coordinates ``q = R^T (p - a)``;
``d = |q|``, ``alpha = atan2(q_y, q_x)`` wrapped to (-pi, pi] and
``elevation = atan2(q_z, hypot(q_x, q_y))``.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

__all__ = ["AntennaFrameAngles", "antenna_frame_angles", "as_antenna_poses6", "wrap_angle"]


@dataclass(frozen=True)
class AntennaFrameAngles:
    """Tag geometry seen from each antenna pose.

    Attributes
    ----------
    d_m : numpy.ndarray
        Distance antenna to tag, shape (n_poses, n_points), float64, metres.
    alpha_rad : numpy.ndarray
        Bearing of the tag in the antenna frame, atan2(y_local, x_local), wrapped to
        (-pi, pi], shape (n_poses, n_points), float64, radians. Positive to the
        antenna's left (counter-clockwise seen from above for an untilted antenna).
    elevation_rad : numpy.ndarray
        Elevation of the tag above the antenna's local x-y plane, in [-pi/2, pi/2],
        shape (n_poses, n_points), float64, radians.
    """

    d_m: np.ndarray
    alpha_rad: np.ndarray
    elevation_rad: np.ndarray


def wrap_angle(angle_rad: np.ndarray) -> np.ndarray:
    """Wrap angles to (-pi, pi].

    Parameters
    ----------
    angle_rad : array_like
        Angles, any shape, radians.

    Returns
    -------
    numpy.ndarray
        Same shape, float64, in (-pi, pi].
    """
    a = np.asarray(angle_rad, dtype=float)
    w = np.mod(a + np.pi, 2.0 * np.pi) - np.pi  # [-pi, pi)
    return np.where(w <= -np.pi, w + 2.0 * np.pi, w)


def as_antenna_poses6(antenna_poses: np.ndarray) -> np.ndarray:
    """Promote ``(n, 4)`` ``[x, y, z, yaw]`` poses to ``(n, 6)`` with pitch = roll = 0.

    Parameters
    ----------
    antenna_poses : array_like
        Shape (n, 4) or (n, 6), metres and radians.

    Returns
    -------
    numpy.ndarray
        Shape (n, 6), float64.

    Raises
    ------
    ValueError
        If the shape is not (n, 4) or (n, 6) or the values are not finite.
    """
    p = np.asarray(antenna_poses, dtype=float)
    if p.ndim == 1:
        p = p[None, :]
    if p.ndim != 2 or p.shape[1] not in (4, 6):
        raise ValueError(f"antenna_poses must have shape (n, 4) or (n, 6), got {p.shape}")
    if not np.all(np.isfinite(p)):
        raise ValueError("antenna_poses contains NaN or inf")
    if p.shape[1] == 4:
        p = np.concatenate([p, np.zeros((len(p), 2))], axis=1)
    return p


def _rotations(poses6: np.ndarray) -> np.ndarray:
    """World-from-antenna rotation matrices R = Rz(yaw) Ry(-pitch) Rx(roll), (n, 3, 3)."""
    yaw, pitch, roll = poses6[:, 3], poses6[:, 4], poses6[:, 5]
    cy, sy = np.cos(yaw), np.sin(yaw)
    # Ry(-pitch): positive pitch turns +x towards +z (boresight up).
    cp, sp = np.cos(-pitch), np.sin(-pitch)
    cr, sr = np.cos(roll), np.sin(roll)
    n = len(poses6)
    rz = np.zeros((n, 3, 3))
    rz[:, 0, 0], rz[:, 0, 1], rz[:, 1, 0], rz[:, 1, 1], rz[:, 2, 2] = cy, -sy, sy, cy, 1.0
    ry = np.zeros((n, 3, 3))
    ry[:, 0, 0], ry[:, 0, 2], ry[:, 2, 0], ry[:, 2, 2], ry[:, 1, 1] = cp, sp, -sp, cp, 1.0
    rx = np.zeros((n, 3, 3))
    rx[:, 1, 1], rx[:, 1, 2], rx[:, 2, 1], rx[:, 2, 2], rx[:, 0, 0] = cr, -sr, sr, cr, 1.0
    return rz @ ry @ rx


def antenna_frame_angles(antenna_poses: np.ndarray, points: np.ndarray) -> AntennaFrameAngles:
    """Distance, bearing and elevation of points in each antenna's frame.

    Parameters
    ----------
    antenna_poses : array_like
        Shape (n, 4) ``[x, y, z, yaw]`` or (n, 6) ``[x, y, z, yaw, pitch, roll]``,
        metres and radians, world frame.
    points : array_like
        Tag positions, shape (m, 3), metres, world frame.

    Returns
    -------
    AntennaFrameAngles
        ``d_m``, ``alpha_rad``, ``elevation_rad``, each of shape (n, m).

    Examples
    --------
    A tag straight ahead has alpha = 0, one to the antenna's left alpha = +pi/2:

    >>> g = antenna_frame_angles([[0, 0, 1, 0]], [[2, 0, 1], [0, 3, 1]])
    >>> g.d_m.round(6).tolist(), g.alpha_rad.round(6).tolist()
    ([[2.0, 3.0]], [[0.0, 1.570796]])
    """
    p6 = as_antenna_poses6(antenna_poses)
    pts = np.asarray(points, dtype=float)
    if pts.ndim != 2 or pts.shape[1] != 3:
        raise ValueError(f"points must have shape (m, 3), got {pts.shape}")
    rot = _rotations(p6)  # (n, 3, 3)
    diff = pts[None, :, :] - p6[:, None, :3]  # (n, m, 3), world
    # local = R^T diff  ->  local_j = sum_i R_ij diff_i
    local = np.einsum("nij,nmi->nmj", rot, diff)
    d = np.linalg.norm(local, axis=2)
    alpha = wrap_angle(np.arctan2(local[..., 1], local[..., 0]))
    elev = np.arctan2(local[..., 2], np.hypot(local[..., 0], local[..., 1]))
    return AntennaFrameAngles(d_m=d, alpha_rad=alpha, elevation_rad=elev)
