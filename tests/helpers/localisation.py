"""Synthetic scenes for the localisation tests and benchmark (no ray tracing).

* :func:`free_space_gain_db`: the one-way gain of a free-space scene (no walls), Friis
  plus the reader antenna's pattern (``tr38901``, the project's reader) and a constant
  tag gain: a stand-in for the ray-traced gains the oracle takes.
* :class:`SyntheticSensor`: a ``SensorLike`` model in closed form (log-distance RSSI
  with the TR 38.901 horizontal pattern, detection a soft threshold on that RSSI,
  constant RSSI noise) to sample reads from and to localise with.
* :func:`corridor_scenario`: a straight corridor with tags on both walls, a robot
  driving along its centre line with the default two antennas, attempt slots as the
  reader schedules them, and candidate positions on the walls.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.special import ndtr

from pipeline.localisation.observations import Observations, as_pose6
from propagation import antenna_frame_angles, pattern_gain_db
from propagation import free_space_gain_db as _friis
from propagation.analytic import wavelength_m

__all__ = [
    "CorridorScenario",
    "SyntheticSensor",
    "corridor_scenario",
    "free_space_gain_db",
    "max_free_space_range_m",
    "sample_attempts",
    "straight_path",
    "wall_candidates",
]


def free_space_gain_db(antenna_poses, points, frequency_hz: float = 865e6,
                       reader_pattern: str = "tr38901", tag_gain_dbi: float = 2.15) -> np.ndarray:
    """One-way gain [dB] of every (antenna pose, point) pair in free space, shape (n, k).

    ``20 log10(lambda / (4 pi d)) + G_reader(theta, phi) + tag_gain_dbi`` with the reader
    pattern at the point's zenith ``theta = pi/2 - elevation`` and azimuth ``phi = alpha``
    in the antenna frame (:func:`propagation.antenna_frame_angles`).
    """
    geo = antenna_frame_angles(as_pose6(antenna_poses), np.asarray(points, float).reshape(-1, 3))
    d = np.maximum(geo.d_m, 1e-3)
    g = _friis(d, frequency_hz, gain_tx_dbi=0.0, gain_rx_dbi=tag_gain_dbi)
    return g + pattern_gain_db(reader_pattern, np.pi / 2 - geo.elevation_rad, geo.alpha_rad)


@dataclass(frozen=True)
class SyntheticSensor:
    """A closed-form ``SensorLike`` model.

    ``fs_dbm(d, alpha) = p1m_dbm - 10 n log10(d) - min(12 (alpha / 65 deg)^2, 30)``
    (clipped to ``rssi_range_dbm``), ``fT = p_max Phi((rssi - threshold_dbm) / soft_db)``
    on the unclipped RSSI, RSSI noise ``sigma_db`` (``rssi_sigma_db``).
    """

    p1m_dbm: float = -45.0
    n: float = 4.0
    threshold_dbm: float = -72.0
    soft_db: float = 2.0
    p_max: float = 0.95
    sigma_db: float = 2.0
    rssi_range_dbm: tuple = (-80.0, -30.0)
    predicts_rssi = True

    def _rssi(self, d, alpha):
        d, a = np.broadcast_arrays(np.asarray(d, float), np.asarray(alpha, float))
        a = np.pi - np.mod(np.pi - a, 2 * np.pi)
        pat = -np.minimum(12.0 * (np.rad2deg(a) / 65.0) ** 2, 30.0)
        return self.p1m_dbm - 10.0 * self.n * np.log10(np.maximum(d, 1e-3)) + pat

    def fs_dbm(self, d, alpha):
        lo, hi = self.rssi_range_dbm
        return np.clip(self._rssi(d, alpha), lo, hi)

    def fs(self, d, alpha):
        lo, hi = self.rssi_range_dbm
        return (self.fs_dbm(d, alpha) - lo) / (hi - lo)

    def fT(self, d, alpha):  # noqa: N802 - the chapter's name
        return self.p_max * ndtr((self._rssi(d, alpha) - self.threshold_dbm) / self.soft_db)

    def rho(self, d, alpha):
        return self.fs(d, alpha) * self.fT(d, alpha)

    def rssi_sigma_db(self, d, alpha):
        return np.full(np.broadcast(np.asarray(d), np.asarray(alpha)).shape, self.sigma_db)


def sample_attempts(sensor: SyntheticSensor, n: int, rng: np.random.Generator,
                    d_lo_m: float = 0.1, d_hi_m: float = 8.0):
    """`n` attempts at d uniform in [d_lo_m, d_hi_m), alpha uniform in [-pi, pi), outcomes
    drawn from `sensor` (unclipped RSSI), as :class:`pipeline.sensormodels.Attempts`."""
    from pipeline.sensormodels import Attempts

    d = rng.uniform(d_lo_m, d_hi_m, int(n))
    a = rng.uniform(-np.pi, np.pi, int(n))
    read = rng.random(int(n)) < sensor.fT(d, a)
    rssi = np.where(read, sensor._rssi(d, a) + sensor.sigma_db * rng.standard_normal(int(n)),
                    np.nan)
    return Attempts(d, a, read, rssi)


def wall_candidates(length_m: float, width_m: float, spacing_m: float = 0.05,
                    z_range_m=(0.2, 1.6), offset_m: float = 0.005) -> np.ndarray:
    """Candidate positions on the two long walls (y = 0 and y = width) of a corridor (k, 3)."""
    xs = np.arange(spacing_m / 2, length_m, spacing_m)
    zs = np.arange(z_range_m[0], z_range_m[1] + 1e-9, spacing_m)
    gx, gz = np.meshgrid(xs, zs, indexing="ij")
    gx, gz = gx.ravel(), gz.ravel()
    return np.concatenate([np.column_stack([gx, np.full(gx.size, offset_m), gz]),
                           np.column_stack([gx, np.full(gx.size, width_m - offset_m), gz])])


def straight_path(x0: float, x1: float, y: float, speed_m_per_s: float, t_s) -> np.ndarray:
    """Robot poses (n, 3) driving from x0 to x1 at `speed_m_per_s` along y, at times t_s."""
    t = np.asarray(t_s, dtype=float)
    heading = 0.0 if x1 >= x0 else np.pi
    x = x0 + np.sign(x1 - x0) * np.minimum(speed_m_per_s * t, abs(x1 - x0))
    return np.column_stack([x, np.full(len(t), y), np.full(len(t), heading)])


@dataclass(frozen=True)
class CorridorScenario:
    """A synthetic corridor run (see :func:`corridor_scenario`).

    Attributes
    ----------
    tag_ids : tuple of str
    tag_positions_m : (M, 3)
    slot_time_s, slot_antenna : (S,)
    robot_poses : (S, 3)
        True robot pose at each slot.
    slot_poses : (S, 6)
        True antenna pose of each slot.
    candidates_m : (C, 3)
    length_m, width_m : float
    """

    tag_ids: tuple
    tag_positions_m: np.ndarray
    slot_time_s: np.ndarray
    slot_antenna: np.ndarray
    robot_poses: np.ndarray
    slot_poses: np.ndarray
    candidates_m: np.ndarray
    length_m: float
    width_m: float

    def observations(self, read, rssi_dbm, slot_poses=None) -> Observations:
        """Observations of outcomes (M, S) (every tag attempted in every slot)."""
        read = np.asarray(read, dtype=bool)
        return Observations(self.tag_ids, self.slot_time_s, self.slot_antenna,
                            self.slot_poses if slot_poses is None else slot_poses, read,
                            rssi_dbm, np.ones(read.shape, dtype=bool))

    def free_space_boxes(self, margin_m: float = 0.4) -> np.ndarray:
        """The corridor's free space for the robot centre, one box (1, 4)."""
        return np.array([[margin_m, margin_m, self.length_m - margin_m,
                          self.width_m - margin_m]])


def corridor_scenario(rng: np.random.Generator, *, length_m: float = 25.0,
                      width_m: float = 2.4, n_tags: int = 16, n_cycles: int = 400,
                      read_rate_hz: float = 4.0, antenna_mode: str = "round_robin",
                      tag_z_range_m=(0.2, 1.6), candidate_spacing_m: float = 0.05,
                      lane_y_m: float | None = None, mounts=None) -> CorridorScenario:
    """A corridor ``length_m`` x ``width_m`` with `n_tags` tags on its two long walls.

    The robot drives once along y = ``lane_y_m`` (default the centre line; off-centre
    breaks the mirror symmetry of the two antennas between the walls) from x = 0.5 m to
    length - 0.5 m in
    ``n_cycles`` read cycles; ``antenna_mode`` as :class:`pipeline.acquisition.ReaderConfig`
    (``"all"``: every antenna in every cycle). Tags are spread along the walls (alternate
    sides) at random heights; candidates are :func:`wall_candidates`.
    """
    from pipeline.robot.kinematics import antenna_poses, default_antennas, mounts_to_array

    mounts = mounts_to_array(default_antennas() if mounts is None else mounts)
    n_ant = len(mounts)
    k = np.arange(int(n_cycles))
    if antenna_mode == "round_robin":
        cycle, ant = k, k % n_ant
        t = k / read_rate_hz
    elif antenna_mode == "all":
        cycle = np.repeat(k, n_ant)
        ant = np.tile(np.arange(n_ant), len(k))
        t = cycle / read_rate_hz + ant / (read_rate_hz * n_ant)
    else:
        raise ValueError(f"antenna_mode must be 'round_robin' or 'all', got {antenna_mode!r}")
    speed = (length_m - 1.0) / max(t[-1], 1e-9)
    lane = width_m / 2 if lane_y_m is None else float(lane_y_m)
    robot = straight_path(0.5, length_m - 0.5, lane, speed, t)
    slot_poses = antenna_poses(robot, mounts)[np.arange(len(t)), ant]
    xs = (np.arange(n_tags) + 0.5) * length_m / n_tags + rng.uniform(-0.3, 0.3, n_tags)
    side = np.where(np.arange(n_tags) % 2 == 0, 0.005, width_m - 0.005)
    zs = rng.uniform(tag_z_range_m[0], tag_z_range_m[1], n_tags)
    tags = np.column_stack([xs, side, zs])
    cand = wall_candidates(length_m, width_m, candidate_spacing_m, tag_z_range_m)
    ids = tuple(f"E{i + 1:02d}" for i in range(n_tags))
    return CorridorScenario(ids, tags, t, ant, robot, slot_poses, cand, float(length_m),
                            float(width_m))


def max_free_space_range_m(budget, pattern_peak_dbi: float = 8.0,
                           tag_gain_dbi: float = 2.15) -> float:
    """Boresight free-space read range of :func:`free_space_gain_db` under `budget` [m]."""
    budget_db = pattern_peak_dbi + tag_gain_dbi - budget.min_gain_db()
    return float(wavelength_m(budget.frequency_hz) / (4 * np.pi) * 10 ** (budget_db / 20))
