"""Monte Carlo Localization on laser scans (particle filter).

Thrun, Burgard & Fox, *Probabilistic Robotics* (2005):
- motion: ``sample_motion_model_odometry`` (Table 5.6), see :mod:`pipeline.robot.odometry`;
- measurement: likelihood field (sec. 6.4, Table 6.3) on a subsample of the beams,
  ``p(z_k) = z_hit N(dist_k; 0, sigma_hit^2) + z_rand / z_max``, max-range beams skipped;
- resampling: low-variance (systematic) resampler (Table 4.4), only when the effective
  sample size ``N_eff = 1 / sum w_i^2`` drops below a fraction of N;
- recovery: Augmented MCL (Table 8.3): short- and long-term averages of the measurement
  likelihood, ``w_fast`` and ``w_slow``; at each resampling a fraction
  ``max(0, 1 - w_fast / w_slow)`` of particles is drawn from a proposal instead of
  the posterior. The proposal is a *mixture*: in tracking mode a wide Gaussian around
  the current estimate (poses consistent with the recent scans), in global mode
  uniform over free space. This plays the role of the dual sampling of Mixture-MCL
  (Thrun et al. 2001) at a fraction of its cost; it is not the full kd-tree dual sampler.

The likelihood average entering ``w_slow``/``w_fast`` is the per-beam geometric mean of
the particle-average likelihood (the raw product over 30 beams underflows and its
scale depends on how many beams are valid).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from scipy.special import logsumexp as _scipy_logsumexp

from pipeline.robot.kinematics import wrap_angle
from pipeline.robot.laser import LaserScanner
from pipeline.robot.occupancy import OccupancyMap
from pipeline.robot.odometry import OdometryNoise, odometry_deltas, sample_motion_model_odometry

__all__ = [
    "LocalizationResult",
    "MCLConfig",
    "MonteCarloLocalization",
    "PoseEstimate",
    "low_variance_resample",
    "pose_errors",
    "run_mcl",
]


@dataclass(frozen=True)
class MCLConfig:
    """Particle-filter settings.

    Attributes
    ----------
    n_particles : int
        Number of particles (the default is the study's ``localisation.n_particles``).
    motion_noise : OdometryNoise
        Motion-model noise the filter assumes (a bit larger than the robot's true noise).
    n_beams_used : int
        Beams of each scan used by the likelihood field (evenly spread).
    sigma_hit_m : float
        Standard deviation of the hit component [m] (laser noise, map discretisation and
        the map's own error: keep it >= the map's wall-offset std); the default is the
        study's ``localisation.sigma_hit_m``.
    z_hit, z_rand : float
        Mixture weights of the hit and random components.
    max_field_distance_m : float
        Cap on the likelihood-field distance [m].
    occupied_penalty : float
        Likelihood factor of a particle standing in an occupied cell.
    resample_threshold : float
        Resample when N_eff < resample_threshold * n_particles.
    update_min_trans_m, update_min_rot_rad : float
        Measurement updates happen only after the odometry moved this far (as ROS AMCL),
        so a standing robot does not collapse its particle set on repeated scans.
    augmented : bool
        Inject proposal particles (Augmented MCL) when w_fast < w_slow.
    alpha_slow, alpha_fast : float
        Decay rates of the long- and short-term likelihood averages (0 < slow << fast).
    injection_sigma_m, injection_sigma_rad : float
        Spread of the tracking-mode proposal around the current estimate [m, rad].
    initial_sigma_m, initial_sigma_rad : float
        Spread of the initial particles around the known start pose [m, rad].
    global_init : bool
        Start from particles uniform over free space (global localisation) and inject
        uniformly too; otherwise track from the given start pose.
    """

    n_particles: int = 500
    motion_noise: OdometryNoise = field(
        default_factory=lambda: OdometryNoise(0.05, 0.05, 0.05, 0.005)
    )
    n_beams_used: int = 30
    sigma_hit_m: float = 0.10
    z_hit: float = 0.95
    z_rand: float = 0.05
    max_field_distance_m: float = 1.0
    occupied_penalty: float = 1e-3
    resample_threshold: float = 0.5
    update_min_trans_m: float = 0.02
    update_min_rot_rad: float = 0.02
    augmented: bool = True
    alpha_slow: float = 0.001
    alpha_fast: float = 0.1
    injection_sigma_m: float = 0.3
    injection_sigma_rad: float = 0.1
    initial_sigma_m: float = 0.05
    initial_sigma_rad: float = 0.03
    global_init: bool = False

    def __post_init__(self) -> None:
        if int(self.n_particles) < 1:
            raise ValueError(f"MCLConfig: n_particles={self.n_particles} must be >= 1")
        if int(self.n_beams_used) < 1:
            raise ValueError(f"MCLConfig: n_beams_used={self.n_beams_used} must be >= 1")
        for k in ("sigma_hit_m", "max_field_distance_m"):
            if not getattr(self, k) > 0:
                raise ValueError(f"MCLConfig: {k}={getattr(self, k)} must be > 0")
        for k in ("z_hit", "z_rand", "resample_threshold", "occupied_penalty"):
            if not 0 <= getattr(self, k) <= 1:
                raise ValueError(f"MCLConfig: {k}={getattr(self, k)} must be in [0, 1]")
        if not 0 < self.alpha_slow < self.alpha_fast <= 1:
            raise ValueError(
                f"MCLConfig: need 0 < alpha_slow ({self.alpha_slow}) < alpha_fast "
                f"({self.alpha_fast}) <= 1"
            )


@dataclass(frozen=True)
class PoseEstimate:
    """The filter's pose estimate.

    Attributes
    ----------
    pose : numpy.ndarray
        Weighted mean pose (3,) [x_m, y_m, theta_rad] (circular mean heading).
    spread_m : float
        sqrt of the trace of the weighted position covariance [m].
    spread_heading_rad : float
        Circular standard deviation of the heading [rad].
    """

    pose: np.ndarray
    spread_m: float
    spread_heading_rad: float


def low_variance_resample(weights: np.ndarray, n: int, rng: np.random.Generator) -> np.ndarray:
    """Indices drawn by the low-variance (systematic) resampler (Thrun et al. 2005, Table 4.4).

    ``weights`` (m,) are normalised internally; returns (n,) int indices.
    """
    w = np.asarray(weights, dtype=float)
    c = np.cumsum(w / w.sum())
    c[-1] = 1.0
    u = rng.uniform(0.0, 1.0 / n) + np.arange(n) / n
    return np.searchsorted(c, u, side="right").clip(0, len(w) - 1)


class MonteCarloLocalization:
    """A particle filter localising a robot with odometry and a 2-D laser in a known map.

    Parameters
    ----------
    occupancy_map : OccupancyMap
        Map cut at the laser height (its ``boundary_distance_m`` is the likelihood field).
    scanner : LaserScanner
        The scanner model (beam angles, max range, mounting).
    config : MCLConfig, optional
    """

    def __init__(
        self, occupancy_map: OccupancyMap, scanner: LaserScanner, config: MCLConfig | None = None
    ) -> None:
        self.map = occupancy_map
        self.scanner = scanner
        self.config = MCLConfig() if config is None else config
        nb = min(int(self.config.n_beams_used), scanner.n_beams)
        self.beams = np.unique(np.round(np.linspace(0, scanner.n_beams - 1, nb)).astype(int))
        self.particles = np.zeros((0, 3))
        self.log_weights = np.zeros(0)
        self.w_slow = 0.0
        self.w_fast = 0.0
        self.n_resamples = 0
        self.n_injected = 0
        self._moved = np.zeros(2)
        self._fresh = np.zeros(0, dtype=bool)  # injected, not yet weighted by a scan

    # -- initialisation --------------------------------------------------------------
    def _uniform_free(self, n: int, rng: np.random.Generator) -> np.ndarray:
        cells = self.map.free_cell_centres()
        pick = cells[rng.integers(len(cells), size=n)]
        pick = pick + rng.uniform(-0.5, 0.5, pick.shape) * self.map.resolution_m
        return np.column_stack([pick, rng.uniform(-np.pi, np.pi, n)])

    def initialise(self, rng: np.random.Generator, pose: np.ndarray | None = None) -> None:
        """Draw the initial particle set: Gaussian around ``pose`` or uniform (global)."""
        cfg, n = self.config, int(self.config.n_particles)
        if cfg.global_init or pose is None:
            self.particles = self._uniform_free(n, rng)
        else:
            p = np.asarray(pose, dtype=float)
            self.particles = np.column_stack(
                [
                    p[0] + cfg.initial_sigma_m * rng.standard_normal(n),
                    p[1] + cfg.initial_sigma_m * rng.standard_normal(n),
                    wrap_angle(p[2] + cfg.initial_sigma_rad * rng.standard_normal(n)),
                ]
            )
        self.log_weights = np.full(n, -np.log(n))
        self._fresh = np.zeros(n, dtype=bool)
        self.w_slow = self.w_fast = 0.0
        self._moved = np.array([np.inf, np.inf])  # first scan is always used

    # -- filter steps ----------------------------------------------------------------
    def predict(self, u_prev: np.ndarray, u_now: np.ndarray, rng: np.random.Generator) -> None:
        """Propagate the particles with the odometry motion model (Table 5.6)."""
        self.particles = sample_motion_model_odometry(
            u_prev, u_now, self.particles, self.config.motion_noise, rng
        )
        d = odometry_deltas(u_prev, u_now)
        self._moved = self._moved + [float(d.trans_m), abs(float(d.rot1_rad + d.rot2_rad))]

    def _valid_beams(self, ranges: np.ndarray):
        r = np.asarray(ranges, dtype=float)[self.beams]
        valid = r < self.scanner.max_range_m
        return self.beams[valid], r[valid]

    def log_likelihood(self, ranges: np.ndarray) -> np.ndarray:
        """Log measurement likelihood (n_particles,) of one scan (n_beams,) (Table 6.3).

        Sum over the used, non-max-range beams of
        ``log(z_hit N(dist; 0, sigma_hit^2) + z_rand / z_max)``, plus
        ``log(occupied_penalty)`` for particles standing in occupied cells.
        """
        cfg = self.config
        beams, r = self._valid_beams(ranges)
        ll = np.zeros(len(self.particles))
        if len(r):
            ends = self.scanner.endpoints(self.particles, r[None, :], beams)  # (N, k, 2)
            dist = self.map.surface_distance_m(ends, cfg.max_field_distance_m)
            p = (
                cfg.z_hit
                * np.exp(-0.5 * (dist / cfg.sigma_hit_m) ** 2)
                / (np.sqrt(2 * np.pi) * cfg.sigma_hit_m)
                + cfg.z_rand / self.scanner.max_range_m
            )
            ll = np.log(p).sum(axis=1)
        occ = self.map.is_occupied(self.particles[:, :2])
        return ll + np.where(occ, np.log(max(cfg.occupied_penalty, 1e-300)), 0.0)

    def update(self, ranges: np.ndarray, rng: np.random.Generator) -> bool:
        """Weight by one scan (if moved enough since the last update), maybe resample.

        Returns True when the scan was used.
        """
        cfg = self.config
        if self._moved[0] < cfg.update_min_trans_m and self._moved[1] < cfg.update_min_rot_rad:
            return False
        self._moved = np.zeros(2)
        ll = self.log_likelihood(ranges)
        n_valid = len(self._valid_beams(ranges)[1])
        n = len(self.particles)
        # Augmented MCL (Table 8.3) on the per-beam geometric mean of the average likelihood
        lw = self.log_weights + ll
        if n_valid:
            w_avg = float(np.exp((_logsumexp(self.log_weights + ll)) / n_valid))
            if self.w_slow == 0.0:
                self.w_slow = self.w_fast = w_avg
            else:
                self.w_slow += cfg.alpha_slow * (w_avg - self.w_slow)
                self.w_fast += cfg.alpha_fast * (w_avg - self.w_fast)
        self.log_weights = lw - _logsumexp(lw)
        self._fresh[:] = False
        w = np.exp(self.log_weights)
        n_eff = 1.0 / np.sum(w**2)
        if n_eff < cfg.resample_threshold * n:
            self._resample(w, rng)
        return True

    def _resample(self, w: np.ndarray, rng: np.random.Generator) -> None:
        cfg, n = self.config, len(self.particles)
        p_inject = 0.0
        if cfg.augmented and self.w_slow > 0:
            p_inject = max(0.0, 1.0 - self.w_fast / self.w_slow)
        n_inj = int(rng.binomial(n, p_inject)) if p_inject > 0 else 0
        est = self.estimate().pose
        idx = low_variance_resample(w, n - n_inj, rng)
        new = self.particles[idx]
        if n_inj:
            if cfg.global_init:
                inj = self._uniform_free(n_inj, rng)
            else:
                inj = np.column_stack(
                    [
                        est[0] + cfg.injection_sigma_m * rng.standard_normal(n_inj),
                        est[1] + cfg.injection_sigma_m * rng.standard_normal(n_inj),
                        wrap_angle(est[2] + cfg.injection_sigma_rad * rng.standard_normal(n_inj)),
                    ]
                )
            new = np.concatenate([new, inj])
        self._fresh = np.arange(n) >= n - n_inj
        self.particles = new
        self.log_weights = np.full(n, -np.log(n))
        self.n_resamples += 1
        self.n_injected += n_inj

    def estimate(self) -> PoseEstimate:
        """Weighted mean pose and spread of the particle set.

        Particles injected at the last resampling enter only once a scan has weighted
        them (otherwise their uniform weight would drag the mean towards the proposal).
        """
        lw = (
            np.where(self._fresh, -np.inf, self.log_weights)
            if (self._fresh.any() and not self._fresh.all())
            else self.log_weights
        )
        w = np.exp(lw - _logsumexp(lw))
        xy = w @ self.particles[:, :2]
        c, s = w @ np.cos(self.particles[:, 2]), w @ np.sin(self.particles[:, 2])
        var = w @ np.sum((self.particles[:, :2] - xy) ** 2, axis=1)
        r = min(1.0, float(np.hypot(c, s)))
        return PoseEstimate(
            np.array([xy[0], xy[1], np.arctan2(s, c)]),
            float(np.sqrt(var)),
            float(np.sqrt(-2.0 * np.log(max(r, 1e-300)))),
        )


@dataclass(frozen=True)
class LocalizationResult:
    """True, odometry and MCL poses of a run, with errors.

    Attributes
    ----------
    t_s : numpy.ndarray
        Time stamps (n,) [s].
    true_poses : numpy.ndarray or None
        Ground-truth poses (n, 3) [x_m, y_m, theta_rad] (None when unknown).
    odometry_poses : numpy.ndarray
        Dead-reckoning poses (n, 3).
    estimated_poses : numpy.ndarray
        MCL estimates (n, 3): what a real robot would record.
    spread_m : numpy.ndarray
        Particle position spread (n,) [m].
    spread_heading_rad : numpy.ndarray
        Particle heading spread (n,) [rad].
    position_error_m, heading_error_rad : numpy.ndarray or None
        |estimate - truth| per step (n,) [m], |wrapped heading error| [rad].
    odometry_position_error_m, odometry_heading_error_rad : numpy.ndarray or None
        The same for odometry alone.
    n_updates : int
        Scans used in measurement updates.
    n_resamples : int
        Resampling steps.
    n_injected : int
        Particles injected by Augmented MCL over the run.
    """

    t_s: np.ndarray
    true_poses: np.ndarray | None
    odometry_poses: np.ndarray
    estimated_poses: np.ndarray
    spread_m: np.ndarray
    spread_heading_rad: np.ndarray
    position_error_m: np.ndarray | None
    heading_error_rad: np.ndarray | None
    odometry_position_error_m: np.ndarray | None
    odometry_heading_error_rad: np.ndarray | None
    n_updates: int
    n_resamples: int
    n_injected: int

    def summary(self) -> dict:
        """JSON-able means/maxima of the errors (m and deg) and filter counters."""
        out = {
            "n_poses": int(len(self.t_s)),
            "n_updates": self.n_updates,
            "n_resamples": self.n_resamples,
            "n_injected": self.n_injected,
            "mean_spread_m": float(np.mean(self.spread_m)),
        }
        if self.position_error_m is not None:
            for tag, pe, he in (
                ("mcl", self.position_error_m, self.heading_error_rad),
                ("odometry", self.odometry_position_error_m, self.odometry_heading_error_rad),
            ):
                out[f"{tag}_mean_position_error_m"] = float(np.mean(pe))
                out[f"{tag}_max_position_error_m"] = float(np.max(pe))
                out[f"{tag}_final_position_error_m"] = float(pe[-1])
                out[f"{tag}_mean_heading_error_deg"] = float(np.rad2deg(np.mean(he)))
                out[f"{tag}_max_heading_error_deg"] = float(np.rad2deg(np.max(he)))
        return out


def pose_errors(estimate: np.ndarray, truth: np.ndarray):
    """Position error (n,) [m] and absolute wrapped heading error (n,) [rad]."""
    e = np.asarray(estimate, float)
    t = np.asarray(truth, float)
    return (np.linalg.norm(e[:, :2] - t[:, :2], axis=1), np.abs(wrap_angle(e[:, 2] - t[:, 2])))


def run_mcl(
    occupancy_map: OccupancyMap,
    scanner: LaserScanner,
    odometry: np.ndarray,
    scans: np.ndarray,
    initial_pose: np.ndarray | None,
    rng: np.random.Generator,
    n_particles: int | None = None,
    config: MCLConfig | None = None,
    true_poses: np.ndarray | None = None,
    t_s: np.ndarray | None = None,
) -> LocalizationResult:
    """Run MCL over a recorded sequence of odometry readings and scans.

    Parameters
    ----------
    occupancy_map : OccupancyMap
        Map at the laser height.
    scanner : LaserScanner
    odometry : numpy.ndarray
        Odometry readings (n, 3) [x_m, y_m, theta_rad].
    scans : numpy.ndarray
        Ranges (n, n_beams) [m], scan i taken at pose i.
    initial_pose : numpy.ndarray or None
        Known start pose (3,) for tracking; None (or ``config.global_init``) for global.
    rng : numpy.random.Generator
    n_particles : int, optional
        Overrides ``config.n_particles``.
    config : MCLConfig, optional
    true_poses : numpy.ndarray, optional
        Ground truth (n, 3); when given, per-step errors are filled in.
    t_s : numpy.ndarray, optional
        Time stamps (n,); default 0..n-1.

    Returns
    -------
    LocalizationResult
    """
    cfg = MCLConfig() if config is None else config
    if n_particles is not None:
        cfg = MCLConfig(**{**cfg.__dict__, "n_particles": int(n_particles)})
    odo = np.atleast_2d(np.asarray(odometry, dtype=float))
    z = np.atleast_2d(np.asarray(scans, dtype=float))
    if len(odo) != len(z):
        raise ValueError(f"run_mcl: odometry has {len(odo)} poses but scans has {len(z)}")
    if z.shape[1] != scanner.n_beams:
        raise ValueError(f"run_mcl: scans have {z.shape[1]} beams, scanner has {scanner.n_beams}")
    mcl = MonteCarloLocalization(occupancy_map, scanner, cfg)
    mcl.initialise(rng, None if initial_pose is None else np.asarray(initial_pose, float))
    n = len(odo)
    est = np.empty((n, 3))
    spread = np.empty(n)
    spread_h = np.empty(n)
    n_upd = 0
    for i in range(n):
        if i:
            mcl.predict(odo[i - 1], odo[i], rng)
        n_upd += mcl.update(z[i], rng)
        e = mcl.estimate()
        est[i], spread[i], spread_h[i] = e.pose, e.spread_m, e.spread_heading_rad
    t = np.arange(n, dtype=float) if t_s is None else np.asarray(t_s, dtype=float)
    pe = he = ope = ohe = None
    if true_poses is not None:
        tp = np.asarray(true_poses, dtype=float)
        pe, he = pose_errors(est, tp)
        ope, ohe = pose_errors(odo, tp)
    return LocalizationResult(
        t,
        None if true_poses is None else np.asarray(true_poses, float),
        odo,
        est,
        spread,
        spread_h,
        pe,
        he,
        ope,
        ohe,
        n_upd,
        mcl.n_resamples,
        mcl.n_injected,
    )


def _logsumexp(a: np.ndarray) -> float:
    """``scipy.special.logsumexp`` of a 1-D float64 array, the same number bit for bit.

    SciPy's own costs ~0.45 ms a call on the filter's weights (array-API dispatch and
    checks), about a quarter of the laser filter's time in the tour stage; this repeats
    its arithmetic (SciPy >= 1.15: the maxima taken out of the sum, ``log1p``) in plain
    NumPy (so SciPy >= 1.15 is required). An empty array, another shape or a non-finite
    maximum (every weight -inf, or an inf / NaN) goes to SciPy.
    """
    a = np.asarray(a, dtype=np.float64)
    if a.ndim != 1 or a.size == 0:
        return float(_scipy_logsumexp(a))
    a_max = np.max(a, keepdims=True)
    if not np.isfinite(a_max[0]):
        return float(_scipy_logsumexp(a))
    mask = a == a_max
    m = np.sum(mask.astype(np.float64), keepdims=True)
    s = np.sum(np.exp(np.where(mask, -np.inf, a) - a_max), keepdims=True)
    s = np.where(s == 0, s, s / m)
    return float((np.log1p(s) + np.log(m) + a_max)[0])
