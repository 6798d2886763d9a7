"""Robot pose tracks (true, odometry, estimated) and their interpolation at read times."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from pipeline.robot.kinematics import wrap_angle

__all__ = ["PoseTrack", "as_pose_track", "interpolate_poses"]


@dataclass(frozen=True)
class PoseTrack:
    """Time-stamped robot poses as the acquisition stage consumes them.

    Attributes
    ----------
    t_s : numpy.ndarray
        Time stamps, shape (n,), float64, seconds, strictly increasing.
    true_poses : numpy.ndarray
        Ground-truth robot poses (x_m, y_m, theta_rad), shape (n, 3), float64.
    est_poses : numpy.ndarray
        Estimated (MCL) poses, shape (n, 3), float64; equal to ``true_poses`` when no
        localisation was run.
    odom_poses : numpy.ndarray
        Odometry poses, shape (n, 3), float64; NaN where unknown.
    """

    t_s: np.ndarray
    true_poses: np.ndarray
    est_poses: np.ndarray
    odom_poses: np.ndarray

    def __post_init__(self) -> None:
        t = np.asarray(self.t_s, dtype=float).reshape(-1)
        arrs = {}
        for name in ("true_poses", "est_poses", "odom_poses"):
            a = np.asarray(getattr(self, name), dtype=float)
            if a.shape != (len(t), 3):
                raise ValueError(
                    f"PoseTrack: {name} must have shape ({len(t)}, 3) to match t_s, got {a.shape}"
                )
            arrs[name] = a
        if len(t) < 2:
            raise ValueError(f"PoseTrack: need at least 2 time stamps, got {len(t)}")
        if not np.all(np.isfinite(t)) or np.any(np.diff(t) <= 0):
            raise ValueError("PoseTrack: t_s must be finite and strictly increasing")
        for name in ("true_poses", "est_poses"):
            if not np.all(np.isfinite(arrs[name])):
                raise ValueError(f"PoseTrack: {name} contains NaN or inf")
        object.__setattr__(self, "t_s", t)
        for name, a in arrs.items():
            object.__setattr__(self, name, a)


def _first_attr(obj: object, names: tuple[str, ...]) -> np.ndarray | None:
    for n in names:
        v = getattr(obj, n, None)
        if v is not None:
            return np.asarray(v, dtype=float)
    return None


def as_pose_track(obj: object) -> PoseTrack:
    """Turn a localisation result, a trajectory or a tuple into a :class:`PoseTrack`.

    Accepted inputs
    ---------------
    - a :class:`PoseTrack` (returned as is);
    - a tuple ``(true_poses, est_poses, t_s)`` (odometry unknown);
    - an object with ``t_s`` and true poses (``true_poses`` or ``poses``) and
      optionally estimated (``est_poses``/``estimated_poses``) and odometry
      (``odom_poses``/``odometry_poses``) poses: ``pipeline.robot``'s
      ``LocalizationResult`` and ``Trajectory`` (then est = true).

    Raises
    ------
    TypeError
        If ``obj`` is none of these.
    """
    if isinstance(obj, PoseTrack):
        return obj
    if isinstance(obj, tuple):
        if len(obj) != 3:
            raise TypeError("pose track tuple must be (true_poses, est_poses, t_s)")
        true, est, t = (np.asarray(v, dtype=float) for v in obj)
        return PoseTrack(t, true, est, np.full_like(true, np.nan))
    t = _first_attr(obj, ("t_s", "time_s"))
    true = _first_attr(obj, ("true_poses", "poses"))
    if t is None or true is None:
        raise TypeError(
            f"cannot read a pose track from {type(obj).__name__}: need t_s and "
            "true_poses (or poses)"
        )
    est = _first_attr(obj, ("est_poses", "estimated_poses"))
    odom = _first_attr(obj, ("odom_poses", "odometry_poses"))
    return PoseTrack(
        t,
        true,
        true.copy() if est is None else est,
        np.full_like(true, np.nan) if odom is None else odom,
    )


def interpolate_poses(t_s: np.ndarray, poses: np.ndarray, t_query_s: np.ndarray) -> np.ndarray:
    """Linear interpolation of planar poses; heading along the shortest arc.

    Parameters
    ----------
    t_s : numpy.ndarray
        Sample times, shape (n,), seconds, increasing.
    poses : numpy.ndarray
        (x_m, y_m, theta_rad), shape (n, 3).
    t_query_s : numpy.ndarray
        Query times within [t_s[0], t_s[-1]], shape (k,), seconds.

    Returns
    -------
    numpy.ndarray
        Shape (k, 3), float64, heading wrapped to (-pi, pi].
    """
    t_s = np.asarray(t_s, dtype=float)
    poses = np.asarray(poses, dtype=float)
    tq = np.asarray(t_query_s, dtype=float)
    theta = np.unwrap(poses[:, 2])
    out = np.empty((len(tq), 3))
    out[:, 0] = np.interp(tq, t_s, poses[:, 0])
    out[:, 1] = np.interp(tq, t_s, poses[:, 1])
    out[:, 2] = wrap_angle(np.interp(tq, t_s, theta))
    return out
