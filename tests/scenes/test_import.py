"""Mesh import (PLY, GLB) and Mitsuba/Sionna XML scenes."""

import importlib.util
from pathlib import Path

import numpy as np
import pytest
import trimesh

import scenes


def _room(tmp_path):
    """A 4 x 3 x 2.5 m closed room of 0.1 m slabs as one PLY, plus a GLB of two named parts."""
    slabs = [((-0.1, -0.1, -0.1), (4.1, 3.1, 0.0)), ((-0.1, -0.1, 2.5), (4.1, 3.1, 2.6)),
             ((-0.1, -0.1, 0.0), (4.1, 0.0, 2.5)), ((-0.1, 3.0, 0.0), (4.1, 3.1, 2.5)),
             ((-0.1, 0.0, 0.0), (0.0, 3.0, 2.5)), ((4.0, 0.0, 0.0), (4.1, 3.0, 2.5))]
    parts = [scenes.geometry.box_mesh(lo, hi) for lo, hi in slabs]
    ply = tmp_path / "room.ply"
    ply.write_bytes(trimesh.util.concatenate(parts).export(file_type="ply"))
    glb = tmp_path / "room.glb"
    sc = trimesh.Scene()
    sc.add_geometry(trimesh.util.concatenate(parts[:2]), geom_name="slabs", node_name="slabs")
    sc.add_geometry(trimesh.util.concatenate(parts[2:]), geom_name="walls", node_name="walls")
    glb.write_bytes(sc.export(file_type="glb"))
    return ply, glb


TAG = {"id": "T01", "position_m": (2.0, 0.0, 1.0), "normal": (0.0, 1.0, 0.0)}


def test_import_ply_one_material(tmp_path):
    ply, _ = _room(tmp_path)
    s = scenes.import_mesh(ply, material="itu_concrete", tags=[TAG])
    assert s.materials == ["concrete"]
    assert len(s.meshes["concrete"].faces) == 6 * 12
    np.testing.assert_allclose(s.tags.positions_m, [[2.0, 0.005, 1.0]])
    # PLY import merges the slabs' shared vertices: containment still works (winding number)
    inside = scenes.inside_solid(s, [[2.0, -0.05, 1.0], [2.0, 1.5, 1.0], [-0.05, -0.05, 2.55]])
    assert inside.tolist() == [True, False, True]


def test_import_glb_material_map(tmp_path):
    _, glb = _room(tmp_path)
    s = scenes.import_mesh(glb, material_map={"slabs": "concrete", "walls": "brick"}, tags=[TAG])
    assert s.materials == ["brick", "concrete"]
    assert len(s.meshes["brick"].faces) == 4 * 12 and len(s.meshes["concrete"].faces) == 2 * 12
    with pytest.raises(ValueError, match="geometry 'walls'.*has no material"):
        scenes.import_mesh(glb, material_map={"slabs": "concrete"})
    with pytest.raises(ValueError, match="material_map key 'wals' matches no geometry"):
        scenes.import_mesh(glb, material="brick", material_map={"wals": "glass"})


def test_import_errors(tmp_path):
    ply, _ = _room(tmp_path)
    with pytest.raises(FileNotFoundError, match="missing.ply"):
        scenes.import_mesh(tmp_path / "missing.ply", material="concrete")
    with pytest.raises(scenes.UnknownMaterialError, match="'styrofoam'"):
        scenes.import_mesh(ply, material="styrofoam")
    with pytest.raises(ValueError, match="'T01'.*inside solid"):
        scenes.import_mesh(ply, material="concrete",
                           tags=[dict(TAG, position_m=(2.0, -0.05, 1.0))])
    with pytest.raises(FileNotFoundError, match="nowhere.glb"):
        scenes.load(tmp_path / "nowhere.glb", material="concrete")


def test_mesh_spec_toml(tmp_path):
    ply, _ = _room(tmp_path)
    (tmp_path / "room.toml").write_text(
        'name = "room"\nroute_m = [[0.5, 1.5], [3.5, 1.5]]\n'
        'tag = [{ id = "T01", position_m = [2.0, 0.0, 1.0] }]\n'
        '[mesh]\npath = "room.ply"\nmaterial = "concrete"\n')
    s = scenes.load(tmp_path / "room.toml")
    assert s.name == "room" and s.route_m.shape == (2, 2)
    np.testing.assert_allclose(s.tags.normals, [[0, 1, 0]], atol=1e-12)  # from the face
    (tmp_path / "bad.toml").write_text('[mesh]\npath = "gone.ply"\nmaterial = "concrete"\n')
    with pytest.raises(FileNotFoundError, match="gone.ply"):
        scenes.load(tmp_path / "bad.toml")


def _sionna_scene(name: str) -> Path:
    # locate Sionna's bundled scenes without importing sionna (and so mitsuba/drjit)
    spec = importlib.util.find_spec("sionna.rt")
    if spec is None:
        pytest.skip("sionna-rt not installed")
    return Path(spec.submodule_search_locations[0]) / "scenes" / name / f"{name}.xml"


def test_load_sionna_street_canyon():
    xml = _sionna_scene("simple_street_canyon")
    s = scenes.load(xml)
    # itu-radio-material types glass, wood, marble, brick, concrete map onto the library
    assert {"glass", "wood", "marble", "brick", "concrete"} <= set(s.materials)
    assert s.route_m is None and len(s.tags) == 0
    assert s.bounds_m[1, 2] > 10  # buildings tens of metres tall


@pytest.mark.filterwarnings("ignore::scenes.FrequencyRangeWarning")
def test_export_then_load_round_trip(tmp_path):
    lab = scenes.load("corridor_lab")
    xml = lab.export_mitsuba(tmp_path / "lab", 865e6)
    (tmp_path / "lab" / "scene.tags.toml").write_text(
        'route_m = [[0.6, 1.2], [24.4, 1.2]]\n'
        'tag = [{ id = "T01", position_m = [1.0, 0.0, 0.6], normal = [0.0, 1.0, 0.0] }]\n')
    # the export holds what the tracer sees (the radio surfaces, one shape per material and
    # thickness), not the solids: declared single surfaces, it loads back as that geometry
    back = scenes.load_mitsuba_xml(xml, radio_geometry="single")
    assert back.materials == lab.materials
    want, got = scenes.radio_groups(lab), scenes.radio_groups(back)
    assert [g.token for g in got] == [g.token for g in want]
    for g, w in zip(got, want, strict=True):
        assert g.thickness_m == w.thickness_m and len(g.mesh.faces) == len(w.mesh.faces)
        np.testing.assert_allclose(g.mesh.bounds, w.mesh.bounds, atol=1e-6)
    np.testing.assert_allclose(back.tags.positions_m, lab.tags.positions_m[:1])
    np.testing.assert_allclose(back.route_m, lab.route_m)
    # as_is (the default) keeps the triangles but forgets the thicknesses: library values
    plain = scenes.load(xml)
    assert plain.radio_surfaces is None and plain.materials == lab.materials
    assert {g.token for g in scenes.radio_groups(plain)} >= {"ceiling_board-t0p015", "brick-t0p120"}


def test_xml_errors(tmp_path):
    xml = tmp_path / "s.xml"
    xml.write_text('<scene version="2.1.0"><bsdf type="itu-radio-material" id="m">'
                   '<string name="type" value="concrete"/></bsdf>'
                   '<shape type="ply" id="mesh-a"><string name="filename" value="meshes/a.ply"/>'
                   '<ref id="m" name="bsdf"/></shape></scene>')
    with pytest.raises(FileNotFoundError, match="a.ply"):
        scenes.load(xml)
    xml.write_text('<scene version="2.1.0"><bsdf type="radio-material" id="mat-custom"/>'
                   '<shape type="rectangle" id="r"><ref id="mat-custom" name="bsdf"/></shape></scene>')
    with pytest.raises(scenes.UnknownMaterialError, match="mat-custom"):
        scenes.load(xml)


def test_xml_rectangle_with_transform(tmp_path):
    xml = tmp_path / "r.xml"
    xml.write_text('<scene version="2.1.0"><bsdf type="itu-radio-material" id="g">'
                   '<string name="type" value="metal"/></bsdf>'
                   '<shape type="rectangle" id="r"><transform name="to_world">'
                   '<scale x="2" y="3"/><translate x="1" y="0" z="0.5"/></transform>'
                   '<ref id="g" name="bsdf"/></shape></scene>')
    s = scenes.load(xml)
    np.testing.assert_allclose(s.meshes["metal"].bounds, [[-1, -3, 0.5], [3, 3, 0.5]])
