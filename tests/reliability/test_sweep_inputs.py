"""Bad sweep inputs stop before any point runs, in one line naming what is wrong."""

from __future__ import annotations

import json
import os
from pathlib import Path

import pytest
from typer.testing import CliRunner

from pipeline.apps.cli import app
from pipeline.apps.sweep import check_sweep_dir, load_sweep
from pipeline.config import ConfigError

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
    from pipeline.apps.placement.runner import _prepare_dir
    from pipeline.apps.sweep import check_sweep_dir
    from pipeline.config import ConfigError

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


@pytest.mark.parametrize("name", ["placement.json", "sweep.json"])
@pytest.mark.parametrize("kind", ["link to the tool's marker", "link to /dev/zero", "fifo"])
def test_a_marker_that_is_a_link_or_fifo_is_refused_by_name_never_followed(tmp_path, name, kind):
    """A placement.json (sweep.json) that is a symbolic link, even to a marker of the
    tool's, does not make the folder the tool's: refused naming the link, its target
    unread and unchanged, nothing written (issue 54: "no placement.json")."""
    from pipeline.apps.placement.runner import _prepare_dir

    check = _prepare_dir if name == "placement.json" else check_sweep_dir
    mark = tmp_path / "elsewhere.json"
    mark.write_text(json.dumps({"tool": "rfidstudy", "kind": name.split(".")[0], "source": "s.toml",
                                "parameters": {}, "runs": [], "file": "p.toml", "replicates": 3,
                                "candidates": []}))
    before = mark.read_bytes()
    d = tmp_path / "out"
    d.mkdir()
    (d / "summary.csv").write_text("my,table\n")
    if kind == "fifo":
        os.mkfifo(d / name)
        words = "not a regular file (a FIFO)"
    else:
        if kind == "link to /dev/zero" and not Path("/dev/zero").exists():
            pytest.skip("no /dev/zero")
        (d / name).symlink_to(mark if kind.endswith("marker") else "/dev/zero")
        words = "a symbolic link, not followed"
    with pytest.raises(ConfigError) as err:
        check(d)
    assert f"{d / name}: {words}" in str(err.value) and "\n" not in str(err.value)
    assert mark.read_bytes() == before
    assert sorted(p.name for p in d.iterdir()) == sorted([name, "summary.csv"])


def test_placement_out_with_a_linked_placement_json_is_one_line(tmp_path):
    d = tmp_path / "out"
    d.mkdir()
    mark = tmp_path / "elsewhere.json"
    mark.write_text('{"tool": "rfidstudy", "kind": "placement"}')
    (d / "placement.json").symlink_to(mark)
    res = CliRunner().invoke(app, ["placement", str(ROOT / "configs" / "placement_example.toml"),
                                   "--out", str(d)])
    assert res.exit_code == 2 and "Traceback" not in res.output, res.output
    errors = [ln for ln in res.output.splitlines() if ln.startswith("error:")]
    assert len(errors) == 1 and "placement.json: a symbolic link, not followed" in errors[0], res.output
    assert sorted(p.name for p in d.iterdir()) == ["placement.json"]
