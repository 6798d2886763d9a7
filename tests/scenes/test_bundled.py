"""Bundled scenes: load, tags, routes, content hash."""

import numpy as np
import pytest

import scenes


def test_list_bundled():
    assert {"corridor_lab", "glass_metal_junction"} <= set(scenes.list_bundled())


def test_unknown_bundled_name_lists_known():
    with pytest.raises(ValueError, match="unknown bundled scene 'corridor_lob'.*corridor_lab"):
        scenes.load("corridor_lob")


@pytest.mark.parametrize("name", ["corridor_lab", "glass_metal_junction"])
def test_bundled_scene_is_sound(name):
    s = scenes.load(name)
    assert len(s.tags) >= 20
    z = s.tags.positions_m[:, 2]
    assert z.min() <= 0.35 and z.max() >= 1.45  # several heights, 0.3 to 1.5 m
    assert np.all(scenes.is_free(s, s.tags.positions_m))
    # each tag sits 5 mm in front of a surface: the nearest face is within 5 mm (+ rounding)
    dist = scenes.closest_surface(s, s.tags.positions_m).distance_m
    np.testing.assert_allclose(dist, 0.005, atol=1e-9)
    # tags face both ways across the corridor
    assert {1.0, -1.0} <= set(np.round(s.tags.normals[:, 1], 6).tolist())
    assert s.route_m.shape[1] == 2 and len(s.route_m) >= 2
    assert sum(len(m.faces) for m in s.meshes.values()) < 1000  # coarse meshes


def test_corridor_lab_dimensions():
    s = scenes.load("corridor_lab")
    np.testing.assert_allclose(s.free_space_m, [[[0, 0, 0], [25.0, 2.4, 3.0]]])
    assert {"concrete", "plasterboard", "brick", "ceiling_board", "metal", "glass"} <= set(s.materials)
    # the brick wall is at y = 0 and the plasterboard partition at y = 2.4 (z = 1.8, x = 9)
    mats = scenes.solid_material_at(s, [[9.0, -0.06, 1.8], [9.0, 2.46, 1.8]])
    assert mats.tolist() == ["brick", "plasterboard"]


def test_content_hash_stable_and_sensitive():
    a, b = scenes.load("corridor_lab"), scenes.load("corridor_lab")
    assert a.content_hash() == b.content_hash()
    moved = scenes.TagSet(b.tags.ids, b.tags.positions_m + [0.0, 0.0, 0.01], b.tags.normals)
    b.tags = moved
    assert a.content_hash() != b.content_hash()
    c = scenes.load("corridor_lab")
    c.meshes["glass"] = c.meshes["glass"].copy()
    c.meshes["glass"].vertices += [0.0, 0.0, 0.001]
    assert a.content_hash() != c.content_hash()
    d = scenes.load("corridor_lab")
    d.meshes["marble"] = d.meshes.pop("glass")  # same geometry, other material
    assert a.content_hash() != d.content_hash()


def test_summary_numbers():
    sm = scenes.summarize(scenes.load("corridor_lab"))
    assert sm.size_m == pytest.approx((25.24, 2.64, 3.22))  # free space + 0.12 walls, 0.2 + 0.02 slabs
    assert sm.route_length_m == pytest.approx(23.8)  # 0.6 m short of each end wall
    assert sm.n_tags == 24 and sm.n_triangles == sum(sm.triangles_per_material.values())
    assert sm.tag_height_range_m == pytest.approx((0.25, 1.5))
