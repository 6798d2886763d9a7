"""Bad sweep inputs stop before any point runs, in one line naming what is wrong."""

from __future__ import annotations

from pathlib import Path

import pytest
from typer.testing import CliRunner

from pipeline.cli import app
from pipeline.config import ConfigError
from pipeline.sweep import check_sweep_dir, load_sweep

ROOT = Path(__file__).resolve().parents[2]
runner = CliRunner()
EXAMPLE = str(ROOT / "configs" / "sweep_example.toml")


@pytest.mark.parametrize("n", ["0", "-3"])
def test_workers_below_one_is_one_line(tmp_path, n):
    res = runner.invoke(app, ["sweep", EXAMPLE, "--workers", n, "--out", str(tmp_path / "s")])
    assert res.exit_code == 2 and f"--workers {n}" in res.output
    assert not (tmp_path / "s").exists()  # nothing ran


def test_out_is_a_file_is_one_line(tmp_path):
    f = tmp_path / "afile"
    f.write_text("x")
    res = runner.invoke(app, ["sweep", EXAMPLE, "--out", str(f)])
    assert res.exit_code == 2 and "a file, not a directory" in res.output
    assert f.read_text() == "x"


def test_a_users_directory_is_refused_and_left_alone(tmp_path):
    d = tmp_path / "mine"
    d.mkdir()
    (d / "summary.csv").write_text("my numbers\n")
    (d / "runs").mkdir()  # a folder of the user's that happens to be called runs/
    res = runner.invoke(app, ["sweep", EXAMPLE, "--out", str(d)])
    assert res.exit_code == 2 and "not a sweep directory" in res.output
    assert (d / "summary.csv").read_text() == "my numbers\n"
    assert sorted(p.name for p in d.iterdir()) == ["runs", "summary.csv"]
    check_sweep_dir(tmp_path / "new")  # a missing or empty directory is fine


def test_a_nan_point_stops_the_sweep_before_any_point_runs(tmp_path):
    (tmp_path / "tiny.toml").write_text((ROOT / "configs" / "tiny.toml").read_text())
    sw = tmp_path / "nan.toml"
    sw.write_text('base = "tiny.toml"\n[parameters]\ntx_power_dbm = [27.0, nan]\n')
    with pytest.raises(ConfigError, match=r"point 1.*tx_power_dbm.*finite"):
        load_sweep(sw)
    res = runner.invoke(app, ["sweep", str(sw), "--out", str(tmp_path / "s")])
    assert res.exit_code == 2 and "point 1" in res.output
    assert not (tmp_path / "s").exists()


def test_a_link_loop_as_out_is_one_line(tmp_path):
    loop = tmp_path / "loop"
    loop.symlink_to(loop)
    res = runner.invoke(app, ["sweep", EXAMPLE, "--out", str(loop)])
    assert res.exit_code == 2 and "cannot be used as a sweep directory" in res.output, res.output


def test_a_users_sweep_json_or_placement_json_is_not_the_tools_marker(tmp_path):
    """A folder holding the user's own sweep.json (or placement.json) is not a sweep (or
    placement) folder of the tool's: refused before anything is written, the file kept."""
    from pipeline.config import ConfigError
    from pipeline.placement.runner import _prepare_dir
    from pipeline.sweep import check_sweep_dir

    for name, check in (("sweep.json", check_sweep_dir), ("placement.json", _prepare_dir)):
        d = tmp_path / name.split(".")[0]
        d.mkdir()
        (d / name).write_text('{"mine": true}')
        (d / "summary.csv").write_text("my,table\n")
        with pytest.raises(ConfigError, match="not a"):
            check(d)
        assert (d / name).read_text() == '{"mine": true}'
        assert sorted(p.name for p in d.iterdir()) == sorted([name, "summary.csv"])
    # the tool's own marker (and an older one without "tool") is recognised
    own = tmp_path / "own"
    own.mkdir()
    (own / "sweep.json").write_text('{"tool": "rfidstudy", "kind": "sweep", "runs": []}')
    assert check_sweep_dir(own) == own.resolve()
    (own / "sweep.json").write_text('{"source": "s.toml", "parameters": {}, "runs": []}')
    assert check_sweep_dir(own) == own.resolve()
    (own / "sweep.json").write_text('{"tool": "rfidstudy", "kind": "placement"}')
    with pytest.raises(ConfigError):
        check_sweep_dir(own)
