"""Scenes from ROS maps: constructions by rule and by override, radio surfaces (one per
physical layer, racks as shelves and uprights), shelf and CSV tags, the scene TOML's [map]."""

import numpy as np
import pytest

import scenes
from scenes.mapextract import extract_obstacles
from scenes.rosmap import read_map
from scenes.spec import SpecError
from tests.scenes.maphelpers import OCC, RES, building, paint, write_map

PAD, WALL = 0.5, 0.25  # the building's inside starts at 0.75 m

# inside x in [0.75, 12.75], y in [0.75, 8.75]
PARTITION = (0.75, 6.0, 4.0, 6.1)  # 0.1 m thin, joined to the outer wall
RACK = (5.0, 2.0, 10.0, 2.8)  # 0.8 m deep, free-standing
PILLAR = (11.5, 7.5, 11.9, 7.9)
THICK = (6.0, 7.0, 9.0, 7.3)  # 0.3 m, free-standing


def _map(tmp_path, name="site"):
    g = building(width_m=12.0, length_m=8.0, wall_m=WALL, pad_m=PAD)
    for r in (PARTITION, RACK, PILLAR, THICK):
        paint(g, *r, OCC)
    return write_map(tmp_path, g, name=name)


def _by_centre(obstacles, x, y):
    from shapely.geometry import Point

    return min(obstacles, key=lambda o: o.polygon.distance(Point(x, y)))


def test_rules_assign_the_expected_constructions(tmp_path):
    obs = extract_obstacles(read_map(_map(tmp_path)))
    assert len(obs) == 5
    got = {name: (o.kind, o.material, o.construction, o.rule) for name, o in (
        ("outer", _by_centre(obs, 0.6, 4.0)), ("partition", _by_centre(obs, 2.0, 6.05)),
        ("rack", _by_centre(obs, 7.5, 2.4)), ("pillar", _by_centre(obs, 11.7, 7.7)),
        ("thick", _by_centre(obs, 7.5, 7.15)))}
    assert got == {
        "outer": ("wall", "concrete", "solid", "outer"),
        "partition": ("wall", "plasterboard", "stud", "partition"),
        "rack": ("rack", "metal", None, "rack"),
        "pillar": ("pillar", "concrete", None, "pillar"),
        "thick": ("wall", "brick", "solid", "thick wall"),
    }
    thick = _by_centre(obs, 7.5, 7.15)
    # mean thickness = area / centre-line length: within one cell of the drawn 0.3 m
    assert thick.thickness_m == pytest.approx(0.3, abs=RES)
    # the rack's rectangle is snapped to the map's axes, its sides on the cells' edges
    rack = _by_centre(obs, 7.5, 2.4)
    assert rack.rectangle_sides_m == pytest.approx((5.0, 0.8), abs=RES)


def test_radio_surfaces_one_per_layer(tmp_path):
    sc = scenes.load(_map(tmp_path))
    surf = sc.radio_surfaces
    brick = [s for s in surf if s.material == "brick"]
    # a solid wall with free space on both sides: one surface on its centre line, carrying
    # the brick's construction thickness (the library's 0.12 m), not the map's 0.3 m band
    assert len(brick) == 1 and brick[0].kind == "wall"
    assert brick[0].thickness_m == pytest.approx(0.12)
    assert np.allclose(brick[0].mesh.vertices[:, 1], 7.15, atol=RES)
    # a stud partition: two plasterboard leaves of the library thickness, one per face
    leaves = [s for s in surf if s.material == "plasterboard"]
    assert len(leaves) == 2 and {s.thickness_m for s in leaves} == {0.0125}
    ys = sorted(float(s.mesh.vertices[:, 1].mean()) for s in leaves)
    assert ys[1] - ys[0] == pytest.approx(0.1, abs=RES)
    # the rack: per level a metal board and two beams, and uprights; not a block
    metal = [s for s in surf if s.material == "metal"]
    boards = [s for s in metal if s.kind == "shelf" and np.ptp(s.mesh.vertices[:, 2]) == 0]
    assert sorted(float(s.mesh.vertices[0, 2]) for s in boards) == pytest.approx([0.4, 0.9, 1.4, 1.9])
    assert sum(s.kind == "shell" for s in metal) == 2 * (int(np.ceil(5.0 / 1.35)) + 1)
    between = np.array([[7.5, 2.4, 0.6], [7.5, 2.4, 1.1]])  # inside the footprint, between shelves
    assert np.all(scenes.is_free(sc, between))
    assert not np.any(scenes.is_free(sc, [[7.5, 2.4, 0.35], [7.5, 2.4, 0.85]]))  # in the boards
    # floor and ceiling one surface each; free space is the building's inside only
    assert sum(s.kind == "floor" for s in surf) == 1 and sum(s.kind == "ceiling" for s in surf) == 1
    assert scenes.is_free(sc, [[2.0, 2.0, 1.0]])[0] and not scenes.is_free(sc, [[0.2, 0.2, 1.0]])[0]


def test_outer_walls_are_traced_at_their_inside_face(tmp_path):
    """The outer wall's reflector sits at the face the robot sees (set back a cell, the
    skeleton's lean), not half a wall behind it (0.125 m here), and carries the
    construction's thickness; with ``solid_wall_thickness_m = 0`` the map's band."""
    sc = scenes.load(_map(tmp_path))
    outer = [s for s in sc.radio_surfaces if s.material == "concrete" and s.kind == "wall"]
    inner = PAD + WALL  # the inside faces: x = 0.75 and 12.75, y = 0.75 and 8.75
    # the long segments of the four sides (the skeleton leans by up to a cell)
    sides = [s for s in outer if max(np.ptp(s.mesh.vertices[:, 0]), np.ptp(s.mesh.vertices[:, 1])) > 5.0]
    assert len(sides) == 4
    # within 1.5 cells of the inside face (a cell of the map's own raster, and the
    # skeleton's lean); the centre line is 0.125 m = 2.5 cells behind it
    for s in sides:
        v = s.mesh.vertices[:, :2]
        axis = 0 if np.ptp(v[:, 0]) < np.ptp(v[:, 1]) else 1  # the coordinate across the wall
        face = inner if v[0, axis] < 5.0 else (inner + (12.0 if axis == 0 else 8.0))
        assert np.all(np.abs(v[:, axis] - face) <= 1.5 * RES), (axis, v[:, axis], face)
        assert s.thickness_m == pytest.approx(0.2)  # concrete's library thickness
    assert sc.metadata["map"]["solid_walls_at_inside_face"] >= 4
    (tmp_path / "drawn.toml").write_text('[map]\npath = "site.yaml"\nsolid_wall_thickness_m = 0\n')
    drawn = scenes.load(tmp_path / "drawn.toml")
    walls = [s for s in drawn.radio_surfaces if s.material == "concrete" and s.kind == "wall"]
    assert all(s.thickness_m == pytest.approx(WALL, abs=RES) for s in walls)


def _hits(scene, origins, directions, max_m):
    """Whether each ray meets a traced wall surface within ``max_m`` (Moller-Trumbore on
    the surfaces' triangles, in NumPy)."""
    tri = np.concatenate([s.mesh.vertices[s.mesh.faces] for s in scene.radio_surfaces
                          if s.kind == "wall"])  # (T, 3, 3)
    o = np.asarray(origins, float)[:, None, :]
    d = np.asarray(directions, float)[:, None, :]
    e1, e2 = tri[None, :, 1] - tri[None, :, 0], tri[None, :, 2] - tri[None, :, 0]
    p = np.cross(d, e2)
    det = np.einsum("rtk,rtk->rt", e1, p)
    ok = np.abs(det) > 1e-12
    inv = np.where(ok, 1.0 / np.where(ok, det, 1.0), 0.0)
    s_ = o - tri[None, :, 0]
    u = np.einsum("rtk,rtk->rt", s_, p) * inv
    q = np.cross(s_, e1)
    v = np.einsum("rtk,rtk->rt", d, q) * inv
    t = np.einsum("rtk,rtk->rt", e2, q) * inv
    hit = ok & (u >= 0) & (v >= 0) & (u + v <= 1) & (t > 0) & (t <= max_m)
    return hit.any(axis=1)


def test_wall_tags_stay_in_front_of_the_traced_wall(tmp_path):
    """No wall tag has its wall's traced surface between it and the room: a link from a
    tag would otherwise cross the 0.2 m slab it is stuck on."""
    g = building(width_m=8.0, length_m=6.0, wall_m=0.25, pad_m=0.5)
    write_map(tmp_path, g, name="room")
    (tmp_path / "room.toml").write_text('[map]\npath = "room.yaml"\n[tags]\nwalls = true\n')
    sc = scenes.load(tmp_path / "room.toml")
    assert len(sc.tags) > 10
    p, n = sc.tags.positions_m, sc.tags.normals
    # from 0.3 m in front of each tag back to the tag: no wall surface on the way
    assert not _hits(sc, p + 0.3 * n, -n, 0.3 - 1e-4).any()


def test_an_inner_corner_of_the_building_has_no_gap(tmp_path):
    """At a corner where the inside bends round (an L-shaped building) the two shifted
    wall segments still meet: every ray from the room into the corner meets a wall."""
    g = building(width_m=8.0, length_m=6.0, wall_m=0.2, pad_m=0.5)
    paint(g, 4.8, 3.8, 9.5, 7.5, OCC)  # the walls of the notch ...
    paint(g, 5.0, 4.0, 9.5, 7.5, 205)  # ... and the outside it cuts into the building
    path = write_map(tmp_path, g, name="ell")
    sc = scenes.load(path)
    # from the room at the notch's corner (4.8, 3.8): 0.7 m away, +-20 deg around it
    ang = np.radians(np.linspace(25.0, 65.0, 81))
    d = np.column_stack([np.cos(ang), np.sin(ang), np.zeros_like(ang)])
    o = np.tile([4.3, 3.3, 1.0], (len(ang), 1))
    assert _hits(sc, o, d, 2.0).all()


def test_shelf_tags_on_the_fronts(tmp_path):
    yaml = _map(tmp_path)
    # a bare map: one row at the beam nearest 1 m (0.85 m), 1 m apart: (5 - 2 x 0.2) / 1 + 1 = 5
    bare = scenes.load(yaml).tags
    assert len(bare) == 2 * 5 and set(np.round(bare.positions_m[:, 2], 3)) == {0.85}
    # a scene TOML's [tags] defaults: every beam, 0.5 m apart
    (tmp_path / "site.toml").write_text(f'[map]\npath = "{yaml.name}"\n')
    sc = scenes.load(tmp_path / "site.toml")
    tags = sc.tags
    # both long faces of the one rack look onto free space; 4 beams; (5 - 2 x 0.2) / 0.5 + 1 = 10
    assert len(tags) == 2 * 4 * 10
    y = tags.positions_m[:, 1]
    assert set(np.round(y, 3)) == {1.995, 2.805}  # 5 mm in front of the faces y = 2.0, 2.8
    assert np.all(np.sign(tags.normals[:, 1]) == np.where(y > 2.4, 1, -1))
    assert set(np.round(tags.positions_m[:, 2], 3)) == {0.35, 0.85, 1.35, 1.85}  # mid-beam
    x = np.sort(np.unique(np.round(tags.positions_m[:, 0], 6)))
    assert np.allclose(np.diff(x), 0.5) and x[0] >= 5.0 + 0.2 - 1e-9 and x[-1] <= 10.0 - 0.2 + 1e-9
    assert set(scenes.solid_material_at(sc, tags.positions_m - 0.01 * tags.normals)) == {"metal"}


def test_toml_overrides_and_tag_layouts(tmp_path):
    _map(tmp_path)
    (tmp_path / "tags.csv").write_text("id,x_m,y_m,z_m,nx,ny,nz\nW1,2.0,0.75,1.0,0,1,0\n")
    (tmp_path / "site.toml").write_text(
        'name = "site"\n'
        '[map]\npath = "site.yaml"\nheight_m = 3.5\n'
        '[[map.override]]\npoint_m = [2.0, 6.05]\nmaterial = "glass"\nconstruction = "double"\n'
        '[[map.override]]\npolygon_m = [[5.5, 6.5], [9.5, 6.5], [9.5, 7.8], [5.5, 7.8]]\nmaterial = "concrete"\n'
        '[tags]\nlayout = "csv"\ncsv = "tags.csv"\n')
    sc = scenes.load(tmp_path / "site.toml")
    glass = [s for s in sc.radio_surfaces if s.material == "glass"]
    assert len(glass) == 2 and all(s.kind == "leaf" for s in glass)  # double glazing: two panes
    assert not any(s.material == "brick" for s in sc.radio_surfaces)
    rules = {o["rule"] for o in sc.metadata["map"]["obstacles"]}
    assert "override" in rules
    assert sc.tags.ids.tolist() == ["W1"]
    assert sc.bounds_m[1, 2] == pytest.approx(3.5 + 0.05)


@pytest.mark.parametrize("table, message", [
    ('[map]\npath = "site.yaml"\nwall_height_m = 3.0\n', r"\[map\]: unknown key 'wall_height_m'"),
    ('[map]\npath = "site.yaml"\n[[map.override]]\npoint_m = [0.1, 0.1]\nmaterial = "brick"\n',
     r"\[\[map.override\]\] #1: point_m \[0.1, 0.1\] matches no obstacle"),
    ('[map]\npath = "site.yaml"\n[[map.override]]\npoint_m = [2.0, 6.05]\nkind = "pillar"\n'
     'construction = "stud"\n', r"'construction' applies to walls only"),
    ('[map]\npath = "site.yaml"\n[tags]\nheights_m = [0.6]\n', r"\[tags\] key 'heights_m': 0.6 m is on no front beam"),
    ('[map]\npath = "site.yaml"\n[tags]\nlayout = "aisles"\n', r"\[tags\]: key 'layout' must be one of"),
])
def test_bad_map_tables_name_the_key(tmp_path, table, message):
    _map(tmp_path)
    (tmp_path / "bad.toml").write_text(table)
    with pytest.raises((SpecError, ValueError), match=message) as err:
        scenes.load(tmp_path / "bad.toml")
    assert "\n" not in str(err.value) and "bad.toml" in str(err.value)


def test_bundled_warehouse_loads():
    sc = scenes.load("warehouse_small")
    assert "warehouse_small" in scenes.list_bundled()
    kinds = [o["kind"] for o in sc.metadata["map"]["obstacles"]]
    assert kinds.count("rack") == 4 and kinds.count("pillar") == 2
    assert len(sc.tags) == 4 * 2 * 2 * 12  # racks x faces x heights x tags per 12 m front
    raw = scenes.load(scenes.bundled_path("warehouse_small").with_suffix(".yaml"))
    assert len(raw.tags) == 4 * 2 * 1 * 12  # the map alone: one row, 1 m apart


def test_bundled_warehouse_scale_case_loads():
    # issue 34's scale case: ~30 m x 50 m inside, >= 500 tags (8 racks x 2 faces x 40 per
    # 40 m front at 1 m, one height), a PNG map image (map_server reads PNG too)
    sc = scenes.load("warehouse_large")
    kinds = [o["kind"] for o in sc.metadata["map"]["obstacles"]]
    assert kinds.count("rack") == 8
    assert len(sc.tags) == 8 * 2 * 40
    lo, hi = sc.bounds_m
    assert 29.0 < hi[0] - lo[0] < 32.0 and 49.0 < hi[1] - lo[1] < 52.0  # outer wall included
    assert scenes.bundled_path("warehouse_large").with_suffix(".png").exists()


def test_a_waypoint_list_is_kept(tmp_path):
    from pipeline.robot import Robot
    from pipeline.studyscene import map_route

    _map(tmp_path)
    (tmp_path / "route.toml").write_text(
        'route_m = [[1.5, 1.5], [11.5, 1.5], [11.5, 5.0]]\n[map]\npath = "site.yaml"\n')
    sc = scenes.load(tmp_path / "route.toml")
    assert sc.route_m.tolist() == [[1.5, 1.5], [11.5, 1.5], [11.5, 5.0]]
    assert map_route(sc, Robot()) is sc  # no planning over a given route


def test_override_material_takes_its_default_construction(tmp_path):
    from scenes.mapextract import apply_override

    obs = extract_obstacles(read_map(_map(tmp_path)))
    out = apply_override(obs, "t", point_m=(2.0, 6.05), material="brick", snap_m=RES)
    part = _by_centre(out, 2.0, 6.05)
    assert (part.kind, part.material, part.construction, part.rule) == ("wall", "brick", "solid", "override")
    out = apply_override(obs, "t", point_m=(7.5, 7.15), material="plasterboard", snap_m=RES)
    assert _by_centre(out, 7.5, 7.15).construction == "stud"
    out = apply_override(obs, "t", point_m=(7.5, 2.4), kind="wall", snap_m=RES)
    assert (_by_centre(out, 7.5, 2.4).material, _by_centre(out, 7.5, 2.4).construction) == ("metal", "solid")
