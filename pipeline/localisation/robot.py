"""RFID-only robot localisation: a particle filter on odometry and tag reads (no laser).

Thrun, Burgard & Fox, *Probabilistic Robotics* (2005), as the project's laser MCL
(:mod:`pipeline.robot.mcl`), with the laser replaced by the reads of tags at known
positions (Haehnel et al., ICRA 2004; Joho et al., ICRA 2009):

- state: robot pose (x, y, theta); one filter step per attempt slot (one antenna, one
  read cycle): odometry interpolated to the slot time moves the particles
  (:func:`pipeline.robot.sample_motion_model_odometry`, Table 5.6), then the slot's
  outcomes of every mapped tag weight them, ``log w += sum_tags log p(z | d, alpha)``
  with the antenna pose composed from the particle and the mount
  (:class:`~pipeline.localisation.ModelLikelihood` of the chosen sensor model);
- particles outside the free space are penalised (``outside_log_penalty`` per step);
- resampling: low-variance, when N_eff < ``resample_threshold`` N, followed by a small
  jitter (``roughening_m``, ``roughening_rad``) so that a standing robot, whose odometry
  adds no noise, keeps a diverse particle set;
- recovery: Augmented MCL (Table 8.3): EMAs ``w_slow``, ``w_fast`` of the per-tag
  geometric mean of the average measurement likelihood; at each resampling a fraction
  ``min(max_injection, 1 - w_fast / w_slow)`` of the particles is drawn uniformly over
  the free space (random-particle injection), so the filter recovers from a kidnapping
  and from a wrong global start;
- global initialisation: particles uniform over the free space, heading uniform.

The free space is given as axis-aligned boxes ``(k, 4) [x_min, y_min, x_max, y_max]``,
as an object with ``sample(n, rng) -> (n, 2)`` and ``contains(xy) -> bool``, or as a
:class:`pipeline.robot.OccupancyMap` (its free cells; pass the robot's collision map so
particles keep the robot's clearance).

Metrics (:func:`filter_metrics`): the filter has *converged* at the first step from
which the position error stays below ``threshold_m`` (0.5 m) for ``n_consecutive`` (8,
2 s at 4 slots per second) consecutive steps; ``converge_s`` is the time from the start
to that step (NaN: never, ``converged`` False). After a kidnapping at ``kidnap_time_s``
the same rule from that time gives ``recover_s`` (NaN: never). ``median_m`` and
``p90_m`` are over ALL steps of the run, whether or not it converged, so that a median
means one thing in every run; ``median_before_kidnap_m`` and ``median_after_kidnap_m``
split the steps at the kidnapping. A run that never converges counts as such in every
statistic: its errors are in the medians, and it is a run that did not converge in the
study's share of converged runs (:mod:`pipeline.evaluation.headline`).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from pipeline.acquisition.track import interpolate_poses
from pipeline.localisation.likelihood import ModelLikelihood
from pipeline.localisation.observations import Observations
from pipeline.localisation.tags import as_tag_map
from pipeline.robot.kinematics import antenna_poses, mounts_to_array, wrap_angle
from pipeline.robot.mcl import low_variance_resample
from pipeline.robot.odometry import OdometryNoise, sample_motion_model_odometry

__all__ = [
    "BoxFreeSpace",
    "RfidMCLConfig",
    "RfidMCLResult",
    "RfidParticleFilter",
    "as_free_space",
    "filter_metrics",
    "kidnap_index",
    "run_rfid_mcl",
]


@dataclass(frozen=True)
class RfidMCLConfig:
    """Settings of the RFID particle filter (module doc).

    Attributes
    ----------
    n_particles : int
    motion_noise : OdometryNoise
        Noise the filter assumes (larger than the robot's, as the laser MCL's default).
    resample_threshold : float
        Resample when N_eff < resample_threshold * n_particles.
    augmented : bool
        Random-particle injection (Augmented MCL).
    alpha_slow, alpha_fast : float
        EMA rates of the likelihood averages (0 < slow < fast <= 1), per slot.
    max_injection : float
        Cap on the injected fraction at one resampling.
    roughening_m, roughening_rad : float
        Std of the jitter after resampling [m, rad].
    outside_log_penalty : float
        Log-weight added per step to particles outside the free space (<= 0).
    likelihood_power : float
        Exponent on the measurement likelihood (1: Bayes; < 1 tempers correlated errors).
    """

    n_particles: int = 2000
    motion_noise: OdometryNoise = field(
        default_factory=lambda: OdometryNoise(0.05, 0.05, 0.05, 0.005))
    resample_threshold: float = 0.5
    augmented: bool = True
    alpha_slow: float = 0.02
    alpha_fast: float = 0.3
    max_injection: float = 0.2
    roughening_m: float = 0.02
    roughening_rad: float = 0.01
    outside_log_penalty: float = -10.0
    likelihood_power: float = 1.0

    def __post_init__(self) -> None:
        if int(self.n_particles) < 1:
            raise ValueError(f"RfidMCLConfig: n_particles={self.n_particles} must be >= 1")
        if not 0 < self.alpha_slow < self.alpha_fast <= 1:
            raise ValueError(f"RfidMCLConfig: need 0 < alpha_slow ({self.alpha_slow}) < "
                             f"alpha_fast ({self.alpha_fast}) <= 1")
        for k in ("resample_threshold", "max_injection"):
            if not 0 <= getattr(self, k) <= 1:
                raise ValueError(f"RfidMCLConfig: {k}={getattr(self, k)} must be in [0, 1]")
        for k in ("roughening_m", "roughening_rad"):
            if not getattr(self, k) >= 0:
                raise ValueError(f"RfidMCLConfig: {k} must be >= 0")
        if not self.outside_log_penalty <= 0:
            raise ValueError("RfidMCLConfig: outside_log_penalty must be <= 0")
        if not self.likelihood_power > 0:
            raise ValueError("RfidMCLConfig: likelihood_power must be > 0")


class BoxFreeSpace:
    """Free space as a union of axis-aligned boxes ``(k, 4) [x_min, y_min, x_max, y_max]``."""

    def __init__(self, boxes) -> None:
        b = np.asarray(boxes, dtype=np.float64).reshape(-1, 4)
        if len(b) == 0 or not np.all(np.isfinite(b)) or np.any(b[:, 2:] <= b[:, :2]):
            raise ValueError("free-space boxes must be finite [x_min, y_min, x_max, y_max] "
                             "with x_min < x_max and y_min < y_max")
        self.boxes = b
        area = np.prod(b[:, 2:] - b[:, :2], axis=1)
        self._p = area / area.sum()

    def sample(self, n: int, rng: np.random.Generator) -> np.ndarray:
        k = rng.choice(len(self.boxes), size=int(n), p=self._p)
        b = self.boxes[k]
        return b[:, :2] + rng.random((int(n), 2)) * (b[:, 2:] - b[:, :2])

    def contains(self, xy) -> np.ndarray:
        p = np.asarray(xy, dtype=np.float64)
        b = self.boxes
        inside = ((p[..., None, 0] >= b[:, 0]) & (p[..., None, 0] <= b[:, 2])
                  & (p[..., None, 1] >= b[:, 1]) & (p[..., None, 1] <= b[:, 3]))
        return inside.any(axis=-1)


class _OccupancyFreeSpace:
    """Free cells of an OccupancyMap with at least ``min_clearance_m`` to any obstacle."""

    def __init__(self, occ, min_clearance_m: float = 0.0) -> None:
        self.occ = occ
        self.min_clearance_m = float(min_clearance_m)
        cells = occ.free_cell_centres()
        if self.min_clearance_m > 0 and len(cells):
            cells = cells[occ.clearance_m(cells) >= self.min_clearance_m]
        if len(cells) == 0:
            raise ValueError(f"the occupancy map has no free cell with clearance >= "
                             f"{self.min_clearance_m} m")
        self.cells = cells

    def sample(self, n: int, rng: np.random.Generator) -> np.ndarray:
        pick = self.cells[rng.integers(len(self.cells), size=int(n))]
        return pick + rng.uniform(-0.5, 0.5, pick.shape) * self.occ.resolution_m

    def contains(self, xy) -> np.ndarray:
        p = np.asarray(xy, dtype=np.float64)
        if self.min_clearance_m > 0:
            return self.occ.clearance_m(p) >= self.min_clearance_m
        return ~self.occ.is_occupied(p)


def as_free_space(free_space, min_clearance_m: float = 0.0):
    """A free-space object (``sample``, ``contains``) from boxes, an OccupancyMap or itself.

    For an OccupancyMap (e.g. :func:`pipeline.robot.collision_map`), only cells with at
    least `min_clearance_m` to an obstacle count (e.g. half the robot's width).
    """
    if hasattr(free_space, "sample") and hasattr(free_space, "contains"):
        return free_space
    if hasattr(free_space, "free_cell_centres") and hasattr(free_space, "is_occupied"):
        return _OccupancyFreeSpace(free_space, min_clearance_m)
    return BoxFreeSpace(free_space)


class RfidParticleFilter:
    """Particle filter over (x, y, theta) with RFID reads of mapped tags (module doc).

    Parameters
    ----------
    likelihood : ModelLikelihood
        The sensor model's read likelihood.
    tag_positions_m : numpy.ndarray, shape (M, 3)
        Known tag positions, in the column order of the outcomes given to :meth:`update`.
    mounts : list of AntennaMount or array (n_antennas, 4|5)
        Antenna mounts on the robot.
    free_space : boxes, OccupancyMap or object with sample/contains
    config : RfidMCLConfig, optional
    """

    def __init__(self, likelihood: ModelLikelihood, tag_positions_m, mounts, free_space,
                 config: RfidMCLConfig | None = None) -> None:
        if not (isinstance(likelihood, ModelLikelihood) or hasattr(likelihood, "terms_for_particles")):
            raise ValueError("likelihood must be a ModelLikelihood or a particle likelihood "
                             f"(terms_for_particles, e.g. the oracle's), got {type(likelihood).__name__}")
        self.likelihood = likelihood
        self.tags = np.asarray(tag_positions_m, dtype=np.float64).reshape(-1, 3)
        if len(self.tags) == 0:
            raise ValueError("the tag map is empty")
        self.mounts = mounts_to_array(mounts)
        self.free = as_free_space(free_space)
        self.config = RfidMCLConfig() if config is None else config
        self.particles = np.zeros((0, 3))
        self.log_weights = np.zeros(0)
        self.w_slow = self.w_fast = 0.0
        self.n_resamples = self.n_injected = 0
        self._fresh = np.zeros(0, dtype=bool)

    def _uniform(self, n: int, rng: np.random.Generator) -> np.ndarray:
        xy = self.free.sample(n, rng)
        return np.column_stack([xy, rng.uniform(-np.pi, np.pi, int(n))])

    def initialise(self, rng: np.random.Generator, pose=None, sigma_m: float = 0.1,
                   sigma_rad: float = 0.05) -> None:
        """Particles uniform over the free space (``pose`` None: global), else Gaussian."""
        n = int(self.config.n_particles)
        if pose is None:
            self.particles = self._uniform(n, rng)
        else:
            p = np.asarray(pose, dtype=np.float64)
            self.particles = np.column_stack([
                p[0] + sigma_m * rng.standard_normal(n), p[1] + sigma_m * rng.standard_normal(n),
                wrap_angle(p[2] + sigma_rad * rng.standard_normal(n))])
        self.log_weights = np.full(n, -np.log(n))
        self._fresh = np.zeros(n, dtype=bool)
        self.w_slow = self.w_fast = 0.0

    def predict(self, u_prev, u_now, rng: np.random.Generator) -> None:
        """Move the particles by the odometry step u_prev -> u_now (Table 5.6)."""
        self.particles = sample_motion_model_odometry(u_prev, u_now, self.particles,
                                                      self.config.motion_noise, rng)

    def log_likelihood(self, antenna: int, read, rssi_dbm, attempted=None) -> np.ndarray:
        """Log-likelihood (N,) of one slot's outcomes (M,) seen by `antenna`.

        Tags with ``attempted`` False (not in that slot's inventory) are skipped.
        """
        read = np.asarray(read, dtype=bool)
        rssi = np.asarray(rssi_dbm, dtype=np.float64)
        tags = self.tags
        keep = None
        if attempted is not None:
            keep = np.asarray(attempted, dtype=bool)
            tags, read, rssi = tags[keep], read[keep], rssi[keep]
        if len(tags) == 0:
            return np.zeros(len(self.particles))
        if hasattr(self.likelihood, "terms_for_particles"):  # gains tabulated per robot pose
            terms = self.likelihood.terms_for_particles(self.particles, int(antenna), keep)
            return terms.loglik(read[None, :], rssi[None, :]).sum(axis=1)
        ant = antenna_poses(self.particles, self.mounts[[int(antenna)]])[:, 0, :]  # (N, 6)
        return self.likelihood.pose_loglik(ant, tags, read, rssi)

    def update(self, antenna: int, read, rssi_dbm, rng: np.random.Generator,
               attempted=None) -> None:
        """Weight by one slot's outcomes of the mapped tags (columns of the tag map)."""
        cfg = self.config
        ll = self.log_likelihood(antenna, read, rssi_dbm, attempted)
        m_eff = int(np.size(read) if attempted is None else np.sum(attempted))
        ll = cfg.likelihood_power * ll
        outside = ~self.free.contains(self.particles[:, :2])
        ll = ll + np.where(outside, cfg.outside_log_penalty, 0.0)
        if m_eff:
            w_avg = float(np.exp(_logsumexp(self.log_weights + ll) / m_eff))
            if self.w_slow == 0.0:
                self.w_slow = self.w_fast = w_avg
            else:
                self.w_slow += cfg.alpha_slow * (w_avg - self.w_slow)
                self.w_fast += cfg.alpha_fast * (w_avg - self.w_fast)
        lw = self.log_weights + ll
        self.log_weights = lw - _logsumexp(lw)
        self._fresh[:] = False
        w = np.exp(self.log_weights)
        if 1.0 / np.sum(w * w) < cfg.resample_threshold * len(w):
            self._resample(w, rng)

    def _resample(self, w: np.ndarray, rng: np.random.Generator) -> None:
        cfg, n = self.config, len(self.particles)
        p_inj = 0.0
        if cfg.augmented and self.w_slow > 0:
            p_inj = min(cfg.max_injection, max(0.0, 1.0 - self.w_fast / self.w_slow))
        n_inj = int(rng.binomial(n, p_inj)) if p_inj > 0 else 0
        new = self.particles[low_variance_resample(w, n - n_inj, rng)]
        if cfg.roughening_m > 0 or cfg.roughening_rad > 0:
            k = len(new)
            new = np.column_stack([new[:, 0] + cfg.roughening_m * rng.standard_normal(k),
                                   new[:, 1] + cfg.roughening_m * rng.standard_normal(k),
                                   wrap_angle(new[:, 2] + cfg.roughening_rad
                                              * rng.standard_normal(k))])
        if n_inj:
            new = np.concatenate([new, self._uniform(n_inj, rng)])
        self._fresh = np.arange(n) >= n - n_inj
        self.particles = new
        self.log_weights = np.full(n, -np.log(n))
        self.n_resamples += 1
        self.n_injected += n_inj

    def estimate(self) -> tuple[np.ndarray, float]:
        """Weighted mean pose (3,) (circular heading) and position spread [m].

        Particles injected at the last resampling count only once weighted by a slot.
        """
        lw = self.log_weights
        if self._fresh.any() and not self._fresh.all():
            lw = np.where(self._fresh, -np.inf, lw)
        w = np.exp(lw - _logsumexp(lw))
        xy = w @ self.particles[:, :2]
        c, s = w @ np.cos(self.particles[:, 2]), w @ np.sin(self.particles[:, 2])
        var = w @ np.sum((self.particles[:, :2] - xy) ** 2, axis=1)
        return np.array([xy[0], xy[1], np.arctan2(s, c)]), float(np.sqrt(max(var, 0.0)))


@dataclass(frozen=True)
class RfidMCLResult:
    """Estimates of an RFID particle-filter run, one per attempt slot.

    Attributes
    ----------
    t_s : numpy.ndarray (S,)
    est_poses : numpy.ndarray (S, 3)
    spread_m : numpy.ndarray (S,)
    n_resamples, n_injected : int
    """

    t_s: np.ndarray
    est_poses: np.ndarray
    spread_m: np.ndarray
    n_resamples: int
    n_injected: int


def _slot_outcomes(obs: Observations, tag_map):
    ids, pos = as_tag_map(tag_map)
    if not ids:
        raise ValueError("the tag map is empty")
    known = set(obs.tag_ids)
    unknown = [t for t in ids if t not in known]
    if unknown:
        raise ValueError(f"tag map id(s) {unknown} are unknown to the read log (it has "
                         f"{list(obs.tag_ids)[:20]})")
    sub = obs.select(ids)
    return pos, sub.read.T, sub.rssi_dbm.T, sub.attempted.T


def run_rfid_mcl(likelihood: ModelLikelihood, obs: Observations, tag_map, odometry,
                 odometry_t_s, mounts, free_space, rng: np.random.Generator, *,
                 config: RfidMCLConfig | None = None, initial_pose=None,
                 kidnap_time_s: float | None = None, kidnap_offset=None) -> RfidMCLResult:
    """Run the RFID particle filter over the slots of `obs`.

    Parameters
    ----------
    likelihood : ModelLikelihood
    obs : Observations
        The tour's outcomes; the slot poses are NOT used (the filter estimates them), only
        slot times, antennas and outcomes. Tags of the log absent from the map are ignored.
    tag_map : TagSet, mapping id -> (x, y, z) or (ids, positions)
        Known tag positions; an id the log lacks raises ValueError naming it.
    odometry : array_like (n, 3)
        Odometry readings [x, y, theta] at `odometry_t_s` (n,) [s], interpolated to the
        slot times (slots outside the odometry's time span raise ValueError).
    mounts : list of AntennaMount or array (n_antennas, 4|5)
    free_space : boxes (k, 4), OccupancyMap or object with sample/contains
    rng : numpy.random.Generator
    config : RfidMCLConfig, optional
    initial_pose : array_like (3,), optional
        Known start (tracking); default None: global initialisation.
    kidnap_time_s, kidnap_offset : optional
        Kidnap the *filter*: at the first slot at or after `kidnap_time_s`, every
        particle is moved by ``kidnap_offset`` (dx, dy, dtheta) in the world frame
        (before that slot's update). From the filter's side this equals teleporting the
        robot without odometry, and needs no new reads.

    Returns
    -------
    RfidMCLResult
    """
    if obs.n_slots == 0:
        raise ValueError("the read log has no attempt slots")
    pos, read, rssi, att = _slot_outcomes(obs, tag_map)
    odo = np.asarray(odometry, dtype=np.float64).reshape(-1, 3)
    to = np.asarray(odometry_t_s, dtype=np.float64).reshape(-1)
    if len(to) != len(odo) or len(to) < 2 or np.any(np.diff(to) <= 0):
        raise ValueError("odometry_t_s must be increasing with one time per odometry pose (>= 2)")
    t = obs.slot_time_s
    if t[0] < to[0] - 1e-9 or t[-1] > to[-1] + 1e-9:
        raise ValueError(f"slot times [{t[0]}, {t[-1]}] s outside the odometry's "
                         f"[{to[0]}, {to[-1]}] s")
    u = interpolate_poses(to, odo, np.clip(t, to[0], to[-1]))
    if kidnap_time_s is not None:
        off = np.asarray(kidnap_offset, dtype=np.float64).reshape(3)
    pf = RfidParticleFilter(likelihood, pos, mounts, free_space, config)
    pf.initialise(rng, initial_pose)
    n = len(t)
    est, spread = np.empty((n, 3)), np.empty(n)
    kidnapped = kidnap_time_s is None
    for i in range(n):
        if i:
            pf.predict(u[i - 1], u[i], rng)
        if not kidnapped and t[i] >= kidnap_time_s:
            p = pf.particles
            pf.particles = np.column_stack([p[:, 0] + off[0], p[:, 1] + off[1],
                                            wrap_angle(p[:, 2] + off[2])])
            kidnapped = True
        pf.update(int(obs.slot_antenna[i]), read[i], rssi[i], rng, attempted=att[i])
        est[i], spread[i] = pf.estimate()
    return RfidMCLResult(t.copy(), est, spread, pf.n_resamples, pf.n_injected)


def _logsumexp(a: np.ndarray) -> float:
    """``log(sum(exp(a)))`` of a 1-D array, shifted by its maximum (-inf for all -inf).

    scipy.special.logsumexp costs ~140 us a call on the filter's 2,000 weights (its
    argument checks), this ~20 us; the filter calls it three times a slot.
    """
    m = np.max(a)
    if not np.isfinite(m):
        return float(m)
    return float(m + np.log(np.sum(np.exp(a - m))))


def _first_stable(ok: np.ndarray, start: int, n_consecutive: int) -> int | None:
    """First index i >= start with ok[i : i + n_consecutive] all True (None if none)."""
    run = 0
    for i in range(start, len(ok)):
        run = run + 1 if ok[i] else 0
        if run >= n_consecutive:
            return i - n_consecutive + 1
    return None


def filter_metrics(t_s, est_poses, true_poses, *, threshold_m: float = 0.5,
                   n_consecutive: int = 8, kidnap_time_s: float | None = None) -> dict:
    """Convergence and recovery times and the error over all steps (module doc).

    Returns
    -------
    dict
        ``median_m``, ``p90_m``, ``heading_median_deg`` (all steps), ``converge_s``,
        ``converged`` (bool) and, with `kidnap_time_s`, ``recover_s`` (NaN if it never
        recovered), ``median_before_kidnap_m`` and ``median_after_kidnap_m`` (NaN where
        that part has no step).
    """
    t = np.asarray(t_s, dtype=np.float64).reshape(-1)
    e_p = np.asarray(est_poses, dtype=np.float64).reshape(-1, 3)
    t_p = np.asarray(true_poses, dtype=np.float64).reshape(-1, 3)
    if not (len(t) == len(e_p) == len(t_p)) or len(t) == 0:
        raise ValueError(f"t_s ({len(t)}), est_poses ({len(e_p)}) and true_poses ({len(t_p)}) "
                         "must have the same non-zero length")
    err = np.hypot(e_p[:, 0] - t_p[:, 0], e_p[:, 1] - t_p[:, 1])
    herr = np.abs(wrap_angle(e_p[:, 2] - t_p[:, 2]))
    ok = err < float(threshold_m)
    n_c = max(1, int(n_consecutive))
    k = len(t) if kidnap_time_s is None else kidnap_index(t, kidnap_time_s)
    i0 = _first_stable(ok[:k], 0, n_c)
    out = {"converge_s": float("nan") if i0 is None else float(t[i0] - t[0]),
           "converged": i0 is not None}
    if kidnap_time_s is not None:
        ir = _first_stable(ok, k, n_c) if k < len(t) else None
        out["recover_s"] = float("nan") if ir is None else float(t[ir] - kidnap_time_s)
        out["median_before_kidnap_m"] = float(np.median(err[:k])) if k else float("nan")
        out["median_after_kidnap_m"] = float(np.median(err[k:])) if k < len(t) else float("nan")
    out["median_m"] = float(np.median(err))
    out["p90_m"] = float(np.percentile(err, 90))
    out["heading_median_deg"] = float(np.rad2deg(np.median(herr)))
    return out


def kidnap_index(t_s, kidnap_time_s: float) -> int:
    """Index of the first step at or after the kidnapping (the first step scored "after")."""
    return int(np.searchsorted(np.asarray(t_s, np.float64), float(kidnap_time_s), side="left"))
