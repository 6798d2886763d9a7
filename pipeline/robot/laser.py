"""2-D laser range finder (SICK LMS-like) ray-cast against the scene's wall segments.

The scan plane is horizontal at the scanner's height; the scene is cut there into
segments (:func:`scenes.floor_plan_segments`) and each beam is
intersected exactly with every nearby segment (vectorised 2-D ray/segment test).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from pipeline.robot.kinematics import compose_poses

__all__ = ["LaserScanner", "ray_cast"]


def ray_cast(
    origins: np.ndarray,
    directions: np.ndarray,
    segments: np.ndarray,
    max_range_m: float,
    chunk_elements: int = 2_000_000,
) -> np.ndarray:
    """Distance along each ray to the first segment it hits.

    Solves ``o + t d = a + u (b - a)`` with ``t > 0``, ``0 <= u <= 1`` by 2-D cross
    products: ``t = (a - o) x e / (d x e)``, ``u = (a - o) x d / (d x e)``, e = b - a.

    Parameters
    ----------
    origins : numpy.ndarray
        Ray origins (k, 2) [m].
    directions : numpy.ndarray
        Unit ray directions (k, 2).
    segments : numpy.ndarray
        Segments (m, 2, 2) [m].
    max_range_m : float
        Returned where nothing is hit within this range [m].
    chunk_elements : int
        Rays x segments evaluated at once (memory bound).

    Returns
    -------
    numpy.ndarray
        Ranges (k,) float64 [m], ``max_range_m`` where no hit closer than that.
    """
    o = np.asarray(origins, dtype=float).reshape(-1, 2)
    d = np.asarray(directions, dtype=float).reshape(-1, 2)
    seg = np.asarray(segments, dtype=float).reshape(-1, 2, 2)
    out = np.full(len(o), float(max_range_m))
    if len(seg) == 0 or len(o) == 0:
        return out
    a = seg[:, 0]
    e = seg[:, 1] - seg[:, 0]
    step = max(1, chunk_elements // len(seg))
    for i in range(0, len(o), step):
        oo, dd = o[i : i + step, None, :], d[i : i + step, None, :]
        ao = a[None] - oo  # (c, m, 2)
        denom = dd[..., 0] * e[None, :, 1] - dd[..., 1] * e[None, :, 0]
        with np.errstate(divide="ignore", invalid="ignore"):
            t = (ao[..., 0] * e[None, :, 1] - ao[..., 1] * e[None, :, 0]) / denom
            u = (ao[..., 0] * dd[..., 1] - ao[..., 1] * dd[..., 0]) / denom
        ok = (np.abs(denom) > 1e-12) & (t > 1e-9) & (u >= -1e-12) & (u <= 1 + 1e-12)
        t = np.where(ok, t, np.inf)
        out[i : i + step] = np.minimum(t.min(axis=1), max_range_m)
    return out


@dataclass(frozen=True)
class LaserScanner:
    """A planar laser scanner mounted on the robot (defaults: SICK LMS-200 on a P3-AT).

    Attributes
    ----------
    n_beams : int
        Beams per scan (181: one per degree).
    fov_rad : float
        Angular field of view [rad], centred on the scanner's heading (pi: 180 deg).
    max_range_m : float
        Maximum range [m]; reported when nothing is hit (8 m).
    range_noise_m : float
        Standard deviation of the Gaussian range noise [m] (SICK LMS: about 1 cm).
    mount_x_m, mount_y_m, mount_yaw_rad : float
        Scanner pose in the robot frame [m, m, rad] (on the P3-AT: 0.16 m forward).
    height_m : float
        Height of the scan plane above the floor [m].
    """

    n_beams: int = 181
    fov_rad: float = np.pi
    max_range_m: float = 8.0
    range_noise_m: float = 0.01
    mount_x_m: float = 0.16
    mount_y_m: float = 0.0
    mount_yaw_rad: float = 0.0
    height_m: float = 0.35

    def __post_init__(self) -> None:
        if int(self.n_beams) < 1:
            raise ValueError(f"LaserScanner: n_beams={self.n_beams} must be >= 1")
        if not 0 < self.fov_rad <= 2 * np.pi:
            raise ValueError(f"LaserScanner: fov_rad={self.fov_rad} must be in (0, 2 pi]")
        if not self.max_range_m > 0:
            raise ValueError(f"LaserScanner: max_range_m={self.max_range_m} must be > 0")
        if not self.range_noise_m >= 0:
            raise ValueError(f"LaserScanner: range_noise_m={self.range_noise_m} must be >= 0")
        if not self.height_m > 0:
            raise ValueError(f"LaserScanner: height_m={self.height_m} must be > 0")

    @property
    def angles_rad(self) -> np.ndarray:
        """Beam angles relative to the scanner heading, shape (n_beams,) [rad]."""
        if self.n_beams == 1:
            return np.zeros(1)
        return np.linspace(-self.fov_rad / 2, self.fov_rad / 2, int(self.n_beams))

    def sensor_poses(self, robot_poses: np.ndarray) -> np.ndarray:
        """World poses (..., 3) of the scanner for robot poses (..., 3)."""
        mount = np.array([self.mount_x_m, self.mount_y_m, self.mount_yaw_rad])
        return compose_poses(np.asarray(robot_poses, dtype=float), mount)

    def true_ranges(self, segments: np.ndarray, robot_poses: np.ndarray) -> np.ndarray:
        """Noise-free ranges (n_poses, n_beams) [m] from robot poses (n_poses, 3)."""
        poses = np.atleast_2d(np.asarray(robot_poses, dtype=float))
        sp = self.sensor_poses(poses)
        ang = sp[:, 2:3] + self.angles_rad[None, :]
        dirs = np.stack([np.cos(ang), np.sin(ang)], axis=-1)  # (n, b, 2)
        out = np.empty(ang.shape)
        seg = np.asarray(segments, dtype=float).reshape(-1, 2, 2)
        chunk = 64  # poses per chunk: prune segments out of reach of the chunk
        for i in range(0, len(sp), chunk):
            p = sp[i : i + chunk, :2]
            lo, hi = p.min(0) - self.max_range_m, p.max(0) + self.max_range_m
            smin, smax = seg.min(axis=1), seg.max(axis=1)
            near = np.all((smax >= lo) & (smin <= hi), axis=1)
            orig = np.repeat(p, self.n_beams, axis=0)
            out[i : i + chunk] = ray_cast(
                orig, dirs[i : i + chunk].reshape(-1, 2), seg[near], self.max_range_m
            ).reshape(-1, self.n_beams)
        return out

    def scan(self, segments: np.ndarray, poses: np.ndarray, rng: np.random.Generator) -> np.ndarray:
        """Simulated scans: exact ranges plus Gaussian noise, max range where nothing is hit.

        Parameters
        ----------
        segments : numpy.ndarray
            Wall segments (m, 2, 2) at the scan height [m]
            (:func:`scenes.floor_plan_segments`).
        poses : numpy.ndarray
            Robot poses (n_poses, 3) [x_m, y_m, theta_rad].
        rng : numpy.random.Generator

        Returns
        -------
        numpy.ndarray
            Ranges (n_poses, n_beams) float64 [m], in [0, max_range_m]; exactly
            ``max_range_m`` for beams that hit nothing within range.
        """
        r = self.true_ranges(segments, poses)
        miss = r >= self.max_range_m
        noisy = r + rng.normal(0.0, self.range_noise_m, size=r.shape)
        noisy = np.clip(noisy, 0.0, self.max_range_m)
        return np.where(miss, self.max_range_m, noisy)

    def endpoints(self, robot_poses: np.ndarray, ranges: np.ndarray, beams=None) -> np.ndarray:
        """World end points (n, n_beams_used, 2) [m] of ranges (n, n_beams_used).

        ``beams`` is an optional index array selecting which beams ``ranges`` holds.
        ``robot_poses`` (n, 3) broadcasts against ``ranges``.
        """
        ang0 = self.angles_rad if beams is None else self.angles_rad[np.asarray(beams)]
        sp = self.sensor_poses(robot_poses)
        ang = sp[..., 2:3] + ang0
        return np.stack(
            [sp[..., 0:1] + ranges * np.cos(ang), sp[..., 1:2] + ranges * np.sin(ang)], axis=-1
        )
