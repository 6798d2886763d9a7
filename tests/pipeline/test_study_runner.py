"""The stage runner: caching, selective re-runs, failure and resume, corrupt files.

These tests drive :func:`pipeline.study.run_study` with small stages of its own (the
runner is what is under test here); the real study on a real scene is exercised in
test_study_tiny.py.
"""

from __future__ import annotations

import json
import logging

import pytest

from pipeline.config import StudyConfig, replace_path
from pipeline.study import Stage, StageError, run_study

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
