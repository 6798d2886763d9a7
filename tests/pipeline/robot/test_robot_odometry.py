"""Odometry noise model (Thrun et al. 2005, Table 5.6)."""

import numpy as np
import pytest

from pipeline.robot import OdometryNoise, sample_motion_model_odometry, simulate_odometry


def _square_path(n=400):
    t = np.linspace(0, 4 * np.pi, n)
    return np.stack([3 * np.cos(t / 2), 2 * np.sin(t / 2), t / 2 + np.pi / 2], 1)


def test_zero_noise_is_exact():
    truth = _square_path()
    odo = simulate_odometry(truth, OdometryNoise(0, 0, 0, 0), np.random.default_rng(0))
    # forward steps of 5 cm (> the 1 cm rot1 threshold): exact up to rounding
    np.testing.assert_allclose(odo[:, :2], truth[:, :2], atol=1e-9)
    np.testing.assert_allclose(np.cos(odo[:, 2] - truth[:, 2]), 1.0, atol=1e-12)


def test_single_step_variances_match_model():
    # one straight 1 m step: rot1 = rot2 = 0, so var(trans) = alpha3, var(rot1) = alpha2
    noise = OdometryNoise(alpha1=0.1, alpha2=0.01, alpha3=0.04, alpha4=0.3)
    x = np.zeros((40_000, 3))
    out = sample_motion_model_odometry([0, 0, 0], [1, 0, 0], x, noise, np.random.default_rng(2))
    # 40k samples: relative standard error of a std is 1/sqrt(2N) = 0.35 %; allow 3 %
    assert np.std(out[:, 0]) == pytest.approx(np.sqrt(0.04), rel=0.03)
    # y = trans sin(rot1) ~ rot1 for small rot1: std sqrt(alpha2) = 0.1
    assert np.std(out[:, 1]) == pytest.approx(0.1, rel=0.03)
    # heading = rot1 + rot2, independent, each with variance alpha2 * 1
    assert np.std(out[:, 2]) == pytest.approx(np.sqrt(2 * 0.01), rel=0.03)
    assert abs(np.mean(out[:, 0]) - 1.0) < 0.01


def test_drift_spread_grows_along_the_path():
    truth = _square_path()
    noise = OdometryNoise()
    rng = np.random.default_rng(3)
    err = np.array(
        [
            np.linalg.norm(simulate_odometry(truth, noise, rng)[:, :2] - truth[:, :2], axis=1)
            for _ in range(100)
        ]
    )
    rms = np.sqrt(np.mean(err**2, axis=0))
    assert rms[0] == 0.0  # starts at the true pose
    assert rms[100] < rms[200] < rms[399]  # dead reckoning: error accumulates


def test_systematic_scale_biases_distance():
    truth = np.stack([np.linspace(0, 10, 201), np.zeros(201), np.zeros(201)], 1)
    odo = simulate_odometry(
        truth, OdometryNoise(0, 0, 0, 0, translation_scale=1.02), np.random.default_rng(0)
    )
    assert odo[-1, 0] == pytest.approx(10.2)


def test_bad_noise_raises():
    with pytest.raises(ValueError, match="alpha3"):
        OdometryNoise(alpha3=-1.0)
