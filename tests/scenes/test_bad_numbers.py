"""Numbers that are not numbers (TOML nan/inf) and empty or garbage mesh files are
refused when the scene is read, naming the file, the item and the value (issue 12)."""

import numpy as np
import pytest

import scenes
from scenes import TagSet
from scenes.importers import import_mesh, load_mitsuba_xml
from scenes.spec import SpecError, TagSpec
from scenes.tags import make_tags

TAG_OK = '{ id = "T01", position_m = [1.0, 0.0, 1.0], normal = [0.0, 1.0, 0.0] }'
CORRIDOR = "[corridor]\nlength_m = {length}\nwidth_m = {width}\nheight_m = 2.5\n"


def _spec(tmp_path, tag=TAG_OK, length="6.0", width="2.0", extra=""):
    p = tmp_path / "scene.toml"
    p.write_text(f'name = "s"\ntag = [{tag}]\n' + CORRIDOR.format(length=length, width=width) + extra)
    return p


def test_nan_tag_normal_is_refused_not_replaced(tmp_path):
    valid = scenes.load(_spec(tmp_path))
    bad = _spec(tmp_path, tag='{ id = "T01", position_m = [1.0, 0.0, 1.0], normal = [nan, nan, nan] }')
    with pytest.raises(SpecError, match=r"scene\.toml: \[\[tag\]\] #1 \(id 'T01'\): key 'normal' "
                                        r"must hold finite numbers, got \[nan, nan, nan\]"):
        scenes.load(bad)
    # an absent normal still comes from the nearest face
    absent = scenes.load(_spec(tmp_path, tag='{ id = "T01", position_m = [1.0, 0.0, 1.0] }'))
    np.testing.assert_allclose(absent.tags.normals, valid.tags.normals)


def test_nan_normal_from_the_api_is_refused():
    scene = scenes.load("corridor_lab")
    with pytest.raises(ValueError, match=r"#1 \(id 'X1'\): key 'normal' must hold finite"):
        make_tags(scene, [TagSpec("X1", (1.0, 0.005, 1.0), (np.nan, np.nan, np.nan))])
    with pytest.raises(ValueError, match=r"normals of tags \['a'\] contain NaN"):
        TagSet(["a"], [[0.0, 0.0, 1.0]], [[np.nan, 0.0, 0.0]])
    with pytest.raises(ValueError, match=r"positions_m of tags \['a'\] contain NaN"):
        TagSet(["a"], [[0.0, np.inf, 1.0]], [[0.0, 1.0, 0.0]])


@pytest.mark.parametrize(("length", "width", "key", "value"), [
    ("nan", "2.0", "length_m", "nan"), ("inf", "2.0", "length_m", "inf"),
    ("6.0", "-inf", "width_m", "-inf"), ("6.0", "nan", "width_m", "nan")])
def test_non_finite_corridor_sizes(tmp_path, length, width, key, value):
    with pytest.raises(SpecError, match=rf"scene\.toml: \[corridor\]: key '{key}' must be a finite "
                                        rf"number, got {value}"):
        scenes.load(_spec(tmp_path, length=length, width=width))


def test_non_finite_items_name_the_item(tmp_path):
    tag = '{ id = "T07", position_m = [1.0, nan, 1.0], normal = [0.0, 1.0, 0.0] }'
    with pytest.raises(SpecError, match=r"scene\.toml: \[\[tag\]\] #1 \(id 'T07'\): key 'position_m' "
                                        r"must hold finite numbers, got \[1\.0, nan, 1\.0\]"):
        scenes.load(_spec(tmp_path, tag=tag))
    door = '[[door]]\nposition_m = [inf, 0.0]\n'
    with pytest.raises(SpecError, match=r"\[\[door\]\] #1: key 'position_m' must hold finite numbers"):
        scenes.load(_spec(tmp_path, extra=door))
    route = _spec(tmp_path).read_text().replace('name = "s"', 'name = "s"\nroute_m = [[0.5, 1.0], [nan, 1.0]]')
    (tmp_path / "r.toml").write_text(route)
    with pytest.raises(SpecError, match=r"r\.toml: key 'route_m\[1\]' must hold finite numbers"):
        scenes.load(tmp_path / "r.toml")


PLY_NO_FACES = ("ply\nformat ascii 1.0\nelement vertex 0\nproperty float x\nproperty float y\n"
                "property float z\nelement face 0\nproperty list uchar int vertex_indices\nend_header\n")


@pytest.mark.parametrize(("content", "why"), [
    (b"", "cannot read it as a mesh"), (b"\x00\x01garbage not a ply at all\n" * 10, "cannot read it as a mesh"),
    (PLY_NO_FACES.encode(), "no triangles")])
def test_empty_or_garbage_ply_names_the_path(tmp_path, content, why):
    ply = tmp_path / "room.ply"
    ply.write_bytes(content)
    with pytest.raises(ValueError, match=why) as ei:
        import_mesh(ply, material="concrete")
    assert str(ply) in str(ei.value) and "\n" not in str(ei.value)


def test_mitsuba_shape_with_an_empty_mesh(tmp_path):
    (tmp_path / "empty.ply").write_text(PLY_NO_FACES)
    (tmp_path / "garbage.ply").write_bytes(b"\x00garbage")
    for mesh in ("empty.ply", "garbage.ply"):
        xml = tmp_path / f"scene_{mesh}.xml"
        xml.write_text('<scene version="2.1.0"><bsdf type="diffuse" id="mat-itu_concrete"/>'
                       f'<shape type="ply" id="floor"><string name="filename" value="{mesh}"/>'
                       '<ref id="mat-itu_concrete"/></shape></scene>')
        with pytest.raises(ValueError) as ei:
            load_mitsuba_xml(xml)
        msg = str(ei.value)
        assert str(xml) in msg and "'floor'" in msg and mesh in msg, msg


def test_mitsuba_nan_transform_and_thickness(tmp_path):
    base = ('<scene version="2.1.0"><bsdf type="diffuse" id="mat-itu_concrete">{thick}</bsdf>'
            '<shape type="rectangle" id="wall"><ref id="mat-itu_concrete"/>'
            '<transform name="to_world">{op}</transform></shape></scene>')
    xml = tmp_path / "s.xml"
    xml.write_text(base.format(thick="", op='<translate x="nan" y="0" z="0"/>'))
    with pytest.raises(ValueError, match=r"<shape id='wall'>: its <transform> holds NaN or inf"):
        load_mitsuba_xml(xml)
    xml.write_text(base.format(thick='<float name="thickness" value="nan"/>',
                               op='<translate x="1" y="0" z="0"/>'))
    with pytest.raises(ValueError, match=r"thickness must be a positive number, got 'nan'"):
        load_mitsuba_xml(xml, radio_geometry="single")
