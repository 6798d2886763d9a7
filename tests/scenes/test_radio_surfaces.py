"""Radio surfaces: what the ray tracer sees beside the solids (each physical layer once)."""

import dataclasses

import numpy as np
import pytest
import trimesh

import scenes
from scenes.radio import RadioSurface, rectangle_mesh, thickness_token


@pytest.fixture(scope="module")
def lab():
    return scenes.load("corridor_lab")


def _of(scene, material=None, kind=None):
    return [s for s in scene.radio_surfaces
            if (material is None or s.material == material) and (kind is None or s.kind == kind)]


def _plane(s):
    """(axis, coordinate, normal sign) of a planar axis-aligned surface."""
    lo, hi = s.mesh.bounds
    k = int(np.flatnonzero(np.isclose(lo, hi))[0])
    return k, round(float(lo[k]), 9), int(np.sign(s.mesh.face_normals[0, k]))


def test_brick_wall_is_one_surface_per_piece_on_its_inner_face(lab):
    brick = _of(lab, "brick")
    # y = 0 wall: pieces beside the doors D1 (x 3.55-4.45) and D3 (x 16.9-18.1), lintels above them
    assert len(brick) == 5 and all(s.kind == "wall" and s.thickness_m == 0.12 for s in brick)
    assert {_plane(s) for s in brick} == {(1, 0.0, 1)}  # inner face, normal into the corridor
    spans = sorted((*np.round(s.mesh.bounds[:, 0], 6), *np.round(s.mesh.bounds[:, 2], 6)) for s in brick)
    assert spans == [(0.0, 3.55, 0.0, 3.0), (3.55, 4.45, 2.1, 3.0), (4.45, 16.9, 0.0, 3.0),
                     (16.9, 18.1, 2.1, 3.0), (18.1, 25.0, 0.0, 3.0)]
    # the open door D1 has no surface at all: no surface of any material spans its opening
    opening = np.array([[4.0, y, 1.0] for y in (0.0, -0.06, -0.12)])
    for s in lab.radio_surfaces:
        lo, hi = s.mesh.bounds
        assert not np.any(np.all((opening >= lo - 1e-9) & (opening <= hi + 1e-9), axis=1)), s


def test_floor_ceiling_doors_and_shells(lab):
    (floor,) = _of(lab, kind="floor")
    (ceiling,) = _of(lab, kind="ceiling")
    assert (floor.material, floor.thickness_m) == ("concrete", 0.2)
    assert (ceiling.material, ceiling.thickness_m) == ("ceiling_board", 0.02)  # the spec's, not the library's 0.015
    assert np.all(floor.mesh.vertices[:, 2] == 0.0) and np.all(floor.mesh.face_normals[:, 2] == 1.0)
    assert np.all(ceiling.mesh.vertices[:, 2] == 3.0) and np.all(ceiling.mesh.face_normals[:, 2] == -1.0)
    assert floor.area_m2 == pytest.approx(25.24 * 2.64)
    # closed doors D2 (y = 2.4) and D3 (y = 0): one wood surface each, 2 cm behind the wall face
    doors = sorted(_plane(s) for s in _of(lab, kind="door"))
    assert doors == [(1, -0.02, 1), (1, 2.42, -1)]
    assert all(s.material == "wood" and s.thickness_m == 0.04 for s in _of(lab, kind="door"))
    # cabinets and boxes stay closed shells with the library thickness
    metal = _of(lab, "metal")
    assert len(metal) == 3 and all(s.kind == "shell" and s.mesh.is_watertight for s in metal)
    assert all(s.thickness_m == scenes.get_material("metal").thickness_m for s in metal)
    assert len(_of(lab, "chipboard", "shell")) == 5


def test_plasterboard_partition_is_two_leaves(lab):
    pb = _of(lab, "plasterboard")
    assert all(s.kind == "leaf" and s.thickness_m == 0.0125 for s in pb)
    planes = {_plane(s) for s in pb}
    # y = 2.4 (inner, facing the corridor) and y = 2.52 (outer), the end walls x = 0 / 25 and
    # their outer faces x = -0.12 / 25.12, and the outer corners y = -0.12
    assert {(1, 2.4, -1), (1, 2.52, 1), (0, 0.0, 1), (0, -0.12, -1), (0, 25.0, -1), (0, 25.12, 1)} <= planes
    inner = sum(s.area_m2 for s in pb if _plane(s) == (1, 2.4, -1))
    # 25 x 3 m minus the window (2 x 1.2) and the two door openings (0.9 x 2.1 each)
    assert inner == pytest.approx(75.0 - 2.4 - 2 * 0.9 * 2.1)
    # the window in it is one pane of the library's glass (construction = "single" in the
    # scene file; glass would otherwise default to "solid", a slab of the wall thickness)
    (window,) = [s for s in _of(lab, "glass") if _plane(s)[:2] == (1, 2.4)]
    assert window.thickness_m == 0.008 and window.kind == "leaf"


def test_content_hash_covers_radio_surfaces(lab):
    plain = dataclasses.replace(lab, radio_surfaces=None)
    assert plain.content_hash() != lab.content_hash()
    s0 = lab.radio_surfaces[0]
    thicker = dataclasses.replace(lab, radio_surfaces=(dataclasses.replace(s0, thickness_m=0.02),
                                                       *lab.radio_surfaces[1:]))
    assert thicker.content_hash() != lab.content_hash()
    assert scenes.load("corridor_lab").content_hash() == lab.content_hash()


def test_constructions_per_wall_material_and_panel():
    kw = dict(length_m=6.0, width_m=2.0, height_m=2.5)
    solid = scenes.corridor(wall_construction="solid", **kw)
    walls = _of(solid, "plasterboard")
    assert walls and all(s.kind == "wall" and s.thickness_m == 0.12 for s in walls)
    assert len(walls) == 4  # the four inner faces, nothing outside
    panel = {"position_m": (3.0, 2.0), "width_m": 1.0, "sill_m": 1.0, "height_m": 1.0}
    double = scenes.corridor(glass_panels=[dict(panel, construction="double")], **kw)
    panes = sorted(_plane(s) for s in _of(double, "glass"))
    assert panes == [(1, 2.0, -1), (1, 2.12, 1)]
    assert all(s.thickness_m == scenes.get_material("glass").thickness_m for s in _of(double, "glass"))
    # per material: concrete walls as a single leaf of the library thickness (0.2 m)
    single = scenes.corridor(wall_material="concrete", material_construction={"itu_concrete": "single"}, **kw)
    leaves = [s for s in _of(single, "concrete") if s.kind == "leaf"]
    assert len(leaves) == 4 and all(s.thickness_m == 0.2 for s in leaves)
    # a panel's own construction wins over the material's
    mixed = scenes.corridor(material_construction={"glass": "double"},
                            glass_panels=[dict(panel, construction="solid")], **kw)
    assert [s.kind for s in _of(mixed, "glass")] == ["wall"]


def test_construction_keys_in_toml(tmp_path):
    base = ('name = "m"\n[corridor]\nlength_m = 6.0\nwidth_m = 2.0\nwall_construction = "solid"\n'
            'material_construction = { itu_glass = "double" }\n'
            '[[panel]]\nposition_m = [3.0, 2.0]\nwidth_m = 1.0\nconstruction = "single"\n')
    p = tmp_path / "m.toml"
    p.write_text(base)
    spec = scenes.load_spec(p)
    assert spec.corridor.material_construction == {"glass": "double"}
    assert spec.panels[0].construction == "single"
    again = scenes.load_spec(scenes.save_spec(spec, tmp_path / "again.toml"))
    assert scenes.build(again).content_hash() == scenes.build(spec).content_hash()
    p.write_text(base.replace('wall_construction = "solid"', 'wall_construction = "hollow"'))
    with pytest.raises(scenes.SpecError, match=r"m.toml: \[corridor\]: key 'wall_construction' must be one of"):
        scenes.load_spec(p)
    p.write_text(base.replace('construction = "single"', 'construction = "triple"'))
    with pytest.raises(scenes.SpecError, match=r"m.toml: \[\[panel\]\] #1: key 'construction'.*'triple'"):
        scenes.load_spec(p)
    p.write_text(base.replace("itu_glass", "cheese"))
    with pytest.raises(scenes.UnknownMaterialError, match=r"m.toml.*material_construction.*'cheese'"):
        scenes.load_spec(p)
    p.write_text(base.replace("wall_construction", "wall_constructoin"))
    with pytest.raises(scenes.SpecError, match=r"m.toml: \[corridor\]: unknown key 'wall_constructoin'"):
        scenes.load_spec(p)


def _room(tmp_path):
    """A 4 x 3 x 2.5 m room of 0.1 m slabs plus a 0.5 m deep cabinet-like box, one PLY."""
    slabs = [((-0.1, -0.1, -0.1), (4.1, 3.1, 0.0)), ((-0.1, -0.1, 2.5), (4.1, 3.1, 2.6)),
             ((-0.1, -0.1, 0.0), (4.1, 0.0, 2.5)), ((-0.1, 3.0, 0.0), (4.1, 3.1, 2.5)),
             ((-0.1, 0.0, 0.0), (0.0, 3.0, 2.5)), ((4.0, 0.0, 0.0), (4.1, 3.0, 2.5)),
             ((1.0, 0.01, 0.0), (2.0, 0.51, 1.5))]
    ply = tmp_path / "room.ply"
    parts = [scenes.geometry.box_mesh(lo, hi) for lo, hi in slabs]
    ply.write_bytes(trimesh.util.concatenate(parts).export(file_type="ply"))
    return ply


def test_import_radio_geometry_options(tmp_path):
    ply = _room(tmp_path)
    assert scenes.import_mesh(ply, material="concrete").radio_surfaces is None
    single = scenes.import_mesh(ply, material="concrete", radio_geometry="single")
    assert [(s.material, s.thickness_m, len(s.mesh.faces)) for s in single.radio_surfaces] == [
        ("concrete", 0.2, 7 * 12)]
    thin = scenes.import_mesh(ply, material="concrete", radio_geometry="thin_boxes")
    walls = [s for s in thin.radio_surfaces if s.kind == "wall"]
    # the six 0.1 m slabs (vertices merged by the PLY round trip) become one surface each on
    # the face towards the room, carrying 0.1 m; the 0.5 m box stays a closed body
    assert sorted(_plane(s) for s in walls) == [(0, 0.0, 1), (0, 4.0, -1), (1, 0.0, 1), (1, 3.0, -1),
                                                (2, 0.0, 1), (2, 2.5, -1)]
    assert all(s.thickness_m == pytest.approx(0.1) for s in walls)
    (rest,) = [s for s in thin.radio_surfaces if s.kind == "imported"]
    assert rest.mesh.is_watertight and len(rest.mesh.faces) == 12 and rest.thickness_m == 0.2
    mid = scenes.import_mesh(ply, material="concrete", radio_geometry="thin_boxes", thin_box_face="mid",
                             thin_box_max_m=0.6)
    # the PLY holds float32 vertices: 1e-6 m
    np.testing.assert_allclose(sorted(_plane(s)[:2] for s in mid.radio_surfaces)[:2],
                               [(0, -0.05), (0, 4.05)], atol=1e-6)
    assert len(mid.radio_surfaces) == 7  # the 0.5 m box converted too under a 0.6 m threshold
    assert thin.content_hash() != single.content_hash()
    with pytest.raises(ValueError, match="radio_geometry must be one of"):
        scenes.import_mesh(ply, material="concrete", radio_geometry="flat")


def test_rectangles_and_tokens():
    m = rectangle_mesh([0, 0, 1], [2, 3, 1], [0, 0, -1])
    np.testing.assert_allclose(m.face_normals, [[0, 0, -1]] * 2)
    assert m.area == pytest.approx(6.0)
    assert [thickness_token(t) for t in (0.12, 0.0125, 0.2, 1.0)] == ["t0p120", "t0p0125", "t0p200", "t1p000"]
    with pytest.raises(ValueError, match="thickness_m must be positive"):
        RadioSurface("brick", 0.0, m)
