"""The robot's map: per-wall signed offsets, drawn once, and the pose bias they cause."""

import dataclasses

import numpy as np
import pytest

import pipeline.robot.simulate as simulate_mod
from pipeline.evaluation.localisation import pose_error_summary
from pipeline.robot import (
    LocalisationConfig,
    MapError,
    Robot,
    Trajectory,
    displace_wall_lines,
    draw_map_error,
    draw_robot_map,
    laser_map,
    robot_map,
    simulate_localisation,
    wall_lines,
)


def test_wall_lines_merge_collinear_touching_pieces():
    seg = np.array([
        [[0.0, 0.0], [1.0, 0.0]],
        [[2.5, 0.0], [1.0, 0.0]],  # reversed, touching: same wall
        [[3.0, 0.0], [4.0, 0.0]],  # after a 0.5 m gap (a door): another wall
        [[0.0, 0.2], [2.0, 0.2]],  # parallel, 0.2 m away: the wall's other face
        [[0.0, 0.0], [0.0, 0.2]],  # perpendicular end cap
    ])
    lines, normals = wall_lines(seg)
    assert len(lines) == 4
    horiz = np.abs(normals[:, 1]) > 0.9
    np.testing.assert_allclose(normals[horiz], [[0.0, 1.0]] * 3, atol=1e-12)
    np.testing.assert_allclose(normals[~horiz], [[1.0, 0.0]], atol=1e-12)  # +x, +y convention
    spans = sorted((round(min(ln[:, 0]), 6), round(max(ln[:, 0]), 6), round(ln[0, 1], 6))
                   for ln in lines[horiz])
    assert spans == [(0.0, 2.0, 0.2), (0.0, 2.5, 0.0), (3.0, 4.0, 0.0)]


def _square(side=2.0):
    c = np.array([[0, 0], [side, 0], [side, side], [0, side]], float)
    return np.stack([c, np.roll(c, -1, axis=0)], 1)


def test_displaced_walls_move_along_their_normals_and_still_meet():
    lines, normals = wall_lines(_square())
    off = np.array([0.1, -0.05, 0.03, 0.07])
    moved = displace_wall_lines(lines, normals, off)
    for ln, n, o, mv in zip(lines, normals, off, moved, strict=True):
        # every point of the displaced line is o along n from the original line
        np.testing.assert_allclose((mv - ln[0]) @ n, [o, o], atol=1e-12)
    # corners stay closed: every displaced end point is an end point of another line
    ends = moved.reshape(-1, 2)
    d = np.linalg.norm(ends[:, None] - ends[None], axis=2)
    np.fill_diagonal(d, np.inf)
    assert np.all(d.min(axis=1) < 1e-12)
    # a scale error stretches the plan about its centre
    big = displace_wall_lines(lines, normals, np.zeros(4), scale=0.01, centre_m=[0.0, 0.0])
    np.testing.assert_allclose(big, 1.01 * lines, atol=1e-12)


def test_map_error_is_drawn_once_per_generator_and_streams_are_independent(corridor):
    a = draw_map_error(corridor, 0.35, 0.05, 0.0, np.random.default_rng(3))
    b = draw_map_error(corridor, 0.35, 0.05, 0.0, np.random.default_rng(3))
    c = draw_map_error(corridor, 0.35, 0.05, 0.0, np.random.default_rng(4))
    np.testing.assert_array_equal(a.offsets_m, b.offsets_m)
    assert not np.array_equal(a.offsets_m, c.offsets_m)
    assert a.scale == 0.0 and len(a.offsets_m) == len(a.lines_m) >= 8
    assert 0.01 < np.std(a.offsets_m) < 0.1  # N(0, 0.05^2) over a few dozen walls
    # turning the scale error on draws the scale from its own stream: offsets unchanged
    s = draw_map_error(corridor, 0.35, 0.05, 0.002, np.random.default_rng(3))
    np.testing.assert_array_equal(s.offsets_m, a.offsets_m)
    assert s.scale != 0.0
    zero = draw_map_error(corridor, 0.35, 0.0, 0.0, np.random.default_rng(3))
    assert zero.is_zero and np.all(zero.offsets_m == 0)
    back = MapError.from_arrays(a.to_arrays())
    np.testing.assert_array_equal(back.offsets_m, a.offsets_m)
    np.testing.assert_array_equal(back.displaced_lines_m, a.displaced_lines_m)


def test_zero_map_error_gives_the_true_map_exactly(corridor):
    cfg = LocalisationConfig(map_error_m=0.0, map_scale_error=0.0, map_noise_m=0.0)
    rm = draw_robot_map(corridor, cfg, np.random.default_rng(0))
    true = laser_map(corridor, cfg.scanner, cfg.map_resolution_m)
    assert rm.error.is_zero
    for k in ("origin_m", "occupied", "distance_m", "boundary_distance_m"):
        np.testing.assert_array_equal(getattr(rm.occupancy_map, k), getattr(true, k))


def _shift_south_wall(scene, shift_m, height_m=0.35):
    """A MapError with only the inner face of the south wall (y = 0) moved by shift_m in +y."""
    err = draw_map_error(scene, height_m, 0.0, 0.0, np.random.default_rng(0))
    mid = err.lines_m.mean(axis=1)
    south = (np.abs(err.normals[:, 1] - 1) < 1e-9) & (np.abs(mid[:, 1]) < 1e-6)
    assert south.sum() == 1
    return dataclasses.replace(err, offsets_m=np.where(south, shift_m, 0.0))


def test_shifted_wall_moves_the_likelihood_field(hall):
    occ = robot_map(hall, _shift_south_wall(hall, 0.1))
    true = laser_map(hall, LocalisationConfig().scanner)
    x, y = np.meshgrid(np.linspace(2.0, 7.0, 11), np.linspace(-0.05, 1.5, 32))
    p = np.stack([x.ravel(), y.ravel()], 1)  # nearer the south wall than any other
    # the map's field is the true one moved 0.1 m north (two cells: the same interpolation)
    np.testing.assert_allclose(occ.surface_distance_m(p + [0.0, 0.1]), true.surface_distance_m(p),
                               atol=1e-9)
    assert np.all(occ.is_occupied(p[p[:, 1] < 0.05] + [0.0, 0.05]))  # the wall took the strip


def test_simulate_localisation_uses_a_given_map_unchanged(corridor, monkeypatch):
    robot = Robot()
    n = 60
    poses = np.column_stack([np.linspace(2.0, 3.8, n), np.full(n, 1.2), np.zeros(n)])
    traj = Trajectory.from_poses(np.arange(n) * 0.1, poses)
    cfg = LocalisationConfig(map_error_m=0.05)
    # without a map, simulate_localisation draws one from the 4th of its spawned streams
    drawn = draw_robot_map(corridor, cfg, np.random.default_rng(5).spawn(4)[3]).occupancy_map
    own = simulate_localisation(corridor, robot, traj, np.random.default_rng(5), cfg)
    given = simulate_localisation(corridor, robot, traj, np.random.default_rng(5), cfg,
                                  occupancy_map=drawn)
    np.testing.assert_array_equal(own.estimated_poses, given.estimated_poses)
    # the given map reaches the filter as it is, and no other map is drawn
    seen = []
    real_run_mcl = simulate_mod.run_mcl
    monkeypatch.setattr(simulate_mod, "run_mcl", lambda m, *a, **k: seen.append(m) or
                        real_run_mcl(m, *a, **k))
    monkeypatch.setattr(simulate_mod, "draw_robot_map",
                        lambda *a, **k: pytest.fail("drew a map although one was given"))
    simulate_localisation(corridor, robot, traj, np.random.default_rng(5), cfg,
                          occupancy_map=drawn)
    assert len(seen) == 1 and seen[0] is drawn
    wrong = laser_map(corridor, dataclasses.replace(cfg.scanner, height_m=1.0))
    with pytest.raises(ValueError, match="laser scans at 0.35 m"):
        simulate_localisation(corridor, robot, traj, np.random.default_rng(5), cfg,
                              occupancy_map=wrong)


def test_wall_shifted_by_10cm_biases_mcl_laterally_by_10cm(hall):
    """The south wall of the map is 0.1 m too far north (+y): the laser measures 1 m to
    the real wall, so MCL puts the robot 1 m north of the map's wall, 0.1 m north of the
    truth: driving east (+x), a lateral (to the left) offset of +0.1 m."""
    robot = Robot()
    n = 200  # 6 m east at 0.3 m/s, 1 m from the south wall
    poses = np.column_stack([np.linspace(1.5, 7.5, n), np.full(n, 1.0), np.zeros(n)])
    traj = Trajectory.from_poses(np.arange(n) * 0.1, poses)
    cfg = LocalisationConfig(map_error_m=0.0)
    lateral = {}
    for shift in (0.0, 0.1, -0.1):
        occ = robot_map(hall, _shift_south_wall(hall, shift))
        res = simulate_localisation(hall, robot, traj, np.random.default_rng(8), cfg,
                                    occupancy_map=occ)
        # the filter starts at the true pose; skip its first metre, when it moves over
        sl = slice(n // 6, None)
        s = pose_error_summary(res.true_poses[sl], res.estimated_poses[sl])
        lateral[shift] = s.mean_offset_lateral_m
        assert s.mean_offset_y_m == pytest.approx(s.mean_offset_lateral_m, abs=0.005)  # heading ~ +x
        assert abs(s.mean_offset_along_m) < 0.02  # the east wall ahead is where it is
    # tolerance 2 cm: the motion-model noise, the 1 cm laser noise and the 5 cm likelihood-
    # field grid leave a few millimetres of wander in the mean offset of one 5 m drive
    # (seeds 8-13: within 4 mm of the shift); the sign and size of the shift must come through
    assert lateral[0.0] == pytest.approx(0.0, abs=0.02)
    assert lateral[0.1] - lateral[0.0] == pytest.approx(0.1, abs=0.02)
    assert lateral[-0.1] - lateral[0.0] == pytest.approx(-0.1, abs=0.02)


def test_likelihood_field_is_the_exact_capped_distance_to_the_nearest_segment():
    """The tiled field (each tile sees only the segments near it) against shapely's
    point-to-line distances over all segments, at cells near, far and at tile edges."""
    import shapely

    from pipeline.robot.occupancy import _segment_distance_field

    rng = np.random.default_rng(5)
    a = rng.uniform([0, 0], [12, 9], (40, 2))
    segs = np.stack([a, a + rng.normal(0, 1.5, (40, 2))], 1)
    origin, res, shape, cap = np.array([-1.0, -0.5]), 0.1, (125, 201), 2.0
    field = _segment_distance_field(segs, origin, res, shape, cap_m=cap, tile=16)
    xs = origin[0] + (np.arange(shape[1]) + 0.5) * res
    ys = origin[1] + (np.arange(shape[0]) + 0.5) * res
    gx, gy = np.meshgrid(xs, ys)
    lines = shapely.linestrings(segs)
    pts = shapely.points(gx.ravel(), gy.ravel())
    truth = np.min(shapely.distance(pts[:, None], lines[None]), axis=1).reshape(shape)
    # 1e-9 m: two float64 formulas of one distance; the cap where no segment is nearer
    np.testing.assert_allclose(field, np.minimum(truth, cap), atol=1e-9, rtol=0)
    assert (field < cap).mean() > 0.3 and (field == cap).mean() > 0.05  # both regimes seen
