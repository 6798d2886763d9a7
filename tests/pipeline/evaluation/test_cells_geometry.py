import numpy as np
import pytest

from pipeline.evaluation import CellGrid, antenna_frame_geometry, lattice_offsets


def test_cell_grid_indexing_edges_and_wrap():
    g = CellGrid(d_max_m=3.0, d_bin_m=0.5, alpha_bin_deg=90.0)
    assert g.shape == (6, 4)
    idx = g.index([0.0, 0.49, 0.5, 2.99, 3.0, np.nan, 1.0],
                  [-np.pi + 1e-9, 0.1, -0.1, np.pi, 0.0, 0.0, 3 * np.pi])
    assert idx.valid.tolist() == [True, True, True, True, False, False, True]
    assert idx.i_d[:4].tolist() == [0, 0, 1, 5]
    # bearing bins: [-180,-90), [-90,0), [0,90), [90,180]; +pi in the last bin, 3pi wraps to pi
    assert idx.i_alpha[:4].tolist() == [0, 2, 1, 3]
    assert idx.i_alpha[6] == 3
    counts = g.count([0.1, 0.2, 2.5], [0.1, 0.2, -3.0])
    assert counts[0, 2] == 2 and counts[5, 0] == 1 and counts.sum() == 3


def test_cell_grid_rejects_bad_values_and_keys():
    with pytest.raises(ValueError, match="d_bin_m"):
        CellGrid(d_bin_m=-1.0)
    with pytest.raises(ValueError, match="unknown key.*'bogus'"):
        CellGrid.from_dict({"d_max_m": 3, "d_bin_m": 1, "alpha_bin_deg": 10, "bogus": 1})
    g = CellGrid(2.0, 0.25, 10.0)
    assert CellGrid.from_dict(g.to_dict()) == g


def test_frame_geometry_closed_forms():
    # antenna at (1, 2, 1) yawed +90 deg: world +y is boresight, world -x is to the right
    pose = [[1.0, 2.0, 1.0, np.pi / 2]]
    g = antenna_frame_geometry(pose, [[1.0, 4.0, 1.0], [-2.0, 2.0, 1.0], [1.0, 2.0, 4.0]])
    np.testing.assert_allclose(g.d_m[0], [2.0, 3.0, 3.0], atol=1e-12)
    np.testing.assert_allclose(g.alpha_rad[0, :2], [0.0, np.pi / 2], atol=1e-12)
    np.testing.assert_allclose(g.elevation_rad[0, 2], np.pi / 2, atol=1e-12)
    # pitch +30 deg (boresight up): a point straight ahead horizontally sits 30 deg below
    g = antenna_frame_geometry([[0, 0, 0, 0, np.radians(30), 0]], [[1.0, 0.0, 0.0]])
    np.testing.assert_allclose(g.elevation_rad, [[-np.radians(30)]], atol=1e-12)


def test_frame_geometry_matches_propagation():
    prop = pytest.importorskip("propagation.patterns")
    rng = np.random.default_rng(3)
    poses = np.column_stack([rng.uniform(-2, 2, (5, 3)), rng.uniform(-np.pi, np.pi, 5),
                             rng.uniform(-0.5, 0.5, 5), rng.uniform(-0.5, 0.5, 5)])
    pts = rng.uniform(-3, 3, (7, 3))
    ref = prop.antenna_frame_angles(poses, pts)
    ours = antenna_frame_geometry(poses, pts)
    # same rotation convention, float64 round-off only
    np.testing.assert_allclose(ours.d_m, ref.d_m, atol=1e-12)
    np.testing.assert_allclose(ours.alpha_rad, ref.alpha_rad, atol=1e-12)
    np.testing.assert_allclose(ours.elevation_rad, ref.elevation_rad, atol=1e-12)


def test_lattice_offsets_symmetric_and_inside():
    o = lattice_offsets(0.1, "disc", 4)
    assert o.shape == (49, 3) and np.all(o[:, 2] == 0.0)
    assert np.all(np.linalg.norm(o, axis=1) <= 0.1 + 1e-15)
    np.testing.assert_allclose(o.mean(axis=0), 0.0, atol=1e-15)
    b = lattice_offsets(0.1, "ball", 4)
    assert b.shape == (257, 3)
    assert lattice_offsets(0.0).shape == (1, 3)
    with pytest.raises(ValueError, match="shape"):
        lattice_offsets(0.1, "cube")


def test_frame_geometry_per_pose_points_match_one_pose_at_a_time():
    prop = pytest.importorskip("propagation")
    rng = np.random.default_rng(4)
    poses = np.column_stack([rng.uniform(-2, 2, (4, 3)), rng.uniform(-np.pi, np.pi, 4),
                             rng.uniform(-0.5, 0.5, 4), np.zeros(4)])
    poses = np.concatenate([poses, poses[:2]])  # repeated poses share one call
    pts = rng.uniform(-3, 3, (6, 5, 3))
    ours = antenna_frame_geometry(poses, pts)
    assert ours.d_m.shape == (6, 5)
    for i in range(6):
        ref = prop.antenna_frame_angles(poses[i:i + 1], pts[i])
        # the same function on the same numbers: identical bits
        np.testing.assert_array_equal(ours.alpha_rad[i], ref.alpha_rad[0])
        np.testing.assert_array_equal(ours.d_m[i], ref.d_m[0])
    with pytest.raises(ValueError, match="points must have shape"):
        antenna_frame_geometry(poses, pts[:3])
