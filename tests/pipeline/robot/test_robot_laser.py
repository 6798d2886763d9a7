"""Laser ray casting against analytic distances in a box room."""

import numpy as np
import pytest

from pipeline.robot import LaserScanner, OccupancyMap, ray_cast
from scenes import floor_plan_segments


def _room_ranges(sensor_xy, angles, size_x, size_y):
    """Distance from a point inside [0, X] x [0, Y] along each angle to the rectangle."""
    x, y = sensor_xy
    c, s = np.cos(angles), np.sin(angles)
    with np.errstate(divide="ignore"):
        tx = np.where(c > 0, (size_x - x) / c, np.where(c < 0, -x / c, np.inf))
        ty = np.where(s > 0, (size_y - y) / s, np.where(s < 0, -y / s, np.inf))
    return np.minimum(tx, ty)


def test_ranges_match_analytic_box_room(room):
    scanner = LaserScanner(range_noise_m=0.0)
    seg = floor_plan_segments(room, scanner.height_m)
    poses = np.array([[2.0, 1.5, 0.0], [1.0, 0.8, 0.7], [3.2, 2.1, -2.5]])
    r = scanner.scan(seg, poses, np.random.default_rng(0))
    sp = scanner.sensor_poses(poses)
    for i in range(len(poses)):
        ref = _room_ranges(sp[i, :2], sp[i, 2] + scanner.angles_rad, 4.0, 3.0)
        # exact geometry: only floating-point rounding
        np.testing.assert_allclose(r[i], np.minimum(ref, 8.0), atol=1e-9)
    # beam 90 (straight ahead) from (2.16, 1.5) facing +x hits x = 4
    assert r[0, 90] == pytest.approx(4.0 - 2.16, abs=1e-12)


def test_noise_statistics_and_max_range(room):
    rng = np.random.default_rng(1)
    scanner = LaserScanner(range_noise_m=0.01)
    exact = LaserScanner(range_noise_m=0.0)
    seg = floor_plan_segments(room, scanner.height_m)
    poses = np.tile([[2.0, 1.5, 0.3]], (200, 1))
    res = scanner.scan(seg, poses, rng) - exact.scan(seg, poses, rng)
    # 36,200 residuals: the sample std is within ~0.4 % of sigma; 3 % is generous
    assert np.std(res) == pytest.approx(0.01, rel=0.03)
    assert abs(np.mean(res)) < 3 * 0.01 / np.sqrt(res.size)
    short = LaserScanner(max_range_m=1.0)
    r = short.scan(seg, poses[:1], rng)
    # every wall is farther than 1 m from (2.16, 1.5) along some beams: those read exactly 1.0
    far = _room_ranges(short.sensor_poses(poses[:1])[0, :2], 0.3 + short.angles_rad, 4, 3) > 1
    assert far.any() and np.all(r[0, far] == 1.0)
    assert np.all(r[0, ~far] < 1.0)


def test_nothing_hit_reads_max_range():
    r = ray_cast(np.zeros((3, 2)), np.array([[1, 0], [0, 1], [-1, 0]]), np.zeros((0, 2, 2)), 8.0)
    assert np.all(r == 8.0)
    seg = np.array([[[1.0, -1.0], [1.0, 1.0]]])
    r = ray_cast(np.zeros((2, 2)), np.array([[1.0, 0.0], [-1.0, 0.0]]), seg, 8.0)
    np.testing.assert_allclose(r, [1.0, 8.0])


def test_occupancy_map_of_room_and_likelihood_field(room):
    m = OccupancyMap.from_scene(room, 0.05, (0.35, 0.35), n_slices=1)
    free = m.free_cell_centres()
    # free cells are the room interior [0, 4] x [0, 3], up to one cell at the walls
    assert free[:, 0].min() > -0.05 and free[:, 0].max() < 4.05
    assert free[:, 1].min() > -0.05 and free[:, 1].max() < 3.05
    assert len(free) == pytest.approx(80 * 60, rel=0.06)  # 4 x 3 m at 5 cm, +- boundary row
    # likelihood field: exact distance to the nearest wall, bilinear between cell centres
    pts = np.array([[2.0, 1.0], [0.3, 2.0], [3.9, 2.95]])
    np.testing.assert_allclose(m.surface_distance_m(pts), [1.0, 0.3, 0.05], atol=1e-9)
    assert m.is_occupied(np.array([[-0.1, 1.0], [50.0, 1.0]])).all()
    assert not m.is_occupied(np.array([[2.0, 1.5]])).any()


def test_scanner_rejects_bad_settings():
    with pytest.raises(ValueError, match="n_beams"):
        LaserScanner(n_beams=0)
    with pytest.raises(ValueError, match="max_range_m"):
        LaserScanner(max_range_m=-1.0)


def test_map_surface_error(room):
    m = OccupancyMap.from_scene(room, 0.05, (0.35, 0.35), n_slices=1)
    assert m.with_surface_error(np.random.default_rng(0), 0.0) is m
    e = m.with_surface_error(np.random.default_rng(0), 0.02, correlation_m=1.0)
    inner = m.boundary_distance_m > 0.2  # away from walls the shift is the field itself
    shift = m.boundary_distance_m[inner] - e.boundary_distance_m[inner]
    # the displacement field is normalised to 2 cm std over the grid; the interior part
    # is a large sample of it (correlation 1 m over a ~5 x 4 m grid: loose 30 %)
    assert np.std(shift) == pytest.approx(0.02, rel=0.3)
    with pytest.raises(ValueError, match="sigma_m=-1"):
        m.with_surface_error(np.random.default_rng(0), -1.0)
