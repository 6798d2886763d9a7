"""Scene TOML specs: round trip, unknown keys and wrong types named with the file."""

import dataclasses

import pytest

import scenes

MINIMAL = """
name = "mini"
tag = [{ id = "T01", position_m = [1.0, 0.0, 1.0], normal = [0.0, 1.0, 0.0] }]

[corridor]
length_m = 6.0
width_m = 2.0
height_m = 2.5
"""


def _write(tmp_path, text, name="corridor_lab.toml"):
    p = tmp_path / name
    p.write_text(text)
    return p


@pytest.mark.parametrize("name", ["corridor_lab", "glass_metal_junction"])
def test_toml_round_trip(tmp_path, name):
    spec = scenes.load_spec(scenes.bundled_path(name))
    out = scenes.save_spec(spec, tmp_path / f"{name}.toml")
    again = scenes.load_spec(out)
    assert dataclasses.replace(again, base_dir=spec.base_dir, source=spec.source) == spec
    assert scenes.build(again).content_hash() == scenes.build(spec).content_hash()


def test_minimal_spec_builds(tmp_path):
    scene = scenes.load(_write(tmp_path, MINIMAL, "mini.toml"))
    assert scene.name == "mini" and len(scene.tags) == 1
    assert scene.bounds_m[1, 0] == pytest.approx(6.0 + 0.12)  # default wall thickness


def test_unknown_key_named_with_file(tmp_path):
    p = _write(tmp_path, MINIMAL.replace("length_m", "lenght_m"))
    with pytest.raises(scenes.SpecError) as exc:
        scenes.load_spec(p)
    msg = str(exc.value)
    assert "corridor_lab.toml" in msg and "'lenght_m'" in msg and "[corridor]" in msg
    assert "length_m" in msg.split("known keys:")[1]


def test_unknown_top_level_and_item_keys(tmp_path):
    with pytest.raises(scenes.SpecError, match=r"corridor_lab.toml: unknown key 'colour'"):
        scenes.load_spec(_write(tmp_path, 'colour = "red"\n' + MINIMAL))
    bad_item = MINIMAL + '\n[[door]]\nposition_m = [1.0, 0.0]\nwidth = 1.0\n'
    with pytest.raises(scenes.SpecError, match=r"\[\[door\]\] #1: unknown key 'width'"):
        scenes.load_spec(_write(tmp_path, bad_item))


def test_wrong_type_named_with_key_and_value(tmp_path):
    p = _write(tmp_path, MINIMAL.replace("width_m = 2.0", 'width_m = "wide"'))
    with pytest.raises(scenes.SpecError, match=r"corridor_lab.toml: \[corridor\]: key 'width_m' must be a number, got 'wide'"):
        scenes.load_spec(p)
    p = _write(tmp_path, MINIMAL.replace("position_m = [1.0, 0.0, 1.0]", "position_m = [1.0, 0.0]"))
    with pytest.raises(scenes.SpecError, match=r"key 'position_m' must have 3 elements"):
        scenes.load_spec(p)
    p = _write(tmp_path, MINIMAL.replace("height_m = 2.5", "height_m = -2.5"))
    with pytest.raises(scenes.SpecError, match=r"key 'height_m' must be positive, got -2.5"):
        scenes.load_spec(p)


def test_unknown_material_in_file(tmp_path):
    p = _write(tmp_path, MINIMAL + 'wall_material = "cheese"\n')
    with pytest.raises(scenes.UnknownMaterialError, match=r"corridor_lab.toml.*wall_material.*'cheese'"):
        scenes.load_spec(p)


def test_layout_errors(tmp_path):
    seg = MINIMAL + "\n[[segment]]\nmin_m = [0.0, 0.0]\nmax_m = [4.0, 2.0]\n"
    with pytest.raises(scenes.SpecError, match="exclude each other"):
        scenes.load_spec(_write(tmp_path, seg))
    dup = MINIMAL.replace('tag = [', 'tag = [{ id = "T01", position_m = [2.0, 0.0, 1.0] },')
    with pytest.raises(scenes.SpecError, match=r"duplicate tag ids \['T01'\]"):
        scenes.load_spec(_write(tmp_path, dup))
    with pytest.raises(scenes.SpecError, match="exactly one of"):
        scenes.load_spec(_write(tmp_path, 'name = "x"\n'))


def test_missing_spec_file_named(tmp_path):
    with pytest.raises(FileNotFoundError, match="nothere.toml"):
        scenes.load_spec(tmp_path / "nothere.toml")


@pytest.mark.filterwarnings("ignore::scenes.FrequencyRangeWarning")
def test_material_overrides_reach_export_and_hash(tmp_path):
    plain = scenes.load(_write(tmp_path, MINIMAL, "plain.toml"))
    text = MINIMAL + "\n[material_overrides.itu_concrete]\nthickness_m = 0.1\nconductivity_s_per_m = 0.05\n"
    over = scenes.load(_write(tmp_path, text, "over.toml"))
    assert over.metadata["material_overrides"] == {
        "concrete": {"thickness_m": 0.1, "conductivity_s_per_m": 0.05}}
    assert over.content_hash() != plain.content_hash()
    xml = over.export_mitsuba(tmp_path / "x", 865e6).read_text()
    # the floor is the only concrete surface; its overridden thickness names its material
    block = xml.split('id="uhf-concrete-t0p100">')[1].split("</bsdf>")[0]
    assert 'name="conductivity" value="0.05"' in block and 'name="thickness" value="0.1"' in block
    assert 'name="relative_permittivity" value="5.24"' in block  # not overridden
    with pytest.raises(scenes.SpecError, match=r"\[material_overrides.itu_concrete\]: unknown key 'thick'"):
        scenes.load_spec(_write(tmp_path, MINIMAL + "\n[material_overrides.itu_concrete]\nthick = 1.0\n"))
