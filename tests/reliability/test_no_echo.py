"""A scene's tag CSV or ``[map] path`` naming a file that is no tag table or map
(``/etc/passwd``, a key file, a binary) is refused in one line that names the file and
quotes at most a short prefix (60 characters) of anything read from it (issue 54); a
device or FIFO there is "not a regular file", never waited on, never "does not exist".
"""

from __future__ import annotations

import os
from pathlib import Path

import pytest
from typer.testing import CliRunner

import scenes
from pipeline.apps.cli import app
from scenes.spec import SpecError
from tests.scenes.maphelpers import building, write_map

#: A value no message may quote beyond its first 60 characters: every 4-character
#: window is unique, so any longer quote shows as a window past position 60.
SECRET = "S" + "".join(f"{i:03d}" for i in range(100))


def _leaks(message: str, secret: str = SECRET) -> bool:
    """Whether ``message`` quotes ``secret`` beyond its first 60 characters."""
    return any(secret[i:i + 8] in message for i in range(57, len(secret) - 8))


def _site(tmp_path: Path, tags_csv: str | None = None, map_path: str = "site.yaml") -> Path:
    write_map(tmp_path, building(width_m=12.0, length_m=8.0, wall_m=0.25, pad_m=0.5), name="site")
    toml = f'name = "site"\n[map]\npath = "{map_path}"\n'
    if tags_csv is not None:
        toml += f'[tags]\nlayout = "csv"\ncsv = "{tags_csv}"\n'
    (tmp_path / "scene.toml").write_text(toml)
    return tmp_path / "scene.toml"


def _refusal(spec: Path) -> str:
    with pytest.raises((SpecError, ValueError, FileNotFoundError)) as err:
        scenes.load(spec)
    msg = str(err.value)
    assert "\n" not in msg, msg
    return msg


@pytest.mark.parametrize("content", [
    f"{SECRET}:x:0:0:root:/root:/bin/bash\n",  # a passwd line as the header
    f"id,x_m,y_m,z_m,nx,ny,nz\nW1,{SECRET},0,1,0,1,0\n",  # a bad number
    f"id,x_m,y_m,z_m,nx,ny,nz\n{SECRET},1,0,1,0,1,x\n",  # a bad row: the whole row was echoed
    f"id,x_m,y_m,z_m,nx,ny,nz,{SECRET}\n",  # an extra column
])
def test_a_tag_csv_that_is_no_tag_table_is_not_echoed(tmp_path, content):
    (tmp_path / "other.txt").write_text(content)
    msg = _refusal(_site(tmp_path, "other.txt"))
    assert "other.txt" in msg and not _leaks(msg), msg


def test_a_binary_tag_csv_names_the_file(tmp_path):
    (tmp_path / "blob.bin").write_bytes(b"id,x_m\n\xd0\x00\xff" + SECRET.encode() * 3)
    msg = _refusal(_site(tmp_path, "blob.bin"))
    assert "blob.bin" in msg and "UTF-8" in msg and not _leaks(msg), msg


@pytest.mark.parametrize("target", ["/dev/zero", "fifo", "folder"])
def test_a_tag_csv_that_is_no_regular_file_is_named_not_read(tmp_path, target):
    if target == "fifo":
        os.mkfifo(tmp_path / "fifo")  # reading it would wait for a writer for ever
    elif target == "folder":
        (tmp_path / "folder").mkdir()
    elif not Path(target).exists():
        pytest.skip(f"no {target}")
    msg = _refusal(_site(tmp_path, target))
    assert "not a regular file" in msg and "does not exist" not in msg, msg


@pytest.mark.parametrize("yaml_text", [
    f"image: site.pgm\n{SECRET}: 1\n",  # an unknown key, quoted in full
    f"image: {SECRET}.pgm\nresolution: 0.05\norigin: [0.0, 0.0, 0.0]\n",  # a missing image
    f"!{SECRET} x\n",  # a YAML tag in PyYAML's message
    f"password: {SECRET}\n",  # a credentials file
])
def test_a_map_path_at_a_file_that_is_no_map_is_not_echoed(tmp_path, yaml_text):
    (tmp_path / "other.yaml").write_text(yaml_text)
    msg = _refusal(_site(tmp_path, map_path="other.yaml"))
    assert "other.yaml" in msg and not _leaks(msg), msg


def test_a_map_path_at_a_device_is_not_a_regular_file(tmp_path):
    if not Path("/dev/zero").exists():
        pytest.skip("no /dev/zero")
    msg = _refusal(_site(tmp_path, map_path="/dev/zero"))
    assert "/dev/zero" in msg and "not a regular file" in msg and "does not exist" not in msg, msg


@pytest.mark.skipif(not Path("/etc/passwd").is_file(), reason="no /etc/passwd")
@pytest.mark.parametrize("key", ["csv", "map"])
def test_scenes_show_on_etc_passwd_quotes_no_line_of_it(tmp_path, key):
    spec = _site(tmp_path, "/etc/passwd") if key == "csv" else _site(tmp_path, map_path="/etc/passwd")
    res = CliRunner().invoke(app, ["scenes", "show", str(spec)])
    assert res.exit_code != 0 and "Traceback" not in res.output, res.output
    assert "/etc/passwd" in res.output and len(res.output.strip().splitlines()) == 1, res.output
    lines = [ln for ln in Path("/etc/passwd").read_text(errors="replace").splitlines() if len(ln) > 8]
    assert not any(ln in res.output for ln in lines[1:]), res.output  # at most the first line's prefix
    assert not _leaks(res.output, lines[0]) and len(res.output) < 400, res.output
