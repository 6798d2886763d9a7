"""Study config: typed TOML, errors naming file and key, reference.toml in sync."""

from __future__ import annotations

import tomllib
from pathlib import Path

import pytest

from pipeline.config import (
    ConfigError,
    StudyConfig,
    config_from_mapping,
    config_to_toml,
    load_config,
    reference_config_toml,
    replace_path,
)

ROOT = Path(__file__).resolve().parents[2]


def test_reference_toml_in_sync():
    shipped = (ROOT / "configs" / "reference.toml").read_text(encoding="utf-8")
    assert shipped == reference_config_toml(), (
        "configs/reference.toml is stale: regenerate with "
        "`python -c 'from pipeline.config import reference_config_toml as r; print(r(), end=\"\")'"
        " > configs/reference.toml`"
    )


def test_reference_toml_reads_back_to_defaults():
    cfg = config_from_mapping(tomllib.loads(reference_config_toml()))
    assert cfg == StudyConfig()


def test_every_field_documented():
    text = reference_config_toml()
    # each value line is preceded by a non-empty comment line
    lines = text.splitlines()
    for i, line in enumerate(lines):
        if "=" in line and not line.startswith("#"):
            assert lines[i - 1].startswith("# ") and len(lines[i - 1]) > 4, line


def test_unknown_key_named_with_file(tmp_path):
    p = tmp_path / "study.toml"
    p.write_text("[training]\nepochz = 3\n")
    with pytest.raises(ConfigError) as exc:
        load_config(p)
    msg = str(exc.value)
    assert str(p) in msg and "training.epochz" in msg and "epochs" in msg


def test_unknown_top_level_section(tmp_path):
    p = tmp_path / "study.toml"
    p.write_text("[trainig]\nepochs = 3\n")
    with pytest.raises(ConfigError, match=r"study\.toml: trainig: unknown key"):
        load_config(p)


def test_wrong_type_named(tmp_path):
    p = tmp_path / "study.toml"
    p.write_text('[tracing]\nmax_depth = "five"\n')
    with pytest.raises(ConfigError, match=r"study\.toml: tracing\.max_depth: expected int, got str 'five'"):
        load_config(p)


def test_bool_is_not_int(tmp_path):
    p = tmp_path / "study.toml"
    p.write_text("seed = true\n")
    with pytest.raises(ConfigError, match="seed: expected int"):
        load_config(p)


def test_bad_value_in_array_of_tables(tmp_path):
    p = tmp_path / "study.toml"
    p.write_text('[[robot.antennas]]\nname = "a"\nz_m = -0.5\n')
    with pytest.raises(ConfigError, match=r"robot\.antennas\[0\].*z_m must be > 0"):
        load_config(p)


def test_unknown_key_in_antenna(tmp_path):
    p = tmp_path / "study.toml"
    p.write_text('[[robot.antennas]]\nname = "a"\nheight_m = 0.5\n')
    with pytest.raises(ConfigError, match=r"robot\.antennas\[0\]\.height_m: unknown key"):
        load_config(p)


def test_invalid_toml_names_file(tmp_path):
    p = tmp_path / "broken.toml"
    p.write_text("seed = = 3\n")
    with pytest.raises(ConfigError, match="broken.toml: invalid TOML"):
        load_config(p)


def test_missing_file(tmp_path):
    with pytest.raises(ConfigError, match="nope.toml: cannot read"):
        load_config(tmp_path / "nope.toml")


def test_resolved_toml_roundtrip(tmp_path):
    cfg = replace_path(StudyConfig(), "training.epochs", 7)
    cfg = replace_path(cfg, "robot.antennas[*].z_m", 0.9)
    p = tmp_path / "c.toml"
    p.write_text(config_to_toml(cfg))
    back = load_config(p)
    assert back == cfg
    assert back.training.epochs == 7
    assert all(a.z_m == 0.9 for a in back.robot.antennas)


def test_relative_scene_path_resolved(tmp_path):
    p = tmp_path / "sub" / "c.toml"
    p.parent.mkdir()
    p.write_text('scene = "../myscene.toml"\n')
    assert load_config(p).scene == str((tmp_path / "myscene.toml").resolve())
    p.write_text('scene = "corridor_lab"\n')
    assert load_config(p).scene == "corridor_lab"


def test_replace_path_unknown_key():
    with pytest.raises(ConfigError, match="unknown config key 'trainig'"):
        replace_path(StudyConfig(), "trainig.epochs", 3)


@pytest.mark.parametrize("name", ["reference.toml", "paper_scale.toml", "tiny.toml"])
def test_shipped_configs_load(name):
    p = ROOT / "configs" / name
    if not p.exists():
        pytest.skip(f"{name} not shipped yet")
    load_config(p)
