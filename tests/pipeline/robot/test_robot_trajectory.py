"""Guided tours and the evaluation path stay in free space, are reproducible, and bad ones raise."""

import dataclasses

import numpy as np
import pytest

from pipeline.robot import (
    Robot,
    TourConfig,
    Trajectory,
    check_trajectory,
    collision_map,
    evaluation_path,
    footprint_points,
    guided_tour,
)


@pytest.fixture(scope="module")
def robot():
    return Robot()


@pytest.fixture(scope="module")
def cmap(corridor, robot):
    return collision_map(corridor, robot)


@pytest.fixture(scope="module")
def tour(corridor, robot):
    return guided_tour(corridor, robot, np.random.default_rng(7), TourConfig(n_passes=3))


def test_tour_stays_in_free_space_with_clearance(tour, cmap, robot):
    check_trajectory(cmap, tour, robot, clearance_m=0.0)
    c = cmap.clearance_m(footprint_points(robot, tour.poses, 0.05)).min()
    # planned with 0.10 m clearance of the turning disc; the grid lookup is good to ~1 cell
    assert c >= 0.10 - 0.05


def test_tour_goes_up_and_down_within_limits(tour, robot, corridor):
    x = tour.poses[:, 0]
    assert x.min() < 1.0 and x.max() > 19.0  # covers the 20 m corridor
    assert set(np.unique(tour.pass_index)) == {-1, 0, 1, 2}
    # pass 1 drives back: heading about pi
    back = tour.pass_index == 1
    assert np.median(np.abs(tour.poses[back, 2])) > 2.5
    assert tour.v_m_per_s.max() <= 0.3 + 1e-9  # cruise speed, never above
    assert np.abs(tour.w_rad_per_s).max() <= robot.max_turn_rate_rad_per_s
    # stops: the robot stands still inside passes for a while
    assert np.sum((tour.v_m_per_s == 0) & (tour.pass_index >= 0)) >= 3 * 15
    # lanes change across the corridor
    assert np.ptp(tour.poses[tour.pass_index >= 0, 1]) > 0.3
    np.testing.assert_allclose(np.diff(tour.t_s), 0.1, atol=1e-9)


def test_same_seed_same_tour_different_seed_different(corridor, robot, tour):
    again = guided_tour(corridor, robot, np.random.default_rng(7), TourConfig(n_passes=3))
    np.testing.assert_array_equal(again.poses, tour.poses)
    other = guided_tour(corridor, robot, np.random.default_rng(8), TourConfig(n_passes=3))
    assert len(other) != len(tour) or not np.allclose(other.poses, tour.poses)


def test_more_passes_give_longer_tours(corridor, robot):
    t6 = guided_tour(corridor, robot, np.random.default_rng(1), TourConfig(n_passes=6))
    assert set(np.unique(t6.pass_index)) == set(range(-1, 6))
    assert t6.length_m > 6 * 17.0  # six passes of the ~19 m usable corridor


def test_evaluation_path(corridor, robot, cmap, tour):
    ev = evaluation_path(corridor, robot, np.random.default_rng(3), n_poses=200)
    assert len(ev) == 200
    check_trajectory(cmap, ev, robot)
    assert ev.poses[0, 0] < 1.0 and ev.poses[-1, 0] > 19.0
    assert np.all(np.diff(ev.poses[:, 0]) > 0)  # one pass up the corridor


def test_leaving_free_space_raises_with_index(tour, cmap, robot):
    poses = tour.poses.copy()
    poses[37:, 1] -= 1.5  # shove the robot into the right-hand wall from pose 37 on
    bad = Trajectory.from_poses(tour.t_s, poses)
    with pytest.raises(ValueError, match=r"pose 37 .*x = .* y = "):
        check_trajectory(cmap, bad, robot)


def test_no_route_raises(corridor, robot):
    from scenes import Scene

    s = Scene("noroute", corridor.meshes, corridor.tags, route_m=None)
    with pytest.raises(ValueError, match="no route_m"):
        guided_tour(s, robot, np.random.default_rng(0))


def test_tour_in_bundled_corridor_lab(robot):
    import scenes

    lab = scenes.load("corridor_lab")
    tour = guided_tour(lab, robot, np.random.default_rng(0), TourConfig(n_passes=2))
    check_trajectory(collision_map(lab, robot), tour, robot)  # cabinets, doors avoided
    assert np.ptp(tour.poses[:, 0]) > 20.0  # most of the ~25 m corridor


def test_collision_map_is_shared_only_for_the_same_settings(corridor, robot, cmap, monkeypatch):
    # the same scene and robot get the same (read-only) map; a taller robot, another
    # route or resolution get maps of their own, so no caller sees another's map
    assert collision_map(corridor, robot) is cmap
    # room for every map of this test: an identity below never depends on an eviction
    monkeypatch.setattr("pipeline.robot.trajectory._COLLISION_MAPS_KEPT", 100)
    for arr in (cmap.origin_m, cmap.occupied, cmap.distance_m, cmap.boundary_distance_m):
        with pytest.raises(ValueError, match="read-only"):
            arr.flat[0] = arr.flat[0]
    # antennas mounted higher: the map's slices reach higher
    tall = Robot(antennas=[dataclasses.replace(a, z_m=a.z_m + 0.5) for a in robot.antennas])
    assert collision_map(corridor, tall) is not cmap
    assert collision_map(corridor, tall).z_range_m[1] > cmap.z_range_m[1]
    assert collision_map(corridor, robot, resolution_m=0.1).resolution_m == 0.1
    # half the route (a two-point route's [:2] would be all of it: the same map)
    route = np.asarray(corridor.route_m, float)
    short_route = np.array([route[0], (route[0] + route[-1]) / 2])
    other = collision_map(corridor, robot, route_m=short_route)
    assert other is not cmap and other is not collision_map(corridor, robot, resolution_m=0.1)
