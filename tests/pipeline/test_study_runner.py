"""The stage runner: caching, selective re-runs, failure and resume, corrupt files.

These tests drive :func:`pipeline.engine.study.run_study` with small stages of its own (the
runner is what is under test here); the real study on a real scene is exercised in
test_study_tiny.py.
"""

from __future__ import annotations

import json
import logging

import pytest

from pipeline.config import StudyConfig, replace_path
from pipeline.engine.study import Stage, StageError, run_study

CALLS: list[str] = []


def _a(ctx):
    CALLS.append("a")
    ctx.out("a/value.json").write_text(json.dumps({"seed": ctx.config.seed}))
    return {"n": 1}


def _b(ctx):
    CALLS.append("b")
    seed = json.loads(ctx.input("a/value.json").read_text())["seed"]
    ctx.out("b.json").write_text(json.dumps({"v": seed * ctx.config.training.epochs}))


def _c(ctx):
    CALLS.append("c")
    if ctx.config.training.step_size > 0.5:
        raise RuntimeError("step too large")
    v = json.loads(ctx.input("b.json").read_text())["v"]
    ctx.out("c.txt").write_text(str(v + 1))


STAGES = (
    Stage("a", _a, ("seed",)),
    Stage("b", _b, ("training.epochs",), ("a",)),
    Stage("c", _c, ("training.step_size",), ("b",)),
)


def _run(cfg, d, **kw):
    CALLS.clear()
    return run_study(cfg, d, stages=STAGES, manifest_extra=None, command_line=["test"], **kw)


def test_second_run_skips_everything(tmp_path):
    cfg = StudyConfig()
    r1 = _run(cfg, tmp_path)
    assert r1.ran == ["a", "b", "c"] and CALLS == ["a", "b", "c"]
    r2 = _run(cfg, tmp_path)
    assert r2.ran == [] and r2.cached == ["a", "b", "c"] and CALLS == []
    man = json.loads((tmp_path / "manifest.json").read_text())
    assert man["status"] == "complete" and man["stages"]["b"]["status"] == "cached"
    assert (tmp_path / "config.toml").read_text().startswith("scene = ")


def test_changed_key_reruns_only_downstream(tmp_path):
    cfg = StudyConfig()
    _run(cfg, tmp_path)
    r = _run(replace_path(cfg, "training.epochs", 99), tmp_path)
    assert r.ran == ["b", "c"] and r.cached == ["a"]
    assert (tmp_path / "c.txt").read_text() == str(cfg.seed * 99 + 1)
    r = _run(replace_path(cfg, "training.epochs", 99), tmp_path)
    assert r.ran == []


def test_failure_keeps_earlier_outputs_and_resumes(tmp_path):
    cfg = StudyConfig()
    _run(cfg, tmp_path)
    bad = replace_path(replace_path(cfg, "training.step_size", 0.9), "training.epochs", 5)
    with pytest.raises(StageError, match="stage 'c' failed: RuntimeError: step too large"):
        _run(bad, tmp_path)
    # a and b finished and kept their outputs; c's previous output is untouched
    assert json.loads((tmp_path / "b.json").read_text())["v"] == cfg.seed * 5
    assert (tmp_path / "c.txt").read_text() == str(cfg.seed * cfg.training.epochs + 1)
    man = json.loads((tmp_path / "manifest.json").read_text())
    assert man["status"] == "failed" and man["failure"]["stage"] == "c"
    assert not (tmp_path / ".staging" / "c").exists()
    fixed = replace_path(bad, "training.step_size", 0.01)
    r = _run(fixed, tmp_path)
    assert r.ran == ["c"] and r.cached == ["a", "b"]
    assert (tmp_path / "c.txt").read_text() == str(cfg.seed * 5 + 1)


def test_deleted_output_reruns_that_stage(tmp_path, caplog):
    cfg = StudyConfig()
    _run(cfg, tmp_path)
    (tmp_path / "b.json").unlink()
    with caplog.at_level(logging.WARNING):
        r = _run(cfg, tmp_path)
    assert "b.json is missing" in caplog.text
    # b re-ran and produced the same bytes, so c stays cached
    assert r.ran == ["b"] and r.cached == ["a", "c"]


def test_corrupt_output_reruns_with_warning(tmp_path, caplog):
    cfg = StudyConfig()
    _run(cfg, tmp_path)
    (tmp_path / "a" / "value.json").write_text("{garbage")
    with caplog.at_level(logging.WARNING):
        r = _run(cfg, tmp_path)
    assert "value.json was modified or is corrupt" in caplog.text
    assert r.ran == ["a"]
    assert json.loads((tmp_path / "a" / "value.json").read_text())["seed"] == cfg.seed


def test_corrupt_record_reruns_with_warning(tmp_path, caplog):
    cfg = StudyConfig()
    _run(cfg, tmp_path)
    (tmp_path / "stages" / "b.json").write_text("not json")
    with caplog.at_level(logging.WARNING):
        r = _run(cfg, tmp_path)
    assert "stages/b.json is corrupt" in caplog.text
    assert r.ran == ["b"]


def test_missing_input_names_file(tmp_path):
    def needs(ctx):
        ctx.input("nowhere.parquet")

    with pytest.raises(StageError, match=r"input file .*nowhere\.parquet is missing"):
        run_study(StudyConfig(), tmp_path, stages=(Stage("x", needs),), manifest_extra=None)


def test_force_and_unknown_force(tmp_path):
    cfg = StudyConfig()
    _run(cfg, tmp_path)
    r = _run(cfg, tmp_path, force=["a"])
    assert r.ran == ["a"]  # same bytes out, so b and c stay cached
    with pytest.raises(ValueError, match="unknown stage"):
        _run(cfg, tmp_path, force=["zzz"])


# --------------------------------------------------------------------------------------
# A run directory that never lies (issue 12): stale outputs, the manifest's state and
# files, interrupts and killed runs, foreign and read-only directories, checks.

def _parts(ctx):
    CALLS.append("parts")
    for i in range(ctx.config.training.epochs):
        ctx.out(f"parts/p{i}.json").write_text(json.dumps({"i": i}))


PART_STAGES = (Stage("a", _a, ("seed",)), Stage("parts", _parts, ("training.epochs",), ("a",)))


def _files(root):
    """The run directory's files, less the lock's housekeeping (not results)."""
    from pipeline.engine.runstore import HOUSEKEEPING

    return {p.relative_to(root).as_posix() for p in root.rglob("*")
            if p.is_file() and p.name not in HOUSEKEEPING}


def test_outputs_of_an_earlier_config_are_removed_and_the_manifest_lists_the_files(tmp_path):
    cfg = StudyConfig()
    run_study(replace_path(cfg, "training.epochs", 3), tmp_path, stages=PART_STAGES,
              manifest_extra=None)
    assert (tmp_path / "parts" / "p2.json").is_file()
    run_study(replace_path(cfg, "training.epochs", 2), tmp_path, stages=PART_STAGES,
              manifest_extra=None)
    fresh = tmp_path / "fresh"
    run_study(replace_path(cfg, "training.epochs", 2), fresh, stages=PART_STAGES, manifest_extra=None)
    here = _files(tmp_path) - {p for p in _files(tmp_path) if p.startswith("fresh/")}
    assert here == _files(fresh)
    assert not (tmp_path / "parts" / "p2.json").exists()
    man = json.loads((tmp_path / "manifest.json").read_text())
    assert set(man["files"]) == here - {"manifest.json"}
    assert "stages/parts.json" in man["files"] and "config.toml" in man["files"]
    assert man["status"] == "complete" and man["stage"] is None
    assert not (tmp_path / ".staging").exists()


def _interrupt(ctx):
    CALLS.append("b")
    ctx.out("b.json").write_text("half")
    raise KeyboardInterrupt


def test_ctrl_c_names_the_stage_and_the_manifest_says_interrupted(tmp_path, caplog):
    from pipeline.engine.study import StudyInterrupted

    cfg = StudyConfig()
    stages = (STAGES[0], Stage("b", _interrupt, ("training.epochs",), ("a",)), STAGES[2])
    with pytest.raises(StudyInterrupted, match="interrupted at stage b; rerun the same command to resume") as ei:
        _run_stages(cfg, tmp_path, stages)
    assert isinstance(ei.value, KeyboardInterrupt) and ei.value.stage == "b"
    man = json.loads((tmp_path / "manifest.json").read_text())
    assert man["status"] == "interrupted" and man["stage"] == "b"
    assert man["files"] == ["a/value.json", "config.toml", "run.log", "stages/a.json"]
    assert not (tmp_path / ".staging" / "b").exists() and not (tmp_path / "b.json").exists()
    with caplog.at_level(logging.INFO):
        r = _run(cfg, tmp_path)
    assert "the previous run was interrupted during stage b" in caplog.text
    assert r.ran == ["b", "c"] and r.cached == ["a"]
    assert "interrupted during stage b" in r.previous


def _killed(ctx):
    # while a stage runs the manifest on disk says so; then the process dies without
    # any handler running (SystemExit is what os._exit / SIGKILL look like from here)
    man = json.loads(ctx.store.path("manifest.json").read_text())
    assert man["status"] == "running" and man["stage"] == "b"
    raise SystemExit(9)


def test_a_killed_run_is_named_by_the_next_run(tmp_path, caplog):
    cfg = StudyConfig()
    stages = (STAGES[0], Stage("b", _killed, ("training.epochs",), ("a",)), STAGES[2])
    with pytest.raises(SystemExit):
        _run_stages(cfg, tmp_path, stages)
    assert json.loads((tmp_path / "manifest.json").read_text())["status"] == "running"
    with caplog.at_level(logging.WARNING):
        r = _run(cfg, tmp_path)
    assert "the previous run stopped during stage b" in caplog.text and "resuming" in caplog.text
    assert r.ran == ["b", "c"] and r.cached == ["a"]
    man = json.loads((tmp_path / "manifest.json").read_text())
    assert man["status"] == "complete" and man["previous_run"] == "the previous run stopped during stage b"


def _run_stages(cfg, d, stages, **kw):
    CALLS.clear()
    return run_study(cfg, d, stages=stages, manifest_extra=None, command_line=["test"], **kw)


def test_a_foreign_directory_is_refused_unless_forced(tmp_path):
    from pipeline.engine.study import RunDirError

    d = tmp_path / "thesis"
    d.mkdir()
    (d / "chapter1.tex").write_text("precious")
    with pytest.raises(RunDirError, match=r"thesis is not empty \(chapter1.tex\) and is not a run "
                                          r"directory.*--force-dir"):
        _run(StudyConfig(), d)
    assert sorted(p.name for p in d.iterdir()) == ["chapter1.tex"]  # nothing written
    r = _run(StudyConfig(), d, force_dir=True)
    assert r.ran == ["a", "b", "c"] and (d / "chapter1.tex").read_text() == "precious"
    assert _run(StudyConfig(), d).ran == []  # now a run directory: no flag needed
    f = tmp_path / "file"
    f.write_text("x")
    with pytest.raises(RunDirError, match="file is a file, not a directory"):
        _run(StudyConfig(), f)
    with pytest.raises(RunDirError, match="file is a file, not a directory"):
        _run(StudyConfig(), f / "sub")
    assert f.read_text() == "x"


def test_a_run_directory_of_another_config_names_the_keys_that_differ(tmp_path, caplog):
    cfg = StudyConfig()
    _run(cfg, tmp_path)
    other = replace_path(replace_path(cfg, "training.epochs", 7), "robot.antennas[1].z_m", 0.9)
    with caplog.at_level(logging.INFO):
        r = _run(other, tmp_path)
    assert r.changed_keys == ["robot.antennas[1].z_m", "training.epochs"]
    assert "holds a run of another config" in caplog.text
    assert "training.epochs: 100 -> 7" in caplog.text and "robot.antennas[1].z_m: 0.7 -> 0.9" in caplog.text
    assert r.ran == ["b", "c"]  # then reruns as usual
    caplog.clear()
    with caplog.at_level(logging.INFO):
        assert _run(other, tmp_path).changed_keys == []
    assert "another config" not in caplog.text


@pytest.mark.parametrize("where", ["config", "commit"])
def test_a_read_only_run_directory_is_one_clear_error(tmp_path, monkeypatch, where):
    import errno

    from pipeline.engine import runlog, runstore, study
    from pipeline.engine.study import RunDirError

    cfg = StudyConfig()
    if where == "commit":
        _run(cfg, tmp_path)
        cfg = replace_path(cfg, "training.epochs", 3)  # b and c must run and commit

    def erofs(src, dst, *a, **k):
        raise OSError(errno.EROFS, "Read-only file system", str(dst))

    if where == "config":
        monkeypatch.setattr(study, "atomic_write_text", lambda p, t: erofs(None, p))
        monkeypatch.setattr(runlog, "atomic_write_json", lambda p, o: erofs(None, p))  # manifest
    else:
        monkeypatch.setattr(runstore.os, "replace", erofs)
    with pytest.raises(RunDirError) as ei:
        _run(cfg, tmp_path)
    msg = str(ei.value)
    assert "\n" not in msg and "read-only" in msg and str(tmp_path) in msg


def test_checks_run_after_always_stages_and_before_the_first_cached_one(tmp_path):
    from pipeline.config import ConfigError

    seen = []

    def scene(ctx):
        seen.append("scene")
        ctx.memo["scene"] = "loaded"
        ctx.out("scene.json").write_text("{}")

    def check(ctx):
        seen.append(f"check:{ctx.memo.get('scene')}")
        if ctx.config.seed == 13:
            raise ConfigError("seed = 13: unlucky")

    stages = (Stage("scene", scene, (), always=True), *STAGES)
    _run_stages(StudyConfig(), tmp_path, stages, checks=(check,))
    assert seen == ["scene", "check:loaded"] and CALLS == ["a", "b", "c"]
    seen.clear()
    with pytest.raises(ConfigError, match="seed = 13: unlucky"):
        _run_stages(replace_path(StudyConfig(), "seed", 13), tmp_path, stages, checks=(check,))
    assert CALLS == []  # nothing after the check ran
    man = json.loads((tmp_path / "manifest.json").read_text())
    assert man["status"] == "failed" and man["stage"] == "checks"


def test_logs_name_final_paths_not_the_staging_area(tmp_path, caplog):
    def writes(ctx):
        out = ctx.out("report.html")
        out.write_text("<html/>")
        logging.getLogger("pipeline.report.html").info("report written to %s", out)

    with caplog.at_level(logging.INFO):
        _run_stages(StudyConfig(), tmp_path, (Stage("report", writes),))
    assert f"report written to {tmp_path.resolve() / 'report.html'}" in caplog.text
    assert ".staging" not in caplog.text


def test_unknown_stage_key_is_refused_where_the_stage_is_defined():
    """A misspelt key would hash as None and never re-run the stage: refused at definition."""
    from pipeline.engine.study import Stage

    with pytest.raises(ValueError, match=r"unknown config key\(s\) \['training.epochz'\]"):
        Stage("x", lambda ctx: None, ("training.epochs", "training.epochz"))


def test_every_study_stage_depends_on_real_keys():
    from pipeline.config import is_config_key
    from pipeline.stages import STAGES

    for st in STAGES:
        assert all(is_config_key(k) for k in st.config_keys), st.name


def _old_a(ctx):
    ctx.out("x.txt").write_text("x")
    ctx.out("y.txt").write_text("y-old")


def _new_a0(ctx):
    ctx.out("y.txt").write_text("y-new")


def _new_a(ctx):
    ctx.out("x.txt").write_text("x")


def test_an_output_that_moved_to_another_stage_stays(tmp_path):
    # a new stage takes over an output another stage's old record lists (the study's
    # truth_traces took truth/site_truth.npz from truth): the old owner's commit must not
    # remove what the new owner has just written
    run_study(StudyConfig(), tmp_path, stages=(Stage("a", _old_a, ("seed",)),),
              manifest_extra=None, command_line=["test"])
    new = (Stage("a0", _new_a0, ("seed",)), Stage("a", _new_a, ("seed",), version=2))
    r = run_study(StudyConfig(), tmp_path, stages=new, manifest_extra=None, command_line=["test"])
    assert r.ran == ["a0", "a"]
    assert (tmp_path / "y.txt").read_text() == "y-new"
    man = json.loads((tmp_path / "manifest.json").read_text())
    assert "y.txt" in man["files"] and "y.txt" in r.records["a0"].outputs
    assert "y.txt" not in r.records["a"].outputs
    assert run_study(StudyConfig(), tmp_path, stages=new, manifest_extra=None,
                     command_line=["test"]).ran == []
