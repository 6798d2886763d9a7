"""Corridor generator: geometry, openings, one mesh per material, validation errors."""

import numpy as np
import pytest

import scenes

L, W, H, T = 10.0, 2.4, 3.0, 0.12
DOWN, UP = (0.0, -1.0, 0.0), (0.0, 1.0, 0.0)


def _corridor(**kw):
    args = dict(length_m=L, width_m=W, height_m=H, wall_thickness_m=T)
    args.update(kw)
    return scenes.corridor(**args)


@pytest.fixture(scope="module")
def furnished():
    return _corridor(
        doors=[{"id": "D1", "position_m": (3.0, 0.0), "width_m": 1.0, "height_m": 2.0},
               {"id": "D2", "position_m": (6.0, W), "closed": True}],
        glass_panels=[{"position_m": (8.0, W), "width_m": 1.0, "sill_m": 1.0, "height_m": 1.0}],
        boxes=[{"id": "B1", "center_m": (1.0, 0.21), "size_m": (0.6, 0.4, 0.4)},
               {"id": "B2", "center_m": (5.0, 1.9), "size_m": (0.6, 0.4, 0.4), "yaw_deg": 30.0}],
        cabinets=[{"id": "C1", "center_m": (8.0, 0.26), "size_m": (1.0, 0.5, 1.9)}],
        tags=[{"id": "T01", "position_m": (2.0, 0.0, 1.0), "normal": UP},
              {"id": "T02", "position_m": (4.5, W, 0.5)},  # normal taken from the wall
              {"id": "T03", "position_m": (1.0, 0.41, 0.2), "normal": UP}],
    )


def test_wall_inner_faces_where_specified(furnished):
    # from the centre line at 1 m height, rays across the corridor hit the walls' inner faces
    origins = np.array([[1.5, W / 2, 1.0], [1.5, W / 2, 1.0], [5.0, W / 2, 2.5]])
    d = scenes.raycast(furnished, origins, [DOWN, UP, (1.0, 0.0, 0.0)])
    # exact plane intersections: only floating-point rounding separates them from W/2
    np.testing.assert_allclose(d[:2], [W / 2, W / 2], atol=1e-9)
    assert d[2] == pytest.approx(L - 5.0, abs=1e-9)  # the end wall at x = L
    up = scenes.raycast(furnished, [[1.5, 1.2, 1.0]], [(0, 0, 1)])[0]
    assert up == pytest.approx(H - 1.0, abs=1e-9)


def test_floor_plan_has_both_faces_of_each_wall(furnished):
    seg = scenes.floor_plan_segments(furnished, 1.0)
    horizontal = seg[np.isclose(seg[:, 0, 1], seg[:, 1, 1])]
    ys = np.unique(np.round(horizontal[:, 0, 1], 9))
    for y in (-T, 0.0, W, W + T):
        assert np.any(np.isclose(ys, y)), f"no wall face at y = {y}"


def test_door_gap_is_open_and_lintel_is_not(furnished):
    # through the open door D1 (x = 3, 1 m wide, 2 m high): nothing at all is hit
    assert np.isinf(scenes.raycast(furnished, [[3.0, 1.2, 1.0]], [DOWN])[0])
    assert np.isinf(scenes.raycast(furnished, [[2.6, 1.2, 1.9]], [DOWN])[0])
    # above the door (z = 2.5) the wall is still there
    assert scenes.raycast(furnished, [[3.0, 1.2, 2.5]], [DOWN])[0] == pytest.approx(1.2, abs=1e-9)
    # just beside the door the wall is there too
    assert scenes.raycast(furnished, [[3.6, 1.2, 1.0]], [DOWN])[0] == pytest.approx(1.2, abs=1e-9)


def test_closed_door_leaf_is_recessed_wood(furnished):
    d = scenes.raycast(furnished, [[6.0, 1.2, 1.0]], [UP])[0]
    assert d == pytest.approx(1.2 + 0.02, abs=1e-9)  # default recess 2 cm behind the face
    assert "wood" in furnished.meshes


def test_glass_panel_replaces_wall_section(furnished):
    pts = np.array([[8.0, W + T / 2, 1.5], [8.0, W + T / 2, 0.5], [8.0, W + T / 2, 2.5]])
    assert scenes.solid_material_at(furnished, pts).tolist() == ["glass", "plasterboard", "plasterboard"]


def test_one_mesh_per_material_and_coarse(furnished):
    assert furnished.materials == sorted(
        ["chipboard", "ceiling_board", "concrete", "glass", "metal", "plasterboard", "wood"])
    n_tri = sum(len(m.faces) for m in furnished.meshes.values())
    assert n_tri % 12 == 0  # every solid is a 12-triangle box
    assert n_tri <= 25 * 12  # a handful of boxes, not a tessellation


def test_free_space_and_solids(furnished):
    pts = np.array([
        [0.5, 1.2, 1.0],   # corridor air
        [1.0, 0.21, 0.2],  # inside box B1
        [5.0, 1.9 - 0.2, 0.2],  # inside yawed box B2 (winding-number path): the line
        [5.0, 1.9 - 0.25, 0.2],  # x = 5 crosses it over +-0.2 / cos(30 deg) = +-0.231 m
        [8.0, 0.26, 1.0],  # inside cabinet C1
        [3.0, -0.06, 1.0],  # in the open door D1: not walkable (outside the corridor)
        [4.0, -0.06, 1.0],  # inside the wall
        [5.0, 1.2, 3.01],  # inside the ceiling
    ])
    assert scenes.is_free(furnished, pts).tolist() == [True, False, False, True, False, False,
                                                       False, False]
    assert scenes.inside_solid(furnished, pts).tolist() == [False, True, True, False, True, False,
                                                            True, True]


def test_tags_offset_from_surface(furnished):
    t = furnished.tags
    assert t.ids.tolist() == ["T01", "T02", "T03"]
    np.testing.assert_allclose(t.positions_m[0], [2.0, 0.005, 1.0])
    np.testing.assert_allclose(t.normals[1], [0, -1, 0], atol=1e-12)  # inferred from the wall
    np.testing.assert_allclose(t.positions_m[1], [4.5, W - 0.005, 0.5])


def test_route_and_metadata(furnished):
    np.testing.assert_allclose(furnished.route_m, [[0.6, 1.2], [L - 0.6, 1.2]])
    assert furnished.metadata["spec"]["corridor"]["length_m"] == L
    np.testing.assert_allclose(furnished.free_space_m, [[[0, 0, 0], [L, W, H]]])


def test_l_junction_route_and_walls():
    s = scenes.corridor(segments=[{"min_m": (0, 0), "max_m": (10, 2)},
                                  {"min_m": (8, 0), "max_m": (10, 8)}], height_m=2.5)
    np.testing.assert_allclose(s.route_m, [[0.6, 1.0], [9.0, 1.0], [9.0, 7.4]])
    # the inner corner: walls of both legs meet at (8, 2); a ray from the corner square
    # towards -x... runs along y = 1.5 through the first leg to its end wall at x = 0
    assert scenes.raycast(s, [[9.0, 1.5, 1.0]], [(-1, 0, 0)])[0] == pytest.approx(9.0, abs=1e-9)
    # up the second leg from y = 1 the end wall is at y = 8
    assert scenes.raycast(s, [[9.0, 1.0, 1.0]], [UP])[0] == pytest.approx(7.0, abs=1e-9)
    # at y = 5 the first leg's free space is gone: x = 5 is wall-free outside (not walkable)
    assert scenes.is_free(s, [[9.0, 5.0, 1.0], [5.0, 5.0, 1.0], [7.95, 5.0, 1.0]]).tolist() == [
        True, False, False]


def test_tag_inside_wall_is_rejected_by_id():
    with pytest.raises(ValueError, match=r"tag 'T09' at \(2, -0.05, 1\) m lies inside solid"):
        _corridor(tags=[{"id": "T09", "position_m": (2.0, -0.055, 1.0), "normal": UP}])


def test_tag_inside_box_is_rejected():
    with pytest.raises(ValueError, match="'TB'.*inside solid geometry.*chipboard"):
        _corridor(boxes=[{"center_m": (1.0, 1.0), "size_m": (0.5, 0.5, 0.5)}],
                  tags=[{"id": "TB", "position_m": (1.0, 1.0, 0.2), "normal": UP}])


def test_tag_in_the_air_and_outside_bounds_rejected():
    with pytest.raises(ValueError, match="'TA'.*from the nearest surface"):
        _corridor(tags=[{"id": "TA", "position_m": (2.0, 1.2, 1.0), "normal": UP}])
    with pytest.raises(ValueError, match="'TO'.*outside the scene bounds"):
        _corridor(tags=[{"id": "TO", "position_m": (50.0, 1.2, 1.0), "normal": UP}])


def test_door_wider_than_wall_rejected():
    with pytest.raises(ValueError, match=r"door D9 \(width_m = 3\) does not fit"):
        _corridor(doors=[{"id": "D9", "position_m": (L, 1.2), "width_m": 3.0}])


def test_door_not_on_a_wall_rejected():
    with pytest.raises(ValueError, match="door D8 at .* is not on any wall"):
        _corridor(doors=[{"id": "D8", "position_m": (5.0, 1.2)}])


def test_door_taller_than_ceiling_rejected():
    with pytest.raises(ValueError, match="height_m 3.5 exceeds the ceiling"):
        _corridor(doors=[{"id": "D7", "position_m": (5.0, 0.0), "height_m": 3.5}])


def test_box_into_wall_rejected():
    with pytest.raises(ValueError, match="box B7 .* reaches outside the free space"):
        _corridor(boxes=[{"id": "B7", "center_m": (5.0, 0.1), "size_m": (0.5, 0.5, 0.5)}])


def test_unknown_material_rejected_by_name():
    with pytest.raises(scenes.UnknownMaterialError, match="kryptonite"):
        _corridor(wall_material="kryptonite")
    with pytest.raises(scenes.UnknownMaterialError, match="adamantium"):
        _corridor(cabinets=[{"center_m": (5, 1), "size_m": (1, 0.5, 1), "material": "adamantium"}])


def test_unknown_item_key_rejected_by_name():
    with pytest.raises(scenes.SpecError, match="unknown key 'widht_m'"):
        _corridor(doors=[{"position_m": (5.0, 0.0), "widht_m": 1.0}])
