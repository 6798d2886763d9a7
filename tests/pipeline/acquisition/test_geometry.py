"""d/alpha geometry the read log records (propagation.antenna_frame_angles) against hand-computed values.

Contract: alpha = atan2(y_local, x_local) in (-pi, pi], boresight = local +x, pitch up > 0.
"""

import numpy as np
import pytest

from pipeline.robot.kinematics import wrap_angle
from propagation import antenna_frame_angles


def test_straight_ahead_left_right_behind():
    # Antenna at (1, 2, 0.7) looking along +x: tags ahead, left, right, behind.
    ant = [[1.0, 2.0, 0.7, 0.0]]
    tags = [[4.0, 2.0, 0.7], [1.0, 3.5, 0.7], [1.0, 0.0, 0.7], [0.0, 2.0, 0.7]]
    g = antenna_frame_angles(ant, tags)
    # Exact geometry: tolerance only for float rounding.
    np.testing.assert_allclose(g.d_m, [[3.0, 1.5, 2.0, 1.0]], atol=1e-12)
    np.testing.assert_allclose(g.alpha_rad, [[0.0, np.pi / 2, -np.pi / 2, np.pi]], atol=1e-12)
    np.testing.assert_allclose(g.elevation_rad, 0.0, atol=1e-12)


def test_yawed_antenna_and_3_4_5_triangle():
    # Antenna yawed +90 deg (boresight +y): a tag at +y is ahead, one at +x is to the right.
    ant = [[0.0, 0.0, 1.0, np.pi / 2]]
    g = antenna_frame_angles(ant, [[0.0, 5.0, 1.0], [3.0, 0.0, 1.0], [-3.0, 4.0, 1.0]])
    np.testing.assert_allclose(g.d_m, [[5.0, 3.0, 5.0]], atol=1e-12)
    # Third tag: local x = 4, local y = 3 -> alpha = atan2(3, 4).
    np.testing.assert_allclose(g.alpha_rad, [[0.0, -np.pi / 2, np.arctan2(3.0, 4.0)]], atol=1e-12)


def test_pitch_up_tilts_boresight_up():
    # Tag 1 m ahead and 1 m up: with pitch +45 deg it is on boresight (elevation 0, alpha 0).
    g0 = antenna_frame_angles([[0, 0, 0, 0, 0, 0]], [[1.0, 0.0, 1.0]])
    g1 = antenna_frame_angles([[0, 0, 0, 0, np.pi / 4, 0]], [[1.0, 0.0, 1.0]])
    np.testing.assert_allclose(g0.elevation_rad, np.pi / 4, atol=1e-12)
    np.testing.assert_allclose(g1.elevation_rad, 0.0, atol=1e-12)
    np.testing.assert_allclose(g1.alpha_rad, 0.0, atol=1e-12)
    np.testing.assert_allclose(g1.d_m, np.sqrt(2.0), atol=1e-12)


def test_shapes_and_bad_input():
    g = antenna_frame_angles(np.zeros((5, 6)), np.ones((7, 3)))
    assert g.d_m.shape == g.alpha_rad.shape == (5, 7)
    with pytest.raises(ValueError, match="antenna_poses"):
        antenna_frame_angles(np.zeros((2, 5)), np.ones((1, 3)))


def test_wrap_angle_half_open_interval():
    w = wrap_angle(np.array([-np.pi, np.pi, 3 * np.pi, -3 * np.pi / 2, 0.1]))
    np.testing.assert_allclose(w, [np.pi, np.pi, np.pi, np.pi / 2, 0.1], atol=1e-12)
    assert np.all((w > -np.pi) & (w <= np.pi))
