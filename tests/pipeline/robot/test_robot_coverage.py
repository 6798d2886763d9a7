"""The robot in a building from a ROS map: the planned coverage route, and MCL's map being the
occupancy grid as given while collision and the laser use the extracted geometry."""

import dataclasses

import numpy as np
import pytest

import scenes
from pipeline.robot import (
    LocalisationConfig,
    Robot,
    collision_map,
    draw_robot_map,
    plan_coverage_route,
)
from pipeline.robot.coverage import _segment_distance, route_clearance_m
from pipeline.studyscene import map_route
from scenes.rosmap import FREE, resolve_unknown
from tests.scenes.maphelpers import FREE as WHITE
from tests.scenes.maphelpers import OCC, RES, building, paint, write_map


def _aisles(tmp_path, name="aisles", closed=False):
    """Inside x in [0.75, 12.75], y in [0.75, 10.75]; three 0.8 m racks, 2.5 m aisles."""
    g = building(width_m=12.0, length_m=10.0, wall_m=0.25, pad_m=0.5)
    for x0 in (2.5, 5.8) if closed else (2.5, 5.8, 9.1):
        paint(g, x0, 3.0, x0 + 0.8, 9.0, OCC)
    paint(g, 6.0, 1.2, 6.05, 1.25, OCC)  # one noise cell (a stray laser return)
    if closed:  # a room around a third rack, no door: the robot fits in, but cannot get in
        paint(g, 8.4, 2.0, 12.6, 10.3, OCC)
        paint(g, 8.6, 2.2, 12.4, 10.1, WHITE)
        paint(g, 10.1, 3.0, 10.9, 9.0, OCC)
    return write_map(tmp_path, g, name=name)


@pytest.fixture(scope="module")
def aisle_scene(tmp_path_factory):
    return scenes.load(_aisles(tmp_path_factory.mktemp("aisles")))


def test_route_passes_every_tag_face_within_the_standoff(aisle_scene):
    robot = Robot()
    plan = plan_coverage_route(aisle_scene, robot, standoff_m=1.3)
    xy = aisle_scene.tags.positions_m[:, :2]
    route = plan.route_m
    # horizontal distance of each tag to the route polyline
    d = np.min([_segment_distance(xy, a, b) for a, b in zip(route[:-1], route[1:], strict=True)], axis=0)
    assert len(xy) == 3 * 2 * 1 * 6 and np.all(d <= 1.3 + 1e-9)  # one row, 1 m apart
    # every face of every rack has a pass: 6 faces, 4 aisles (3 between + 2 side - shared)
    assert len(plan.faces) == 6 and np.all(plan.face_pass >= 0)
    assert 4 <= len(plan.passes_m) <= 6
    # it never leaves the inflated free space: every point along it (5 cm apart) keeps the
    # robot's radius plus the margin from every obstacle, less one collision-map cell (the
    # clearance lookup is accurate to a cell) and half a planning cell (the simplification)
    cmap = collision_map(aisle_scene, robot, route_m=np.zeros((0, 2)))
    clear = route_clearance_m(cmap, route)
    assert clear.min() >= plan.inflation_m - cmap.resolution_m - 0.05
    assert plan.inflation_m == pytest.approx(robot.radius_m + 0.25)


def test_unreachable_faces_are_skipped_and_named(tmp_path):
    """The closed room's rack faces are skipped with their reason; the others are served,
    and map_route drops the skipped faces' tags from the scene and lists them."""
    sc = scenes.load(_aisles(tmp_path, closed=True))
    plan = plan_coverage_route(sc, Robot(), standoff_m=1.3)
    assert len(plan.skipped) >= 2  # the room's rack (its faces split where the room is cut off)
    assert all(s.reason.startswith(("cut off", "other region")) for s in plan.skipped)
    assert all("\n" not in s.describe() for s in plan.skipped)
    # the skipped faces are the third rack's, at x in [10.1, 10.9]
    in_room = (sc.tags.positions_m[:, 0] > 10.0) & (sc.tags.positions_m[:, 0] < 11.0)
    assert np.array_equal(plan.skipped_tag_index, np.flatnonzero(in_room))
    served = np.setdiff1d(np.arange(len(sc.tags)), plan.skipped_tag_index)
    xy = sc.tags.positions_m[served, :2]
    route = plan.route_m
    d = np.min([_segment_distance(xy, a, b) for a, b in zip(route[:-1], route[1:], strict=True)], axis=0)
    assert np.all(d <= 1.3 + 1e-9)
    skipped_faces = [i for i, f in enumerate(plan.faces) if any(f is s.face for s in plan.skipped)]
    assert np.all((plan.face_pass >= 0) == ~np.isin(np.arange(len(plan.faces)), skipped_faces))
    routed = map_route(sc, Robot())
    assert len(routed.tags) == len(sc.tags) - len(plan.skipped_tag_index)
    assert len(routed.metadata["route"]["skipped"]) == len(plan.skipped)


def test_no_servable_face_names_the_map(tmp_path):
    g = building(width_m=4.0, length_m=4.0, wall_m=0.25, pad_m=0.5)
    paint(g, 1.3, 1.0, 3.7, 1.9, OCC)  # a rack in a room too small to pass it
    paint(g, 1.3, 2.8, 3.7, 3.7, OCC)
    sc = scenes.load(write_map(tmp_path, g, name="cramped"))
    with pytest.raises(ValueError, match=r"cramped\.yaml: no route: none of the \d+ tag faces can be "
                                         r"served") as err:
        plan_coverage_route(sc, Robot(), standoff_m=1.0)
    assert "\n" not in str(err.value)


def test_standoff_too_small_for_the_robot(aisle_scene):
    with pytest.raises(ValueError, match=r"standoff_m 0.3 m is below the robot's radius"):
        plan_coverage_route(aisle_scene, Robot(), standoff_m=0.3)


def test_mcl_map_is_the_grid_as_given(aisle_scene):
    sc = map_route(aisle_scene, Robot())
    assert sc.route_m is not None and len(sc.route_m) > 2
    loc = LocalisationConfig(map_error_m=0.0, map_scale_error=0.0, map_noise_m=0.0)
    rmap = draw_robot_map(sc, loc, np.random.default_rng(1)).occupancy_map
    rm = sc.rosmap
    # the robot's map is the map's own grid: its free cells exactly (resolved unknowns included)
    assert rmap.resolution_m == rm.resolution_m and rmap.shape == rm.shape
    assert np.array_equal(~rmap.occupied, resolve_unknown(rm.cell_class) == FREE)
    # the noise cell at (6.025, 1.225) is in the robot's map but makes no geometry
    noise = np.array([[6.025, 1.225]])
    assert rmap.is_occupied(noise)[0]
    assert scenes.is_free(sc, [[6.025, 1.225, 0.35]])[0]
    # with a map error the map's walls move (the biased-map option applies on top)
    biased = draw_robot_map(sc, dataclasses.replace(loc, map_error_m=0.1), np.random.default_rng(1))
    assert np.max(np.abs(biased.error.offsets_m)) > RES
    assert not np.array_equal(biased.occupancy_map.occupied, rmap.occupied)


def test_cli_shows_a_map_and_refuses_a_bad_one_before_writing(tmp_path):
    from typer.testing import CliRunner

    from pipeline.apps.cli import app

    runner = CliRunner()
    path = _aisles(tmp_path / "ok")
    png = tmp_path / "top.png"
    res = runner.invoke(app, ["scenes", "show", str(path), "--png", str(png)])
    assert res.exit_code == 0, res.output
    assert "tags: 36" in res.output and "route: " in res.output
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    bare = write_map(tmp_path / "bare", building(4.0, 3.0))  # no racks: tags on the walls
    res = runner.invoke(app, ["scenes", "show", str(bare)])
    assert res.exit_code == 0, res.output
    assert "no rack recognised" in res.output and "route: " in res.output
    assert "tags: 0" not in res.output and "planned route: " in res.output
    empty = tmp_path / "empty.toml"  # tags switched off: the route says why there is none
    empty.write_text(f'[map]\npath = "{bare}"\n[tags]\nlayout = "none"\n')
    res = runner.invoke(app, ["scenes", "show", str(empty)])
    assert res.exit_code == 0, res.output
    assert "tags: 0" in res.output and "route: none planned" in res.output and "no tags" in res.output
    bad = write_map(tmp_path / "bad", building(2.0, 2.0), resolution=0)
    out = tmp_path / "run"
    res = runner.invoke(app, ["run", str(bad), "--out", str(out)])
    errors = [ln for ln in res.output.splitlines() if ln.startswith("error: ")]
    assert res.exit_code == 2 and len(errors) == 1
    assert "map.yaml: key 'resolution' must be positive" in errors[0]
    assert not out.exists()  # nothing half-written


def test_a_long_evaluation_path_keeps_its_poses_close(aisle_scene):
    """n_eval_poses on a long path would space the poses too far for MCL to track between
    them: tour.eval_max_spacing_m bounds the spacing; 0 keeps n_eval_poses exactly."""
    from pipeline.robot import TourConfig, evaluation_path

    sc = map_route(aisle_scene, Robot())
    bounded = evaluation_path(sc, Robot(), np.random.default_rng(3), n_poses=20,
                              config=TourConfig(eval_max_spacing_m=0.3))
    step = np.linalg.norm(np.diff(bounded.poses[:, :2], axis=0), axis=1)
    assert len(bounded.poses) > 20 and step.max() <= 0.3 + 0.02  # speed ramps: equal times
    exact = evaluation_path(sc, Robot(), np.random.default_rng(3), n_poses=20,
                            config=TourConfig(eval_max_spacing_m=0.0))
    assert len(exact.poses) == 20


def test_narrow_aisles_get_a_route_with_the_narrow_margin(tmp_path):
    """Aisles 1.25 m wide: the default margin (0.40 + 0.25 m each side: 1.3 m) fits no pass,
    so the planner alone refuses; map_route plans again with 0.15 m (1.1 m) and keeps that
    route (one side at least: the other is within a grid cell of the limit)."""
    from pipeline.studyscene import NARROW_ROUTE_MARGIN_M

    g = building(width_m=3.3, length_m=8.0, wall_m=0.25, pad_m=0.5)  # inside x 0.75 - 4.05
    paint(g, 2.0, 2.0, 2.8, 6.0, OCC)  # one rack, 1.25 m from either wall
    sc = scenes.load(write_map(tmp_path, g, name="narrow"))
    with pytest.raises(ValueError, match="no route"):
        plan_coverage_route(sc, Robot(), standoff_m=1.0)
    routed = map_route(sc, Robot())
    narrow = plan_coverage_route(sc, Robot(), standoff_m=1.0, margin_m=NARROW_ROUTE_MARGIN_M)
    np.testing.assert_allclose(routed.route_m, narrow.route_m)
    assert len(routed.tags) == len(sc.tags) - len(narrow.skipped_tag_index) >= len(sc.tags) // 2


def test_the_driven_tour_follows_the_planned_route(aisle_scene):
    """On a map the planned route is where the robot drives: the tour's poses stay within
    its band (0.3 m) of it, not in the middle of the free space beside it (measured: max
    0.17 m, median 0.02 m; with the corridor's 6 m band 0.56 and 0.24 m)."""
    from pipeline.robot import TourConfig, guided_tour
    from pipeline.studyscene import _route_distance_m

    sc = map_route(aisle_scene, Robot())
    tour = guided_tour(sc, Robot(), np.random.default_rng(5),
                       TourConfig(n_passes=1, lane_fractions=(0.0,), lane_changes_per_pass=0,
                                  stops_per_pass=0, dt_s=0.5))
    d = _route_distance_m(tour.poses[:, :2], sc.route_m)
    assert d.max() <= 0.35 and np.median(d) <= 0.1
