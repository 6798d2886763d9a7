"""RFID-only robot localisation: global convergence, kidnap recovery, metric definitions."""

from __future__ import annotations

import numpy as np
import pytest

from pipeline.localisation import (
    BoxFreeSpace,
    ModelLikelihood,
    Observations,
    RfidMCLConfig,
    filter_metrics,
    pair_geometry,
    run_rfid_mcl,
)
from pipeline.robot.kinematics import antenna_poses, default_antennas
from pipeline.robot.odometry import OdometryNoise, simulate_odometry

L, W = 14.0, 2.4
# eight tags along both walls of a 14 m corridor
TAGS = np.array([[1.5, 0.005, 1.0], [3.0, W - 0.005, 0.6], [4.5, 0.005, 1.3],
                 [6.0, W - 0.005, 1.0], [7.5, 0.005, 0.8], [9.0, W - 0.005, 1.2],
                 [10.5, 0.005, 1.0], [12.5, W - 0.005, 0.9]])
IDS = tuple(f"T{i}" for i in range(len(TAGS)))
FREE = [[0.4, 0.4, L - 0.4, W - 0.4]]
RATE, SPEED, DURATION = 4.0, 0.3, 40.0


def _run(sensor, seed: int, *, kidnap_m: float = 0.0, config=None, filter_kidnap=None,
         known_start: bool = False):
    """A straight pass along y = 1 m; with `kidnap_m`, the true robot is teleported back by
    that much at t = 20 s (its odometry does not see it). Detection-only reads sampled
    from the synthetic sensor; the filter uses the same model, from an unknown start."""
    rng = np.random.default_rng(seed)
    t = np.arange(0.0, DURATION, 1.0 / RATE)
    x = 0.5 + SPEED * t
    smooth = np.column_stack([x, np.full(len(t), 1.0), np.zeros(len(t))])
    odo = simulate_odometry(smooth, OdometryNoise(0.01, 0.01, 0.01, 0.001), rng)
    true = smooth.copy()
    t_k = None
    if kidnap_m:
        t_k = 20.0
        true[t >= t_k, 0] -= kidnap_m
    ant = np.arange(len(t)) % 2
    poses = antenna_poses(true, default_antennas())[np.arange(len(t)), ant]
    lk = ModelLikelihood(sensor, use_rssi=False)
    d, a = pair_geometry(poses, TAGS)
    read, rssi = lk.sample(d.T, a.T, rng)
    obs = Observations(IDS, t, ant, poses, read, rssi, np.ones(read.shape, bool))
    kw = {}
    if filter_kidnap is not None:
        t_k = 20.0
        kw = {"kidnap_time_s": t_k, "kidnap_offset": filter_kidnap}
    res = run_rfid_mcl(lk, obs, (IDS, TAGS), odo, t, default_antennas(), FREE, rng,
                       config=config or RfidMCLConfig(n_particles=1000),
                       initial_pose=true[0] if known_start else None, **kw)
    return res, filter_metrics(t, res.est_poses, true, kidnap_time_s=t_k)


def test_converges_from_unknown_start_and_recovers_from_kidnapping(sensor):
    for seed in range(2):
        _, m = _run(sensor, seed, kidnap_m=4.0)
        # seen over seeds 0-5: convergence 0.25-8.75 s, recovery 0.5-5 s; over all steps
        # (the lost ones included) median 0.18-0.39 m, p90 0.27-0.63 m; bounds ~1.5-2x
        # the worst, inside the 20 s phases
        assert m["converged"] and m["converge_s"] <= 15.0, m
        assert m["recover_s"] <= 12.0, m
        assert m["median_m"] <= 0.6 and m["p90_m"] <= 1.2, m


def test_without_injection_a_kidnapped_filter_stays_lost(sensor):
    # the control: the same run without random-particle injection does not recover
    # (4 m is far beyond what the motion noise spreads the particles in 20 s; seen: never,
    # seeds 0-3)
    _, m = _run(sensor, 0, kidnap_m=4.0, config=RfidMCLConfig(n_particles=1000, augmented=False))
    assert m["converged"] and np.isnan(m["recover_s"]), m


def test_recovers_when_the_filter_is_kidnapped(sensor):
    # moving every particle by 5 m (what the stage can do with real reads) is recovered
    # too (seen over seeds 0-3: 2-7.25 s)
    _, m = _run(sensor, 1, filter_kidnap=(5.0, 0.0, 0.0))
    assert m["recover_s"] <= 12.0, m


def test_tracks_from_a_known_start(sensor):
    res, m = _run(sensor, 3, config=RfidMCLConfig(n_particles=300), known_start=True)
    assert m["converge_s"] == 0.0, m  # within 0.5 m from the first step on (seeds 0-3)
    assert res.est_poses.shape == (160, 3)


def test_filter_metrics_definitions():
    t = np.arange(20) * 0.5
    true = np.zeros((20, 3))
    est = np.zeros((20, 3))
    est[:4, 0] = 2.0  # lost for 4 steps, then converged at t = 2 s
    est[10:12, 0] = 3.0  # kidnapped at t = 5 s, recovered from t = 6 s
    est[12:, 0] = 0.1
    m = filter_metrics(t, est, true, threshold_m=0.5, n_consecutive=3, kidnap_time_s=5.0)
    assert m["converge_s"] == 2.0 and m["recover_s"] == 1.0 and m["converged"]
    # all 20 steps: 0 x6, 0.1 x8, 2 x4, 3 x2 -> the 10th and 11th are 0.1
    assert m["median_m"] == pytest.approx(0.1)
    assert m["p90_m"] == pytest.approx(np.percentile(np.abs(est[:, 0]), 90))
    # steps 0-9 (2 x4, 0 x6) before t = 5 s; steps 10-19 (3 x2, 0.1 x8) from it
    assert m["median_before_kidnap_m"] == 0.0
    assert m["median_after_kidnap_m"] == pytest.approx(0.1)
    never = filter_metrics(t, np.full((20, 3), 5.0), true)
    assert not never["converged"] and np.isnan(never["converge_s"])
    assert never["median_m"] == pytest.approx(np.hypot(5.0, 5.0))


def test_median_counts_the_steps_before_convergence():
    """One definition: a run lost for most of its steps has a median of a lost run (the
    old rule scored only its converged steps and reported 0 m here)."""
    t = np.arange(20) * 0.5
    est = np.zeros((20, 3))
    est[:12, 0] = 4.0  # lost for 12 of 20 steps, then on the spot
    m = filter_metrics(t, est, np.zeros((20, 3)), threshold_m=0.5, n_consecutive=3)
    assert m["converge_s"] == 6.0 and m["median_m"] == 4.0


def test_box_free_space_sampling():
    fs = BoxFreeSpace([[0, 0, 1, 1], [2, 0, 5, 1]])
    xy = fs.sample(4000, np.random.default_rng(0))
    assert fs.contains(xy).all()
    # area-weighted: 3/4 of the samples in the second box (SE ~0.007: 4 of them)
    assert np.mean(xy[:, 0] >= 2) == pytest.approx(0.75, abs=0.03)
    assert not fs.contains(np.array([[1.5, 0.5]]))[0]


def _free_space_field(spacing_m=0.2, n_heading=16):
    """A GainField of free-space gains (the synthetic truth) over the corridor."""
    from pipeline.localisation.robot_oracle import GainField
    from tests.helpers.localisation import free_space_gain_db

    xs, ys = np.arange(0.0, L + 1e-9, spacing_m), np.arange(0.0, W + 1e-9, spacing_m)
    heads = 2 * np.pi * np.arange(n_heading) / n_heading
    gx, gy, gh = np.meshgrid(xs, ys, heads, indexing="ij")
    robot = np.column_stack([gx.ravel(), gy.ravel(), gh.ravel()])
    ant = antenna_poses(robot, default_antennas())  # (K, A, 6)
    g = np.stack([free_space_gain_db(ant[:, a], TAGS) for a in range(ant.shape[1])])  # (A, K, M)
    table = g.reshape(ant.shape[1], len(xs), len(ys), n_heading, len(TAGS)).astype(np.float32)
    return GainField(np.array([xs[0], ys[0]]), spacing_m, n_heading, table, 0)


def test_oracle_field_filter_recovers_from_a_kidnapping():
    """The robot oracle's likelihood (tabulated gains, FieldLikelihood) in the same filter:
    reads drawn from the reader's likelihood of the free-space truth; from an unknown start
    it converges, and after the robot is teleported back 4 m it recovers."""
    from pipeline.localisation import OracleLikelihood
    from pipeline.localisation.robot_oracle import FieldLikelihood
    from propagation import LinkBudget
    from tests.helpers.localisation import free_space_gain_db

    field = _free_space_field()
    rng = np.random.default_rng(5)
    t = np.arange(0.0, DURATION, 1.0 / RATE)
    smooth = np.column_stack([0.5 + SPEED * t, np.full(len(t), 1.0), np.zeros(len(t))])
    odo = simulate_odometry(smooth, OdometryNoise(0.01, 0.01, 0.01, 0.001), rng)
    true = smooth.copy()
    true[t >= 20.0, 0] -= 4.0
    ant = np.arange(len(t)) % 2
    poses = antenna_poses(true, default_antennas())[np.arange(len(t)), ant]
    oracle = OracleLikelihood(LinkBudget(), miss_probability=0.0, rssi_noise_db=1.0)
    read, rssi = oracle.sample(free_space_gain_db(poses, TAGS).T, rng)
    obs = Observations(IDS, t, ant, poses, read, rssi, np.ones(read.shape, bool))
    # 1 dB of spread for the 0.2 m / 22.5 degree grid (no fading in free space)
    lk = FieldLikelihood(oracle, field, fading=None, extra_sigma_db=1.0)
    res = run_rfid_mcl(lk, obs, (IDS, TAGS), odo, t, default_antennas(), FREE, rng,
                       config=RfidMCLConfig(n_particles=1000))
    m = filter_metrics(t, res.est_poses, true, kidnap_time_s=20.0)
    assert m["converged"] and m["recover_s"] is not None and np.isfinite(m["recover_s"])
    # after convergence the error is the grid's and the odometry's: well under 0.5 m
    assert m["median_m"] < 0.5
    with pytest.raises(ValueError, match="extra_sigma_db"):
        FieldLikelihood(oracle, field, extra_sigma_db=-1.0)
    # a traced field holds local means: by default its reads are scored with their fading
    from pipeline.localisation.fading import FadedLikelihood

    assert isinstance(FieldLikelihood(oracle, field).oracle, FadedLikelihood)


def test_median_over_filter_runs():
    """Scores over filter runs: convergence counted and its time the median over runs,
    a run that never converges counting as infinitely late (NaN when most never do)."""
    from pipeline.localisation.benchmark import _median_over_runs

    runs = [{"median_m": 0.2, "p90_m": 1.0, "heading_median_deg": 5.0, "converge_s": 4.0,
             "recover_s": np.nan},
            {"median_m": 0.9, "p90_m": 3.0, "heading_median_deg": 9.0, "converge_s": np.nan,
             "recover_s": 2.0},
            {"median_m": 0.4, "p90_m": 2.0, "heading_median_deg": 7.0, "converge_s": 6.0,
             "recover_s": np.nan}]
    m = _median_over_runs(runs)
    assert m["heading_median_deg"] == 7.0
    assert m["converge_s"] == 6.0 and m["converged"]  # 4, 6, never -> 6
    assert np.isnan(m["recover_s"])  # never, 2, never -> never
    assert (m["converged_runs"], m["recovered_runs"]) == (2, 1)
    assert (m["median_m_min"], m["median_m_max"], m["n_runs"]) == (0.2, 0.9, 3)
    assert m["median_m_runs"] == [0.2, 0.9, 0.4]


@pytest.mark.parallel
def test_filter_runs_side_by_side_score_as_one_after_the_other(sensor):
    """robot_localisation in forked workers: the same scores and traces as in one process
    (each run has its own stream); fails if runs were matched to the wrong model or
    stream, or a worker's result came back out of order."""
    import pandas as pd

    from pipeline.localisation.benchmark import robot_localisation

    rng = np.random.default_rng(5)
    t = np.arange(0.0, 20.0, 1.0 / RATE)
    true = np.column_stack([0.5 + SPEED * t, np.full(len(t), 1.0), np.zeros(len(t))])
    odo = simulate_odometry(true, OdometryNoise(0.01, 0.01, 0.01, 0.001), rng)
    ant = np.arange(len(t)) % 2
    poses = antenna_poses(true, default_antennas())[np.arange(len(t)), ant]
    lk = ModelLikelihood(sensor, use_rssi=False)
    d, a = pair_geometry(poses, TAGS)
    read, rssi = lk.sample(d.T, a.T, rng)
    obs = Observations(IDS, t, ant, poses, read, rssi, np.ones(read.shape, bool))
    eval_poses = pd.DataFrame({"time_s": t, "odom_x_m": odo[:, 0], "odom_y_m": odo[:, 1],
                               "odom_theta_rad": odo[:, 2], "true_x_m": true[:, 0],
                               "true_y_m": true[:, 1], "true_theta_rad": true[:, 2]})
    sources = {"bayes": lk, "again": lk}
    cfgs = RfidMCLConfig(n_particles=300)
    kw = {"config": cfgs, "n_runs": 3}
    one = robot_localisation(sources, obs, (IDS, TAGS), eval_poses, default_antennas(), FREE,
                             np.random.default_rng(11), workers=1, **kw)
    two = robot_localisation(sources, obs, (IDS, TAGS), eval_poses, default_antennas(), FREE,
                             np.random.default_rng(11), workers=2, **kw)
    import json

    assert json.dumps(one, sort_keys=True) == json.dumps(two, sort_keys=True)  # NaN-safe
    # common random numbers: run k of every model draws the same stream, so two sources
    # that are the same model give the same runs, pair by pair (their difference is then
    # the models', not the filters' sampling noise) ...
    assert one["bayes"]["median_m_runs"] == one["again"]["median_m_runs"]
    # ... while the runs of one model differ from each other (a worker handing back one
    # stream's run for every job would make them equal)
    assert len(set(one["bayes"]["median_m_runs"])) == 3
    # the runs as tasks of the caller's own (downstream: beside the tag work), computed in
    # reverse order: the same scores once handed back in task order
    from pipeline.localisation.benchmark import RobotRuns

    runs = RobotRuns(sources, obs, (IDS, TAGS), eval_poses, default_antennas(), FREE,
                     np.random.default_rng(11), **kw)
    assert len(runs) == 6
    results = [runs.run(i) for i in reversed(range(len(runs)))][::-1]
    assert json.dumps(runs.scores(results), sort_keys=True) == json.dumps(one, sort_keys=True)
    with pytest.raises(ValueError, match="expected 6 filter results"):
        runs.scores(results[:-1])
