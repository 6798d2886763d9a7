"""The rfidstudy command line through typer's CliRunner."""

from __future__ import annotations

from pathlib import Path

import pytest
from typer.testing import CliRunner

from pipeline.cli import app, resolve_target
from pipeline.config import ConfigError, StudyConfig

ROOT = Path(__file__).resolve().parents[2]
runner = CliRunner()


def test_run_help_shows_options_and_reference():
    res = runner.invoke(app, ["run", "--help"], env={"COLUMNS": "200"})
    assert res.exit_code == 0
    for text in ("--out", "runs/default", "--set", "--backend", "corridor_lab", "reference.toml"):
        assert text in res.output, text


def test_config_reference_prints_every_default():
    res = runner.invoke(app, ["config", "--reference"])
    assert res.exit_code == 0
    assert "samples_per_src = 30000" in res.output and "[[robot.antennas]]" in res.output


def test_config_resolves_overrides():
    res = runner.invoke(app, ["config", str(ROOT / "configs" / "tiny.toml"), "--set", "training.epochs=9"])
    assert res.exit_code == 0, res.output
    assert "epochs = 9" in res.output and "max_length_m = 5.0" in res.output


def test_bad_config_key_is_named(tmp_path):
    p = tmp_path / "bad.toml"
    p.write_text("seed = 1\n[training]\nepoch = 3\n")
    res = runner.invoke(app, ["run", str(p), "--out", str(tmp_path / "r")])
    assert res.exit_code == 2
    assert "training.epoch" in res.output and "bad.toml" in res.output


def test_resolve_target_scene_vs_study(tmp_path):
    assert resolve_target(None) == StudyConfig()
    assert resolve_target("glass_metal_junction").scene == "glass_metal_junction"
    scene_toml = tmp_path / "my_scene.toml"
    scene_toml.write_text('name = "x"\n[corridor]\nlength_m = 5.0\n')
    assert resolve_target(str(scene_toml)).scene == str(scene_toml.resolve())
    with pytest.raises(ConfigError, match="missing.toml: no such file"):
        resolve_target(str(tmp_path / "missing.toml"))
    with pytest.raises(ConfigError, match="expected KEY=VALUE"):
        resolve_target(None, ["training.epochs"])


def test_scenes_list_and_show(tmp_path):
    res = runner.invoke(app, ["scenes", "list"])
    assert res.exit_code == 0 and "corridor_lab" in res.output and "glass_metal_junction" in res.output
    png = tmp_path / "top.png"
    res = runner.invoke(app, ["scenes", "show", "corridor_lab", "--png", str(png)])
    assert res.exit_code == 0, res.output
    assert "tags: " in res.output
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


def test_figures_on_missing_dir(tmp_path):
    res = runner.invoke(app, ["figures", str(tmp_path / "nope")])
    assert res.exit_code == 2 and "not a directory" in res.output
