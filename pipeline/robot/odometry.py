"""Wheel odometry and its noise: the odometry motion model of Thrun, Burgard & Fox.

*Probabilistic Robotics* (2005), sec. 5.4, Table 5.6 (``sample_motion_model_odometry``):
a relative motion between two odometry readings is decomposed into a rotation
``d_rot1``, a translation ``d_trans`` and a second rotation ``d_rot2``; each is perturbed
by zero-mean Gaussian noise with variance

    var(rot1)  = alpha1 d_rot1^2 + alpha2 d_trans^2
    var(trans) = alpha3 d_trans^2 + alpha4 (d_rot1^2 + d_rot2^2)
    var(rot2)  = alpha1 d_rot2^2 + alpha2 d_trans^2.

Two practical amendments (as in ROS AMCL): for translations below 1 cm ``d_rot1`` is 0
(the bearing of a tiny step is meaningless), and the noise of a backward step uses the
rotation angle folded to the forward direction.

The noise variance per step scales with the square of the step, so the accumulated
drift of a path depends on the step length: the alphas are per trajectory step.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from pipeline.robot.kinematics import wrap_angle

__all__ = [
    "OdometryNoise",
    "odometry_deltas",
    "sample_motion_model_odometry",
    "simulate_odometry",
]


@dataclass(frozen=True)
class OdometryNoise:
    """Parameters of the odometry noise model (Thrun et al. 2005, Table 5.6).

    Attributes
    ----------
    alpha1 : float
        Rotation noise from rotation [rad^2 / rad^2].
    alpha2 : float
        Rotation noise from translation [rad^2 / m^2].
    alpha3 : float
        Translation noise from translation [m^2 / m^2].
    alpha4 : float
        Translation noise from rotation [m^2 / rad^2].
    translation_scale : float
        Systematic factor on measured translations (wheel radius error; 1 = none).
        Used when simulating a robot's odometry, not by the filter.
    rotation_scale : float
        Systematic factor on measured rotations (wheel base / skid error; 1 = none).
    """

    alpha1: float = 0.02
    alpha2: float = 0.02
    alpha3: float = 0.02
    alpha4: float = 0.002
    translation_scale: float = 1.0
    rotation_scale: float = 1.0

    def __post_init__(self) -> None:
        for k in ("alpha1", "alpha2", "alpha3", "alpha4"):
            v = getattr(self, k)
            if not (np.isfinite(v) and v >= 0):
                raise ValueError(f"OdometryNoise: {k}={v} must be finite and >= 0")
        for k in ("translation_scale", "rotation_scale"):
            v = getattr(self, k)
            if not (np.isfinite(v) and v > 0):
                raise ValueError(f"OdometryNoise: {k}={v} must be finite and > 0")


@dataclass(frozen=True)
class OdometryDeltas:
    """Relative motion between consecutive poses, decomposed rot1-trans-rot2.

    Attributes
    ----------
    rot1_rad, trans_m, rot2_rad : numpy.ndarray
        Shape (...,) each [rad, m, rad].
    """

    rot1_rad: np.ndarray
    trans_m: np.ndarray
    rot2_rad: np.ndarray


def odometry_deltas(u_prev: np.ndarray, u_now: np.ndarray) -> OdometryDeltas:
    """Decompose the motion from pose ``u_prev`` to ``u_now`` (..., 3) into rot1, trans, rot2."""
    u_prev = np.asarray(u_prev, dtype=float)
    u_now = np.asarray(u_now, dtype=float)
    dx = u_now[..., 0] - u_prev[..., 0]
    dy = u_now[..., 1] - u_prev[..., 1]
    trans = np.hypot(dx, dy)
    rot1 = np.where(trans < 0.01, 0.0, wrap_angle(np.arctan2(dy, dx) - u_prev[..., 2]))
    rot2 = wrap_angle(u_now[..., 2] - u_prev[..., 2] - rot1)
    return OdometryDeltas(rot1, trans, rot2)


def _noisy_deltas(
    d: OdometryDeltas, noise: OdometryNoise, size, rng: np.random.Generator
) -> OdometryDeltas:
    """Sample perturbed deltas (Table 5.6, lines 5-7), shape ``size``."""
    # noise of a backward step: fold the rotation to the forward direction (ROS AMCL)
    r1 = np.minimum(np.abs(d.rot1_rad), np.abs(np.pi - np.abs(d.rot1_rad)))
    r2 = np.minimum(np.abs(d.rot2_rad), np.abs(np.pi - np.abs(d.rot2_rad)))
    t = d.trans_m
    a1, a2, a3, a4 = noise.alpha1, noise.alpha2, noise.alpha3, noise.alpha4
    sd_r1 = np.sqrt(a1 * r1**2 + a2 * t**2)
    sd_t = np.sqrt(a3 * t**2 + a4 * (r1**2 + r2**2))
    sd_r2 = np.sqrt(a1 * r2**2 + a2 * t**2)
    return OdometryDeltas(
        d.rot1_rad - sd_r1 * rng.standard_normal(size),
        t - sd_t * rng.standard_normal(size),
        d.rot2_rad - sd_r2 * rng.standard_normal(size),
    )


def _apply(x: np.ndarray, d: OdometryDeltas) -> np.ndarray:
    th = x[..., 2] + d.rot1_rad
    return np.stack(
        [
            x[..., 0] + d.trans_m * np.cos(th),
            x[..., 1] + d.trans_m * np.sin(th),
            wrap_angle(th + d.rot2_rad),
        ],
        axis=-1,
    )


def sample_motion_model_odometry(
    u_prev: np.ndarray,
    u_now: np.ndarray,
    x_prev: np.ndarray,
    noise: OdometryNoise,
    rng: np.random.Generator,
) -> np.ndarray:
    """Sample successor poses given an odometry reading (Thrun et al. 2005, Table 5.6).

    Parameters
    ----------
    u_prev, u_now : numpy.ndarray
        Consecutive odometry readings (3,) [x_m, y_m, theta_rad].
    x_prev : numpy.ndarray
        Poses (n, 3) to propagate (particles).
    noise : OdometryNoise
        Noise parameters (the systematic scales are ignored here).
    rng : numpy.random.Generator

    Returns
    -------
    numpy.ndarray
        Propagated poses (n, 3), heading wrapped to (-pi, pi].
    """
    x = np.atleast_2d(np.asarray(x_prev, dtype=float))
    d = odometry_deltas(u_prev, u_now)
    return _apply(x, _noisy_deltas(d, noise, len(x), rng))


def simulate_odometry(
    true_poses: np.ndarray,
    noise: OdometryNoise,
    rng: np.random.Generator,
    start_pose: np.ndarray | None = None,
) -> np.ndarray:
    """Odometry readings a robot driving ``true_poses`` would integrate.

    Each true step is decomposed (rot1, trans, rot2), scaled by the systematic factors,
    perturbed with the Table 5.6 noise, and integrated from ``start_pose`` (default the
    first true pose), so the error accumulates along the path (dead-reckoning drift).

    Parameters
    ----------
    true_poses : numpy.ndarray
        True robot poses (n, 3) [x_m, y_m, theta_rad].
    noise : OdometryNoise
    rng : numpy.random.Generator
    start_pose : numpy.ndarray, optional
        First odometry reading (3,).

    Returns
    -------
    numpy.ndarray
        Odometry poses (n, 3); with all alphas 0 and unit scales equal to ``true_poses``
        up to rounding.
    """
    p = np.atleast_2d(np.asarray(true_poses, dtype=float))
    start = p[0] if start_pose is None else np.asarray(start_pose, dtype=float)
    d = odometry_deltas(p[:-1], p[1:])
    d = OdometryDeltas(
        d.rot1_rad * noise.rotation_scale,
        d.trans_m * noise.translation_scale,
        d.rot2_rad * noise.rotation_scale,
    )
    nd = _noisy_deltas(d, noise, len(p) - 1, rng)
    # integrate: heading before each translation, then after the second rotation
    th_after = start[2] + np.concatenate([[0.0], np.cumsum(nd.rot1_rad + nd.rot2_rad)])
    th_move = th_after[:-1] + nd.rot1_rad
    x = start[0] + np.concatenate([[0.0], np.cumsum(nd.trans_m * np.cos(th_move))])
    y = start[1] + np.concatenate([[0.0], np.cumsum(nd.trans_m * np.sin(th_move))])
    return np.stack([x, y, wrap_angle(th_after)], axis=-1)
