"""The rfidstudy command line through typer's CliRunner."""

from __future__ import annotations

import json
from pathlib import Path

import pytest
from typer.testing import CliRunner

from pipeline.apps.cli import app, resolve_target
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
    canary = tmp_path / "top.pdf"  # the user's own file beside the picture
    canary.write_bytes(b"mine")
    res = runner.invoke(app, ["scenes", "show", "corridor_lab", "--png", str(png)])
    assert res.exit_code == 0, res.output
    assert "tags: " in res.output
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert canary.read_bytes() == b"mine"  # only the file named is written
    bad = runner.invoke(app, ["scenes", "show", "corridor_lab", "--png", str(canary / "x.png")])
    assert bad.exit_code == 2 and "a file stands where its folder would be" in bad.output
    assert sorted(p.name for p in tmp_path.iterdir()) == ["top.pdf", "top.png"]


def test_figures_on_missing_dir(tmp_path):
    res = runner.invoke(app, ["figures", str(tmp_path / "nope")])
    assert res.exit_code == 2 and "not a directory" in res.output


# --------------------------------------------------------------------------------------
# Faults give one clear line (issue 12): no traceback, the file / key / value named.


def _one_line_error(res, code):
    assert res.exit_code == code, res.output
    assert "Traceback" not in res.output
    assert res.exception is None or isinstance(res.exception, SystemExit)
    errors = [line for line in res.output.splitlines() if line.startswith("error: ")]
    assert len(errors) == 1, res.output
    return errors[0]


@pytest.fixture
def fake_study(monkeypatch):
    """The CLI's `run` with three quick stages instead of the study (the second one can
    be told to raise KeyboardInterrupt)."""
    import pipeline.stages
    from pipeline.engine.study import Stage

    state = {"interrupt": False}

    def a(ctx):
        ctx.out("a.json").write_text("{}")

    def b(ctx):
        if state["interrupt"]:
            raise KeyboardInterrupt
        ctx.out("b.json").write_text("{}")

    def c(ctx):
        ctx.out("c.json").write_text("{}")

    monkeypatch.setattr(pipeline.stages, "STAGES",
                        (Stage("a", a), Stage("b", b, (), ("a",)), Stage("c", c, (), ("b",))))
    monkeypatch.setattr(pipeline.stages, "manifest_info", lambda cfg: {})
    monkeypatch.setattr(pipeline.stages, "CHECKS", ())
    return state


def test_out_is_a_file_is_one_line(tmp_path):
    f = tmp_path / "results.txt"
    f.write_text("keep me")
    line = _one_line_error(runner.invoke(app, ["run", "--out", str(f), "--no-progress"]), 2)
    assert str(f) in line and "is a file, not a directory" in line
    assert f.read_text() == "keep me"


def test_foreign_out_dir_needs_force_dir(tmp_path, fake_study):
    d = tmp_path / "docs"
    d.mkdir()
    (d / "notes.md").write_text("mine")
    line = _one_line_error(runner.invoke(app, ["run", "--out", str(d), "--no-progress"]), 2)
    assert str(d) in line and "not a run directory" in line and "--force-dir" in line
    res = runner.invoke(app, ["run", "--out", str(d), "--no-progress", "--force-dir"])
    assert res.exit_code == 0, res.output
    assert (d / "notes.md").read_text() == "mine" and (d / "c.json").is_file()


def test_ctrl_c_exits_130_naming_the_stage_and_resumes(tmp_path, fake_study, caplog):
    import logging

    out = tmp_path / "run"
    fake_study["interrupt"] = True
    res = runner.invoke(app, ["run", "--out", str(out), "--no-progress"])
    assert res.exit_code == 130, res.output
    assert "interrupted at stage b; rerun the same command to resume" in res.output
    assert "Traceback" not in res.output
    man = json.loads((out / "manifest.json").read_text())
    assert man["status"] == "interrupted" and man["stage"] == "b"
    fake_study["interrupt"] = False
    with caplog.at_level(logging.INFO):  # INFO lines are logged with -v only
        res = runner.invoke(app, ["run", "--out", str(out), "--no-progress", "-v"])
    assert res.exit_code == 0, res.output
    assert "the previous run was interrupted during stage b" in caplog.text
    assert "stages run: b, c; cached: a" in res.output


def test_read_only_run_dir_is_one_line(tmp_path, fake_study, monkeypatch):
    import errno

    import pipeline.engine.runlog

    def erofs(path, *a, **k):
        raise OSError(errno.EROFS, "Read-only file system", str(path))

    out = tmp_path / "run"
    assert runner.invoke(app, ["run", "--out", str(out), "--no-progress"]).exit_code == 0
    monkeypatch.setattr(pipeline.engine.runlog, "atomic_write_json", erofs)  # the manifest's writer
    line = _one_line_error(runner.invoke(app, ["run", "--out", str(out), "--no-progress"]), 2)
    assert "read-only" in line and str(out) in line


def test_bad_numbers_in_the_config_are_named(tmp_path):
    tiny = str(ROOT / "configs" / "tiny.toml")
    line = _one_line_error(runner.invoke(app, ["run", tiny, "--set", "seed=-1", "--out",
                                               str(tmp_path / "r1")]), 2)
    assert "seed must be an integer >= 0" in line and "-1" in line
    line = _one_line_error(runner.invoke(app, ["run", tiny, "--set", "training.fcm_exponent=1.0",
                                               "--out", str(tmp_path / "r2")]), 2)
    assert "fcm_exponent must be > 1" in line and "1.0" in line
    assert not (tmp_path / "r1").exists() and not (tmp_path / "r2").exists()


def test_antenna_above_the_ceiling_fails_before_any_tracing(tmp_path):
    out = tmp_path / "r"
    res = runner.invoke(app, ["run", str(ROOT / "configs" / "tiny.toml"), "--no-progress",
                              "--set", "robot.antennas=[{name='high', z_m=5.0}]", "--out", str(out)])
    line = _one_line_error(res, 2)
    assert "robot.antennas[0].z_m = 5.0" in line and "above the ceiling" in line
    assert sorted(p.name for p in (out / "stages").iterdir()) == ["scene.json"]  # no tour, no trace
    man = json.loads((out / "manifest.json").read_text())
    assert man["status"] == "failed" and man["stage"] == "checks"


def test_antenna_in_a_wall_is_named(tmp_path):
    res = runner.invoke(app, ["run", str(ROOT / "configs" / "tiny.toml"), "--no-progress",
                              "--set", "robot.antennas=[{name='wide', y_m=1.5, z_m=0.7}]",
                              "--out", str(tmp_path / "r")])
    line = _one_line_error(res, 2)
    assert "robot.antennas[0] ('wide'" in line and "outside the scene's free space" in line


def test_scenes_show_png_needs_a_png_name(tmp_path):
    line = _one_line_error(runner.invoke(app, ["scenes", "show", "corridor_lab", "--png",
                                               str(tmp_path / "top.jpgg")]), 2)
    assert "top.jpgg" in line and ".png" in line
    assert list(tmp_path.iterdir()) == []


PLY_HEADER = ("ply\nformat ascii 1.0\nelement vertex 0\nproperty float x\nproperty float y\n"
              "property float z\nelement face 0\nproperty list uchar int vertex_indices\nend_header\n")


def test_scenes_show_empty_mesh_in_mitsuba_xml(tmp_path):
    (tmp_path / "empty.ply").write_text(PLY_HEADER)
    xml = tmp_path / "scene.xml"
    xml.write_text('<scene version="2.1.0"><bsdf type="diffuse" id="mat-itu_concrete"/>'
                   '<shape type="ply" id="floor"><string name="filename" value="empty.ply"/>'
                   '<ref id="mat-itu_concrete"/></shape></scene>')
    line = _one_line_error(runner.invoke(app, ["scenes", "show", str(xml)]), 2)
    assert str(xml) in line and "floor" in line and "empty.ply" in line and "no triangles" in line


@pytest.mark.parametrize("content", [b"", b"\x00\x01garbage not a ply\n" * 10, PLY_HEADER.encode()])
def test_scenes_show_empty_or_garbage_ply(tmp_path, content):
    ply = tmp_path / "room.ply"
    ply.write_bytes(content)
    spec = tmp_path / "room.toml"
    spec.write_text('name = "room"\n[mesh]\npath = "room.ply"\nmaterial = "concrete"\n')
    line = _one_line_error(runner.invoke(app, ["scenes", "show", str(spec)]), 2)
    assert str(ply) in line


def test_console_of_a_study_is_quiet_and_run_log_has_everything(tiny_study):
    # the session's tiny study is the real command in its own process, as a user runs it
    # (tests/conftest.py): its console and its run.log
    console = tiny_study.console
    assert not [ln for ln in console if "INFO" in ln], console  # INFO only with -v
    warnings = [ln for ln in console if "WARNING" in ln]
    assert len(warnings) == len(set(warnings)), warnings  # each warning once
    # 80 columns, but for lines that print a path (the test's own tmp path is long)
    rows = [ln for ln in console if str(tiny_study.base) not in ln]
    assert max(len(ln) for ln in rows) <= 80, max(rows, key=len)
    log_lines = (tiny_study.run / "run.log").read_text().splitlines()
    # every line of both processes, whole: the runner's stage lines and the report's
    assert any("INFO" in ln and "stage report: running" in ln for ln in log_lines)
    assert any("INFO" in ln and "report written to" in ln for ln in log_lines)
    assert all(ln[:4].isdigit() for ln in log_lines), log_lines[:5]
    # the side process's own lines (truth_traces beside tour and reads on 2 CPUs)
    side = [ln for ln in log_lines if "MainProcess" not in ln]
    assert any("truth_traces: started in process" in ln for ln in side), log_lines
    assert any("INFO" in ln and "traced" in ln for ln in side), side
    manifest = json.loads((tiny_study.run / "manifest.json").read_text())
    assert "run.log" in manifest["files"]


@pytest.mark.parallel
def test_forked_tasks_log_into_the_run_log_not_onto_the_console(tmp_path, capfd):
    # a stage's forked tasks (pipeline.parallel.map_forked: the figures, the downstream
    # filters) inherit the run log's handler: their INFO lines reach run.log, whole and
    # once, and the console (a WARNING handler, as without -v) shows none of them
    import logging
    import os

    from pipeline.engine.runlog import log_to_file
    from pipeline.parallel import map_forked

    handler = logging.StreamHandler()  # stderr, as the command line's console handler
    handler.setLevel(logging.WARNING)
    root = logging.getLogger()
    others = root.handlers[:]  # pytest's own, at every level: the command line has none
    root.handlers[:] = [handler]
    project = logging.getLogger("pipeline")
    level = project.level
    project.setLevel(logging.INFO)  # as the command line sets it

    def task(i):
        logging.getLogger("pipeline.figures.drawall").info("figure %d drawn in %d", i,
                                                           os.getpid())
        return os.getpid()

    try:
        with log_to_file(tmp_path / "run.log", mode="w"):
            pids = map_forked(task, 4, 2)
    finally:
        root.handlers[:] = others
        project.setLevel(level)
    assert len(set(pids) - {os.getpid()}) >= 1  # forked, not run here
    logged = (tmp_path / "run.log").read_text().splitlines()
    for i, pid in enumerate(pids):
        assert sum(f"figure {i} drawn in {pid}" in ln and "INFO" in ln for ln in logged) == 1
    assert "drawn in" not in capfd.readouterr().err


def test_a_repeated_warning_reaches_the_console_once_and_run_log_every_time(tmp_path):
    import io
    import logging

    from pipeline.engine.runlog import log_to_file

    console = io.StringIO()
    handler = logging.StreamHandler(console)
    handler.setLevel(logging.WARNING)  # as the command line's console handler without -v
    root = logging.getLogger()
    root.addHandler(handler)
    project = logging.getLogger("pipeline")
    level = project.level
    project.setLevel(logging.INFO)  # as the command line sets it
    log = logging.getLogger("pipeline.test_once")
    try:
        with log_to_file(tmp_path / "run.log", mode="w"):
            for _ in range(3):
                log.warning("material X extrapolated below its range")
            log.info("an info line")
        log.warning("material X extrapolated below its range")  # a new run: shown again
    finally:
        root.removeHandler(handler)
        project.setLevel(level)
    shown = console.getvalue().splitlines()
    assert shown.count("material X extrapolated below its range") == 2, shown
    assert "an info line" not in shown
    logged = (tmp_path / "run.log").read_text()
    assert logged.count("extrapolated") == 3 and "an info line" in logged


def test_a_run_log_opened_inside_another_takes_its_own_lines_only(tmp_path):
    # a replicate or placement candidate run in its caller's process (one local worker)
    # writes its own run.log; the caller's holds its own lines, before and after
    import logging

    from pipeline.engine.runlog import log_to_file

    project = logging.getLogger("pipeline")
    level = project.level
    project.setLevel(logging.INFO)
    log = logging.getLogger("pipeline.test_nested")
    try:
        with log_to_file(tmp_path / "outer.log", mode="w"):
            log.info("outer before")
            with log_to_file(tmp_path / "inner.log", mode="w"):
                log.info("inner line")
            log.info("outer after")
    finally:
        project.setLevel(level)
    outer = (tmp_path / "outer.log").read_text()
    assert "outer before" in outer and "outer after" in outer and "inner line" not in outer
    assert "inner line" in (tmp_path / "inner.log").read_text()
