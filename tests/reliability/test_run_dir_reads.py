"""The files ``report``, ``figures`` and ``compare`` read from a run directory
(``metrics.json``, ``manifest.json``, ``config.toml``) as a FIFO, a folder or a symbolic
link (to a file outside, to ``/dev/zero``): one line naming the file and what it is, no
wait on the FIFO, nothing read through the link (issue 54: a FIFO was "none of
['metrics.json'] exists", a link "[Errno 40] Too many levels of symbolic links", and
the Fig. 7 helpers followed a ``config.toml`` link out of the run)."""

from __future__ import annotations

import json
import os
import threading
import time
from pathlib import Path

import pytest
from typer.testing import CliRunner

from pipeline.apps.cli import app
from pipeline.config import StudyConfig
from pipeline.engine.study import Stage, run_study

#: Seconds after which a reader blocked on a planted FIFO is released (and the test fails).
RELEASE_S = 20.0
SECRET = "the user's secret, outside the run"


def _a(ctx):
    ctx.out("a/value.json").write_text("{}")


@pytest.fixture
def run(tmp_path):
    d = tmp_path / "run"
    run_study(StudyConfig(), d, stages=(Stage("a", _a, ("seed",)),), manifest_extra=None,
              command_line=["test"])
    (d / "metrics.json").write_text(json.dumps(  # enough for the headline figure
        {"heldout": {"models": {"anfis": {"rssi_dbm": {"mae": 3.0, "rmse": 4.0}}}}}))
    return d


def _release_later(path: Path, stop: threading.Event) -> None:
    """Open ``path``'s write end after :data:`RELEASE_S` if a reader waits on it: a hang
    becomes a slow pass that the elapsed-time check fails, not a test that never ends."""
    if stop.wait(RELEASE_S):
        return
    try:
        os.close(os.open(path, os.O_WRONLY | os.O_NONBLOCK))
    except OSError:  # no reader waiting
        pass


def _plant(run: Path, name: str, kind: str, outside: Path) -> str:
    """Put a ``kind`` where ``run/name`` was; the words its refusal must hold."""
    p = run / name
    p.unlink(missing_ok=True)
    if kind == "fifo":
        os.mkfifo(p)
        return "not a regular file (a FIFO)"
    if kind == "folder":
        p.mkdir()
        return "not a regular file (a folder)"
    p.symlink_to(outside if kind == "link outside" else "/dev/zero")
    return "symbolic link"


def _invoke(command: str, run: Path, tmp_path: Path):
    args = {"report": ["report", str(run)], "figures": ["figures", str(run)],
            "compare": ["compare", str(run), str(run), "--out", str(tmp_path / "cmp")]}[command]
    return CliRunner().invoke(app, args)


@pytest.mark.parametrize("kind", ["fifo", "folder", "link outside", "link to /dev/zero"])
@pytest.mark.parametrize("name, commands", [
    ("metrics.json", ("report", "figures", "compare")),
    ("manifest.json", ("report", "figures")),
    ("config.toml", ("report", "figures")),
])
def test_a_planted_file_is_one_line_never_waited_on_never_followed(run, tmp_path, name, commands, kind,
                                                                   monkeypatch):
    if kind == "link to /dev/zero" and not Path("/dev/zero").exists():
        pytest.skip("no /dev/zero")
    if kind != "fifo":  # `figures` draws here, in order; a FIFO is read by forked workers too
        monkeypatch.setenv("RFIDSTUDY_WORKERS", "1")
    else:  # forked, whatever share of the CPUs this test process was given
        monkeypatch.delenv("RFIDSTUDY_WORKERS", raising=False)
    outside = tmp_path / f"outside{Path(name).suffix}"
    outside.write_text(json.dumps({"scene": SECRET, "evaluation": {"x": SECRET}}) if name.endswith(".json")
                       else f'scene = "{SECRET}"\n')
    before = outside.read_bytes()
    words = _plant(run, name, kind, outside)
    stop = threading.Event()
    if kind == "fifo":
        threading.Thread(target=_release_later, args=(run / name, stop), daemon=True).start()
    try:
        for command in commands:
            t0 = time.monotonic()
            res = _invoke(command, run, tmp_path)
            assert time.monotonic() - t0 < RELEASE_S, f"{command} waited on the FIFO {name}"
            errors = [ln for ln in res.output.splitlines() if ln.startswith("error:")]
            assert res.exit_code in (1, 2) and "Traceback" not in res.output, (command, res.output)
            assert len(errors) == 1, (command, res.output)
            assert str(run / name) in errors[0] and words in errors[0], (command, res.output)
            assert "Errno" not in errors[0] and "none of" not in errors[0], (command, res.output)
            assert SECRET not in res.output and not (run / "report.html").exists(), (command, res.output)
    finally:
        stop.set()
    assert outside.read_bytes() == before


def test_the_fig7_helpers_do_not_read_a_linked_config_outside(run, tmp_path):
    from pipeline.figures.comparison import _tilts, _training_d_max

    outside = tmp_path / "outside.toml"
    outside.write_text('[training]\nd_max_m = 123.0\n[[robot.antennas]]\ntilt_deg = 45.0\n')
    (run / "config.toml").unlink()
    (run / "config.toml").symlink_to(outside)
    for helper in (_training_d_max, _tilts):
        with pytest.raises(ValueError, match=r"config.toml: a symbolic link"):
            helper(run)


@pytest.mark.parametrize("value", ["0", "-1", "nan", "inf", '"abc"', "1e30", "true", "[865e6]"])
def test_a_bad_frequency_in_the_runs_config_is_one_line_naming_key_and_file(run, tmp_path, value,
                                                                           monkeypatch):
    """The report extrapolated materials to 0 Hz (or NaN, or 1e30) and said nothing; a
    string was "could not convert string to float: 'abc'" with no key or file.

    `figures` draws in this process (one worker) except for "nan": the error is the same
    line whether a forked worker or this process raised it."""
    from pipeline.config import StudyConfig, config_to_toml

    if value != "nan":
        monkeypatch.setenv("RFIDSTUDY_WORKERS", "1")
    else:  # forked, whatever share of the CPUs this test process was given
        monkeypatch.delenv("RFIDSTUDY_WORKERS", raising=False)

    text = config_to_toml(StudyConfig())
    assert "\nfrequency_hz = " in text
    (run / "config.toml").write_text(text.replace("\nfrequency_hz = ", f"\nfrequency_hz = {value}\n#", 1))
    for command in ("report", "figures"):
        res = _invoke(command, run, tmp_path)
        errors = [ln for ln in res.output.splitlines() if ln.startswith("error:")]
        assert res.exit_code in (1, 2) and "Traceback" not in res.output, (command, res.output)
        assert len(errors) == 1, (command, res.output)
        assert str(run / "config.toml") in errors[0] and "frequency_hz" in errors[0], (command, res.output)
        assert not (run / "report.html").exists()


def test_a_good_frequency_in_the_runs_config_is_reported(run, tmp_path):
    from pipeline.config import StudyConfig, config_to_toml, replace_path

    (run / "config.toml").write_text(config_to_toml(replace_path(StudyConfig(), "frequency_hz", 915e6)))
    (run / "scene").mkdir()
    (run / "scene" / "scene.json").write_text(json.dumps({"materials": ["concrete"]}))
    res = _invoke("report", run, tmp_path)
    assert res.exit_code == 0, res.output
    html = (run / "report.html").read_text()
    assert "9.15e+08" in html and "extrapolated to 0.915 GHz" in html
