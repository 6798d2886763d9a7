"""Stages side by side: a stage marked ``own_process`` runs in a spawned process beside the
stages before it, from the first one that runs once its upstream stages are done
(pipeline.engine.study, pipeline.engine.stageproc).

The stage functions are module-level (they travel to the spawned interpreter by
reference) and write the process id they ran in, so each test sees where a stage ran.
"""

from __future__ import annotations

import json
import os
import time

import pytest

from pipeline.config import StudyConfig, replace_path
from pipeline.engine.study import Stage, StageError, StudyInterrupted, run_study
from pipeline.parallel import usable_cpus

pytestmark = [pytest.mark.skipif(usable_cpus() < 2, reason="one CPU: stages run in order"),
              pytest.mark.parallel]


def _a(ctx):
    # long enough that the side stage starts and finishes while this one runs
    time.sleep(float(os.environ.get("TEST_SIDE_A_S", "1.0")))
    if ctx.config.training.step_size > 0.5:
        raise RuntimeError("a: step too large")
    if ctx.config.training.step_size == 0.25:
        raise KeyboardInterrupt  # Ctrl-C here, while b runs beside
    stage = json.loads(ctx.store.path("manifest.json").read_text())["stage"]
    ctx.out("a.json").write_text(json.dumps({"pid": os.getpid(), "manifest_stage": stage}))
    return {"pid": os.getpid()}


def _b(ctx):
    if ctx.config.training.epochs == 13:
        raise ValueError("b: unlucky epochs")
    if ctx.config.training.epochs == 14:
        raise KeyboardInterrupt
    if ctx.config.training.epochs == 15:
        os._exit(3)  # killed: no word back
    if ctx.config.training.epochs == 16:
        time.sleep(30)  # still running when the stage beside it is interrupted
    ctx.out("b/out.json").write_text(json.dumps({"pid": os.getpid(), "seed": ctx.config.seed,
                                                 "sde": os.environ.get("SOURCE_DATE_EPOCH")}))
    return {"pid": os.getpid()}


def _c(ctx):
    a = json.loads(ctx.input("a.json").read_text())
    b = json.loads(ctx.input("b/out.json").read_text())
    ctx.out("c.json").write_text(json.dumps({"a": a["pid"], "b": b["pid"]}))


def _b_after_a(ctx):
    ctx.input("a.json")
    return _b(ctx)


SIDE = (
    Stage("a", _a, ("seed", "training.step_size")),
    Stage("b", _b, ("seed", "training.epochs"), own_process=True, description="b"),
    Stage("c", _c, (), ("a", "b")),
)


def _run(cfg, d, stages=SIDE, **kw):
    return run_study(cfg, d, stages=stages, manifest_extra=None, command_line=["test"], **kw)


def _pids(d):
    return json.loads((d / "c.json").read_text())


def test_independent_stage_runs_in_its_own_process(tmp_path):
    r = _run(StudyConfig(), tmp_path)
    assert r.ran == ["a", "b", "c"]
    pids = _pids(tmp_path)
    assert pids["a"] == os.getpid() and pids["b"] != os.getpid()
    # while both ran, the manifest named both (a killed run says so)
    assert json.loads((tmp_path / "a.json").read_text())["manifest_stage"] == "a + b"
    # the child sees what a stage here sees: reproducible dates
    assert json.loads((tmp_path / "b/out.json").read_text())["sde"] == "0"
    man = json.loads((tmp_path / "manifest.json").read_text())
    assert man["status"] == "complete" and man["stage"] is None
    assert "b/out.json" in man["files"] and man["stages"]["b"]["info"]["pid"] == pids["b"]
    assert not (tmp_path / ".staging").exists()
    # a second run skips both; a change to b's key re-runs b (alone: a is cached) and c
    assert _run(StudyConfig(), tmp_path).ran == []
    r = _run(replace_path(StudyConfig(), "training.epochs", 7), tmp_path)
    assert r.ran == ["b", "c"] and r.cached == ["a"]
    assert _pids(tmp_path)["b"] == os.getpid()  # nothing to run beside: in order, here


def _x(ctx):
    # a stage between a and b, which b does not need either; what the manifest named
    stage = json.loads(ctx.store.path("manifest.json").read_text())["stage"]
    ctx.out("x.json").write_text(json.dumps({"pid": os.getpid(), "manifest_stage": stage}))


def test_side_stage_starts_as_early_as_its_upstream_allows(tmp_path):
    # b needs nothing of a or x: it starts beside a, runs on beside x, and is waited for
    # where it stands (before c, which needs it); as truth_traces beside the tour and reads
    stages = (SIDE[0], Stage("x", _x, ("seed",)), SIDE[1], SIDE[2])
    r = _run(StudyConfig(), tmp_path, stages=stages)
    assert r.ran == ["a", "x", "b", "c"]
    pids = _pids(tmp_path)
    assert pids["a"] == os.getpid() and pids["b"] != os.getpid()
    assert json.loads((tmp_path / "a.json").read_text())["manifest_stage"] == "a + b"
    assert json.loads((tmp_path / "x.json").read_text())["manifest_stage"] in ("x + b", "x")
    # b depends on a: it cannot start before a is done, so it starts beside x
    dep = (SIDE[0], Stage("x", _x, ("seed",)), Stage("b", _b_after_a, ("seed",), ("a",),
                                                     own_process=True), SIDE[2])
    _run(StudyConfig(), tmp_path / "dep", stages=dep)
    assert _pids(tmp_path / "dep")["b"] != os.getpid()
    assert json.loads((tmp_path / "dep" / "x.json").read_text())["manifest_stage"] == "x + b"


def _blas_threads() -> int:
    from threadpoolctl import threadpool_info

    # 0 where threadpoolctl sees no BLAS pool: the test then skips (no limit can be seen)
    return max((p["num_threads"] for p in threadpool_info() if p["user_api"] == "blas"), default=0)


def _a_blas(ctx):
    time.sleep(1.0)  # the side stage is running meanwhile
    ctx.out("a.json").write_text(json.dumps({"pid": os.getpid(), "blas": _blas_threads()}))


def _b_blas(ctx):
    ctx.out("b/out.json").write_text(json.dumps({"pid": os.getpid(), "blas": _blas_threads(),
                                                 "nice": os.nice(0)}))


def test_side_by_side_processes_share_the_blas_threads(tmp_path):
    # OpenBLAS's threads spin while waiting: beside each other, the runner's process and
    # the stage's each use half the CPUs' worth; the runner's own are restored after
    from pipeline.parallel import blas_threads_per_process

    here = _blas_threads()
    if here <= blas_threads_per_process(2):
        pytest.skip(f"this process has {here} BLAS thread(s): a limit could not be seen")
    if os.nice(0) >= 19:
        pytest.skip("this process already runs at the lowest priority: no lower one to see")
    stages = (Stage("a", _a_blas, ("seed",)), Stage("b", _b_blas, ("seed",), own_process=True),
              SIDE[2])
    _run(StudyConfig(), tmp_path, stages=stages)
    a = json.loads((tmp_path / "a.json").read_text())
    b = json.loads((tmp_path / "b/out.json").read_text())
    assert b["pid"] != os.getpid()
    assert a["blas"] == b["blas"] == blas_threads_per_process(2)
    assert _blas_threads() == here
    # and it runs at a lower priority: the runner's stages are the critical path
    from pipeline.engine.stageproc import SIDE_NICENESS

    assert b["nice"] == min(19, os.nice(0) + SIDE_NICENESS) > os.nice(0)


def test_dependent_stage_or_one_worker_runs_in_order(tmp_path, monkeypatch):
    dep = (SIDE[0], Stage("b", _b_after_a, ("seed",), ("a",), own_process=True), SIDE[2])
    _run(StudyConfig(), tmp_path / "dep", stages=dep)
    assert _pids(tmp_path / "dep")["b"] == os.getpid()
    monkeypatch.setenv("RFIDSTUDY_WORKERS", "1")
    _run(StudyConfig(), tmp_path / "one")
    assert _pids(tmp_path / "one")["b"] == os.getpid()


def test_failure_in_the_side_stage_keeps_the_other_and_resumes(tmp_path):
    bad = replace_path(StudyConfig(), "training.epochs", 13)
    with pytest.raises(StageError, match=r"stage 'b' failed: ValueError: b: unlucky epochs \(earlier"):
        _run(bad, tmp_path)
    man = json.loads((tmp_path / "manifest.json").read_text())
    assert man["status"] == "failed" and man["failure"]["stage"] == "b"
    assert (tmp_path / "a.json").exists() and not (tmp_path / "b").exists()
    assert not (tmp_path / ".staging" / "b").exists()
    r = _run(StudyConfig(), tmp_path)
    assert r.cached == ["a"] and r.ran == ["b", "c"]


def test_failure_beside_the_side_stage_stops_it(tmp_path, monkeypatch):
    monkeypatch.setenv("TEST_SIDE_A_S", "0")
    bad = replace_path(StudyConfig(), "training.step_size", 0.9)
    with pytest.raises(StageError, match="stage 'a' failed: RuntimeError: a: step too large"):
        _run(bad, tmp_path)
    man = json.loads((tmp_path / "manifest.json").read_text())
    assert man["status"] == "failed" and man["failure"]["stage"] == "a"
    # b ran beside a, but nothing of it is kept: no record, no output, no staging
    assert not (tmp_path / "stages" / "b.json").exists() and not (tmp_path / "b").exists()
    assert not (tmp_path / ".staging" / "b").exists()


def test_interrupt_in_the_side_stage(tmp_path):
    with pytest.raises(StudyInterrupted):
        _run(replace_path(StudyConfig(), "training.epochs", 14), tmp_path)
    man = json.loads((tmp_path / "manifest.json").read_text())
    assert man["status"] == "interrupted" and man["stage"] == "b"
    assert (tmp_path / "a.json").exists() and not (tmp_path / ".staging" / "b").exists()


def test_process_that_dies_is_the_stages_failure(tmp_path):
    with pytest.raises(StageError, match=r"stage 'b' failed: ProcessDied: .*exit code 3"):
        _run(replace_path(StudyConfig(), "training.epochs", 15), tmp_path)
    man = json.loads((tmp_path / "manifest.json").read_text())
    assert man["status"] == "failed" and man["failure"]["stage"] == "b"
    assert (tmp_path / "a.json").exists() and not (tmp_path / ".staging" / "b").exists()


def test_interrupt_beside_the_side_stage_stops_both(tmp_path, monkeypatch):
    monkeypatch.setenv("TEST_SIDE_A_S", "2.0")  # b is under way when a is interrupted
    cfg = replace_path(replace_path(StudyConfig(), "training.step_size", 0.25), "training.epochs", 16)
    t0 = time.perf_counter()
    with pytest.raises(StudyInterrupted):
        _run(cfg, tmp_path)
    assert time.perf_counter() - t0 < 20  # b (30 s) was stopped, not waited for
    man = json.loads((tmp_path / "manifest.json").read_text())
    assert man["status"] == "interrupted" and man["stage"] == "a + b"
    assert not (tmp_path / ".staging" / "a").exists() and not (tmp_path / ".staging" / "b").exists()
    assert not (tmp_path / "stages" / "b.json").exists()


def test_blas_limit_restored_when_the_side_stage_is_stopped(tmp_path, monkeypatch):
    # a failure beside the side stage stops it: the runner's BLAS threads come back too
    monkeypatch.setenv("TEST_SIDE_A_S", "0")
    here = _blas_threads()
    with pytest.raises(StageError, match="a: step too large"):
        _run(replace_path(StudyConfig(), "training.step_size", 0.9), tmp_path)
    assert _blas_threads() == here
