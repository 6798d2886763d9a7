"""Antenna patterns and antenna frames in NumPy, matching Sionna RT 2.x exactly.

The vertically polarised pattern functions re-implement ``sionna/rt/antenna_pattern.py``
(``v_iso_pattern``, ``v_dipole_pattern``, ``v_hw_dipole_pattern``, ``v_tr38901_pattern``)
and Sionna's default polarisation model ``tr38901_2`` (3GPP TR 38.901 eq. 7.3-4/5:
``C_theta = cos(zeta) C~``, ``C_phi = sin(zeta) C~``). Circular polarisation is added
here (Sionna has none): ``(C_theta, C_phi) = C~ (1, -/+ j) / sqrt(2)`` for RHCP/LHCP
(IEEE handedness, e^{j omega t}), so a circular reader feeding a linear tag shows its
3 dB mismatch in the traced gain itself.

Antenna frames follow ``shared`` contracts: an antenna pose is (x, y, z, yaw, pitch,
roll); the boresight is the local +x axis; positive pitch tilts the boresight *up*.
The rotation is ``R = Rz(yaw) Ry(-pitch) Rx(roll)``, i.e. Sionna's orientation
``(alpha, beta, gamma) = (yaw, -pitch, roll)`` (Sionna's positive beta tilts +x down;
TR 38.901 eq. 7.1-4).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

__all__ = [
    "PATTERNS",
    "POLARIZATIONS",
    "AntennaFrameAngles",
    "antenna_frame_angles",
    "as_pose6",
    "dipole_rotation",
    "pattern_amplitude",
    "pattern_gain_db",
    "pattern_field_world",
    "pose_rotation",
    "rotation_matrix",
    "sionna_orientation",
    "spherical_basis",
    "theta_phi_from_unit_vec",
    "unit_vec_from_theta_phi",
]

#: Pattern names understood here (Sionna's registry names).
PATTERNS = ("iso", "dipole", "hw_dipole", "tr38901")
#: Polarisations: linear V/H (Sionna's slant 0 / pi/2) and circular RHCP/LHCP.
POLARIZATIONS = ("V", "H", "RHCP", "LHCP")


def pattern_amplitude(name: str, theta, phi) -> np.ndarray:
    """Vertically polarised field pattern C~_theta(theta, phi) (real, >= 0).

    Parameters
    ----------
    name : {"iso", "dipole", "hw_dipole", "tr38901"}
        ``iso``: 1; ``dipole``: sqrt(1.5)|sin theta| (short dipole, Balanis eq. 4-26a);
        ``hw_dipole``: sqrt(1.643)|cos(pi/2 cos theta)/sin theta| (Balanis eq. 4-84,
        2.15 dBi); ``tr38901``: 3GPP TR 38.901 Table 7.3-1 (8 dBi, 65 deg HPBW both
        planes, 30 dB front-back and side-lobe floor).
    theta, phi : array_like
        Zenith and azimuth angles in the antenna frame [rad], broadcastable.

    Returns
    -------
    numpy.ndarray
        Field amplitude, float64, broadcast shape; gain is its square.
    """
    theta = np.asarray(theta, dtype=float)
    phi = np.asarray(phi, dtype=float)
    if name == "iso":
        return np.ones(np.broadcast(theta, phi).shape)
    if name == "dipole":
        return np.abs(np.sqrt(1.5) * np.sin(theta)) + 0.0 * phi
    if name == "hw_dipole":
        s = np.sin(theta)
        inv = np.where(np.isclose(s, 0.0, atol=1e-5), 1.0, 1.0 / np.where(s == 0, 1.0, s))
        return np.abs(np.sqrt(1.643) * np.cos(np.pi / 2 * np.cos(theta)) * inv) + 0.0 * phi
    if name == "tr38901":
        phi = np.mod(phi + np.pi, 2 * np.pi) - np.pi
        theta_3db = phi_3db = np.deg2rad(65.0)
        a_max = sla_v = 30.0
        g_e_max = 8.0
        a_v = -np.minimum(12.0 * ((theta - np.pi / 2) / theta_3db) ** 2, sla_v)
        a_h = -np.minimum(12.0 * (phi / phi_3db) ** 2, a_max)
        a_db = -np.minimum(-(a_v + a_h), a_max) + g_e_max
        return np.sqrt(10.0 ** (a_db / 10.0))
    raise ValueError(f"unknown antenna pattern {name!r}; known: {', '.join(PATTERNS)}")


def pattern_gain_db(name: str, theta, phi) -> np.ndarray:
    """Directional gain 10 log10(|C_theta|^2 + |C_phi|^2) [dBi] of pattern ``name``.

    Same angles and names as :func:`pattern_amplitude`; independent of polarisation.
    Nulls give -inf.
    """
    with np.errstate(divide="ignore"):
        return 20.0 * np.log10(pattern_amplitude(name, theta, phi))


def _polarization_vector(polarization: str) -> np.ndarray:
    if polarization == "V":
        return np.array([1.0, 0.0], dtype=complex)
    if polarization == "H":
        return np.array([0.0, 1.0], dtype=complex)
    if polarization == "RHCP":
        return np.array([1.0, -1.0j]) / np.sqrt(2.0)
    if polarization == "LHCP":
        return np.array([1.0, 1.0j]) / np.sqrt(2.0)
    raise ValueError(f"unknown polarization {polarization!r}; known: {', '.join(POLARIZATIONS)}")


def rotation_matrix(alpha, beta, gamma) -> np.ndarray:
    """Sionna's rotation ``Rz(alpha) Ry(beta) Rx(gamma)`` (TR 38.901 eq. 7.1-4).

    Parameters
    ----------
    alpha, beta, gamma : array_like
        Rotation angles about z, y, x [rad], broadcastable, shape (...).

    Returns
    -------
    numpy.ndarray
        Shape (..., 3, 3); columns are the local axes in world coordinates.
    """
    a, b, c = np.broadcast_arrays(*(np.asarray(v, dtype=float) for v in (alpha, beta, gamma)))
    sa, ca, sb, cb, sc, cc = np.sin(a), np.cos(a), np.sin(b), np.cos(b), np.sin(c), np.cos(c)
    r = np.empty(a.shape + (3, 3))
    r[..., 0, 0] = ca * cb
    r[..., 0, 1] = ca * sb * sc - sa * cc
    r[..., 0, 2] = ca * sb * cc + sa * sc
    r[..., 1, 0] = sa * cb
    r[..., 1, 1] = sa * sb * sc + ca * cc
    r[..., 1, 2] = sa * sb * cc - ca * sc
    r[..., 2, 0] = -sb
    r[..., 2, 1] = cb * sc
    r[..., 2, 2] = cb * cc
    return r


def sionna_orientation(yaw, pitch, roll) -> np.ndarray:
    """Sionna orientation (alpha, beta, gamma) = (yaw, -pitch, roll) of a pose, shape (..., 3)."""
    return np.stack(np.broadcast_arrays(yaw, -np.asarray(pitch, dtype=float), roll), axis=-1)


def as_pose6(antenna_poses) -> np.ndarray:
    """Antenna poses as (n, 6) [x, y, z, yaw, pitch, roll]; (n, 4) gets pitch = roll = 0.

    Raises
    ------
    ValueError
        Any other shape.
    """
    poses = np.asarray(antenna_poses, dtype=float)
    if poses.ndim == 1:
        poses = poses[None, :]
    if poses.ndim != 2 or poses.shape[1] not in (4, 6):
        raise ValueError(
            f"antenna_poses must have shape (n, 4) [x, y, z, yaw] or (n, 6) "
            f"[x, y, z, yaw, pitch, roll], got {poses.shape}"
        )
    if poses.shape[1] == 4:
        poses = np.concatenate([poses, np.zeros((len(poses), 2))], axis=1)
    return poses


def pose_rotation(antenna_poses) -> np.ndarray:
    """Rotation matrices of antenna poses, shape (n, 3, 3), ``Rz(yaw) Ry(-pitch) Rx(roll)``.

    ``antenna_poses`` is (n, 4) [x, y, z, yaw] or (n, 6) [x, y, z, yaw, pitch, roll] [m, rad].
    """
    p = as_pose6(antenna_poses)
    return rotation_matrix(p[:, 3], -p[:, 4], p[:, 5])


def dipole_rotation(axes) -> np.ndarray:
    """Rotations taking the local z axis (a dipole's axis) onto ``axes``, shape (m, 3, 3)."""
    z = np.asarray(axes, dtype=float).reshape(-1, 3)
    z = z / np.linalg.norm(z, axis=1, keepdims=True)
    ref = np.where(np.abs(z[:, [0]]) < 0.9, [[1.0, 0.0, 0.0]], [[0.0, 1.0, 0.0]])
    x = ref - np.sum(ref * z, axis=1, keepdims=True) * z
    x /= np.linalg.norm(x, axis=1, keepdims=True)
    y = np.cross(z, x)
    return np.stack([x, y, z], axis=-1)


def theta_phi_from_unit_vec(v) -> tuple[np.ndarray, np.ndarray]:
    """Zenith and azimuth [rad] of unit vectors ``v`` (..., 3); azimuth 0 at the poles."""
    v = np.asarray(v, dtype=float)
    rho = np.hypot(v[..., 0], v[..., 1])
    theta = np.arctan2(rho, v[..., 2])
    phi = np.where(rho > 0, np.arctan2(v[..., 1], v[..., 0]), 0.0)
    return theta, phi


def unit_vec_from_theta_phi(theta, phi) -> np.ndarray:
    """Unit vectors (..., 3) of zenith/azimuth angles [rad]."""
    st = np.sin(theta)
    return np.stack([st * np.cos(phi), st * np.sin(phi), np.cos(theta) + 0.0 * phi], axis=-1)


def spherical_basis(theta, phi) -> tuple[np.ndarray, np.ndarray]:
    """Unit vectors theta-hat and phi-hat (..., 3) of the spherical basis at (theta, phi)."""
    theta, phi = np.broadcast_arrays(np.asarray(theta, float), np.asarray(phi, float))
    ct, st, cp, sp = np.cos(theta), np.sin(theta), np.cos(phi), np.sin(phi)
    theta_hat = np.stack([ct * cp, ct * sp, -st], axis=-1)
    phi_hat = np.stack([-sp, cp, np.zeros_like(phi)], axis=-1)
    return theta_hat, phi_hat


def pattern_field_world(name: str, polarization: str, rotation, k_world) -> np.ndarray:
    """Complex pattern of a rotated antenna in the world spherical basis at ``k_world``.

    Evaluates the pattern at the local angles of ``R^T k`` and rotates its local
    (theta', phi') components into the world (theta, phi) basis at ``k`` -- the algebra
    of Sionna's ``antenna_pattern_to_world_implicit`` without the implicit basis (which
    cancels against a trace made with unrotated isotropic ``VH`` antennas).

    Parameters
    ----------
    name, polarization : str
        Pattern (see :data:`PATTERNS`) and polarisation (see :data:`POLARIZATIONS`).
    rotation : array_like
        Antenna-to-world rotations, shape (..., 3, 3).
    k_world : array_like
        Unit directions (..., 3) pointing away from the antenna (departure direction
        for a transmitter; the direction toward the incoming wave for a receiver).

    Returns
    -------
    numpy.ndarray
        (C_theta, C_phi) in the world basis, complex128, shape (..., 2).
    """
    rot = np.asarray(rotation, dtype=float)
    k = np.asarray(k_world, dtype=float)
    k_local = np.einsum("...ji,...j->...i", rot, k)
    th_l, ph_l = theta_phi_from_unit_vec(k_local)
    amp = pattern_amplitude(name, th_l, ph_l)
    c_local = amp[..., None] * _polarization_vector(polarization)
    thl_hat, phl_hat = spherical_basis(th_l, ph_l)
    thl_w = np.einsum("...ij,...j->...i", rot, thl_hat)
    phl_w = np.einsum("...ij,...j->...i", rot, phl_hat)
    th_w, ph_w = theta_phi_from_unit_vec(k)
    thw_hat, phw_hat = spherical_basis(th_w, ph_w)
    m00 = np.sum(thw_hat * thl_w, axis=-1)
    m01 = np.sum(thw_hat * phl_w, axis=-1)
    m10 = np.sum(phw_hat * thl_w, axis=-1)
    m11 = np.sum(phw_hat * phl_w, axis=-1)
    c_th = m00 * c_local[..., 0] + m01 * c_local[..., 1]
    c_ph = m10 * c_local[..., 0] + m11 * c_local[..., 1]
    return np.stack([c_th, c_ph], axis=-1)


@dataclass(frozen=True)
class AntennaFrameAngles:
    """Geometry of points seen from antennas (the sensor model's d and alpha).

    Attributes
    ----------
    d_m : numpy.ndarray
        Distance antenna to point, shape (n, m), float64, metres.
    alpha_rad : numpy.ndarray
        Bearing atan2(y_local, x_local) in the antenna frame, wrapped to (-pi, pi],
        shape (n, m), rad.
    elevation_rad : numpy.ndarray
        atan2(z_local, hypot(x_local, y_local)), shape (n, m), rad.
    """

    d_m: np.ndarray
    alpha_rad: np.ndarray
    elevation_rad: np.ndarray


def antenna_frame_angles(antenna_poses, points) -> AntennaFrameAngles:
    """d, alpha and elevation of ``points`` (m, 3) from ``antenna_poses`` (n, 4|6).

    Uses the full antenna frame ``R = Rz(yaw) Ry(-pitch) Rx(roll)``; with pitch = roll = 0
    alpha is the bearing relative to the yaw direction in the horizontal plane.
    """
    poses = as_pose6(antenna_poses)
    pts = np.asarray(points, dtype=float).reshape(-1, 3)
    rot = pose_rotation(poses)
    diff = pts[None, :, :] - poses[:, None, :3]
    local = np.einsum("nji,nmj->nmi", rot, diff)
    d = np.linalg.norm(diff, axis=-1)
    alpha = np.arctan2(local[..., 1], local[..., 0])
    alpha = np.where(alpha <= -np.pi, alpha + 2 * np.pi, alpha)
    elev = np.arctan2(local[..., 2], np.hypot(local[..., 0], local[..., 1]))
    return AntennaFrameAngles(d_m=d, alpha_rad=alpha, elevation_rad=elev)
