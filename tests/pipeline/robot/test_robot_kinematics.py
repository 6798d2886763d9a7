"""Robot kinematics: antenna pose composition and mounting checks."""

import numpy as np
import pytest

from pipeline.configschema import from_dict
from pipeline.robot import AntennaMount, Robot, antenna_poses, compose_poses, wrap_angle
from pipeline.robot.trajectory import TourConfig


def test_antenna_poses_hand_computed():
    mounts = [
        AntennaMount("a", x_m=0.2, y_m=0.1, z_m=0.7, yaw_rad=np.pi / 4, tilt_rad=0.1),
        AntennaMount("b", x_m=-0.3, y_m=0.0, z_m=0.9, yaw_rad=-np.pi / 2),
    ]
    poses = np.array([[1.0, 2.0, np.pi / 2], [0.0, 0.0, 0.0]])
    out = antenna_poses(poses, mounts)
    assert out.shape == (2, 2, 6)
    # robot at (1, 2) facing +y: robot +x is world +y, robot +y is world -x
    # a: (1 - 0.1, 2 + 0.2), yaw 90 + 45 deg; b: (1, 2 - 0.3), yaw 0
    np.testing.assert_allclose(out[0, 0], [0.9, 2.2, 0.7, 3 * np.pi / 4, 0.1, 0.0], atol=1e-12)
    np.testing.assert_allclose(out[0, 1], [1.0, 1.7, 0.9, 0.0, 0.0, 0.0], atol=1e-12)
    np.testing.assert_allclose(out[1, 0], [0.2, 0.1, 0.7, np.pi / 4, 0.1, 0.0], atol=1e-12)
    np.testing.assert_allclose(out[1, 1], [-0.3, 0.0, 0.9, -np.pi / 2, 0.0, 0.0], atol=1e-12)


def test_antenna_yaw_is_wrapped():
    m = [AntennaMount("a", 0.0, 0.4, 0.7, yaw_rad=np.pi / 2)]
    out = antenna_poses(np.array([[0.0, 0.0, 3.0]]), m)
    assert -np.pi < out[0, 0, 3] <= np.pi
    assert out[0, 0, 3] == pytest.approx(3.0 + np.pi / 2 - 2 * np.pi)


def test_default_robot_has_two_front_antennas_at_pm45():
    r = Robot()
    assert [a.name for a in r.antennas] == ["left", "right"]
    assert sorted(np.rad2deg([a.yaw_rad for a in r.antennas])) == pytest.approx([-45, 45])
    assert all(a.z_m > r.body_height_m for a in r.antennas)
    # circumscribed radius of the 0.626 x 0.505 m P3-AT footprint
    assert r.radius_m == pytest.approx(np.hypot(0.313, 0.2525))


def test_antenna_inside_body_raises_naming_it():
    bad = AntennaMount("buried", x_m=0.1, y_m=0.0, z_m=0.2, yaw_rad=0.0)
    with pytest.raises(ValueError, match="'buried'.*inside the body"):
        Robot(antennas=[bad])


def test_antenna_outside_footprint_or_above_body_is_fine():
    on_bracket = AntennaMount("bracket", x_m=0.40, y_m=0.0, z_m=0.2, yaw_rad=0.0)
    on_mast = AntennaMount("mast", x_m=0.0, y_m=0.0, z_m=0.5, yaw_rad=0.0)
    r = Robot(antennas=[on_bracket, on_mast])
    assert len(r.antennas) == 2


def test_antenna_below_floor_and_duplicates_raise():
    with pytest.raises(ValueError, match="'low'.*not above the floor"):
        Robot(antennas=[AntennaMount("low", 1.0, 0.0, 0.0, 0.0)])
    a = AntennaMount("x", 0.0, 0.0, 0.8, 0.0)
    with pytest.raises(ValueError, match="duplicate antenna names"):
        Robot(antennas=[a, a])


def test_compose_and_wrap():
    p = compose_poses(np.array([1.0, 1.0, np.pi]), np.array([1.0, 0.0, np.pi / 2]))
    np.testing.assert_allclose(p, [0.0, 1.0, -np.pi / 2], atol=1e-12)
    assert wrap_angle(-np.pi) == pytest.approx(np.pi)  # (-pi, pi]
    assert wrap_angle(3 * np.pi) == pytest.approx(np.pi)


def test_config_rejects_unknown_key_by_name():
    with pytest.raises(ValueError, match=r"study.toml: tour.speed_mps: unknown key"):
        from_dict(TourConfig, {"speed_mps": 0.3}, source="study.toml", prefix="tour")


def test_tour_faster_than_robot_raises_naming_key():
    with pytest.raises(ValueError, match="speed_m_per_s=0.9 exceeds"):
        TourConfig(speed_m_per_s=0.9).check_robot(Robot())
