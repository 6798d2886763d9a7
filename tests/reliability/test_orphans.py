"""Workers die with their parent: ``kill -9`` of a sweep's, placement's or replicated
run's main process leaves no worker finishing its study and idling at a gigabyte
(issue 54); the forked tasks of a study likewise. Where one still lives (a platform
without PR_SET_PDEATHSIG, a worker started by hand), a rerun pools or ranks nothing
while it writes: the replicate or candidate is named with the writer's PID."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import textwrap
import time
from pathlib import Path

import pytest

pytestmark = pytest.mark.skipif(not sys.platform.startswith("linux"), reason="PR_SET_PDEATHSIG")

PARENT = textwrap.dedent("""
    import concurrent.futures as cf, multiprocessing, os, sys, time
    from pipeline.apps.studypool import _cap_nested_workers
    if __name__ == "__main__":
        ctx = multiprocessing.get_context("spawn")
        with cf.ProcessPoolExecutor(1, mp_context=ctx, initializer=_cap_nested_workers,
                                    initargs=(1,)) as ex:
            print(ex.submit(os.getpid).result(), flush=True)
            ex.submit(time.sleep, 120)  # a study under way
            time.sleep(120)
""")


def _alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    with open(f"/proc/{pid}/stat") as fh:  # a zombie is dead, only not yet reaped
        return fh.read().split(")")[-1].split()[0] != "Z"


def test_a_sweep_worker_dies_with_its_killed_parent(tmp_path):
    script = tmp_path / "parent.py"
    script.write_text(PARENT)
    proc = subprocess.Popen([sys.executable, str(script)], stdout=subprocess.PIPE, text=True)
    try:
        worker = int(proc.stdout.readline())
        assert _alive(worker)
        proc.send_signal(signal.SIGKILL)
        proc.wait(timeout=10)
        t0 = time.monotonic()
        while _alive(worker) and time.monotonic() - t0 < 10:
            time.sleep(0.1)
        assert not _alive(worker), "the worker outlived its killed parent"
    finally:
        if proc.poll() is None:
            proc.kill()


# -- a rerun while a worker of a killed run still writes ---------------------------------

ROOT = Path(__file__).resolve().parents[2]
#: A worker of an earlier run: a study in ``argv[1]`` whose stage never ends, holding the
#: run directory's lock as every study does while it runs.
WRITER = textwrap.dedent("""
    import sys, time
    from pipeline.config import StudyConfig
    from pipeline.engine.study import Stage, run_study

    def forever(ctx):
        print("writing", flush=True)
        time.sleep(600)

    run_study(StudyConfig(), sys.argv[1], stages=(Stage("tour", forever, ("seed",)),),
              manifest_extra=None, command_line=["rfidstudy", "run", "--replicates", "(point)"])
""")


@pytest.fixture
def writer(tmp_path):
    """``start(run_dir)`` starts a live writer of ``run_dir``; its process is returned."""
    procs = []
    env = {**os.environ, "PYTHONPATH": f"{ROOT}{os.pathsep}{os.environ.get('PYTHONPATH', '')}"}

    def start(run_dir: Path) -> subprocess.Popen:
        script = tmp_path / "writer.py"
        script.write_text(WRITER)
        p = subprocess.Popen([sys.executable, str(script), str(run_dir)], stdout=subprocess.PIPE,
                             text=True, env=env)
        procs.append(p)
        assert p.stdout.readline().strip() == "writing"
        return p

    yield start
    for p in procs:
        if p.poll() is None:
            p.kill()
            p.wait(timeout=10)


def test_a_live_writer_is_named_with_its_pid_and_a_dead_ones_lock_is_free(tmp_path, writer):
    from pipeline.engine.runstore import RunDirLocked, check_no_writer, lock_holder

    free, busy = tmp_path / "r0", tmp_path / "r1"
    free.mkdir()
    assert lock_holder(free) is None and not (free / ".rfidstudy.lock").exists()  # nothing made
    p = writer(busy)
    assert f"process {p.pid} (rfidstudy run --replicates (point)" in lock_holder(busy)
    with pytest.raises(RunDirLocked, match=rf"{busy} is still being written by process {p.pid} "
                                           r".*: pooling refused"):
        check_no_writer([free, busy, tmp_path / "missing"], "pooling")
    p.send_signal(signal.SIGKILL)
    p.wait(timeout=10)
    assert lock_holder(busy) is None  # the kernel released the dead writer's lock
    check_no_writer([free, busy], "pooling")
    # a study refused for the lock during this run: not complete, so not pooled either
    row = {"status": "failed", "kind": "RunDirLocked",
           "error": f"{busy} is in use by process {p.pid} (x): one writer per run directory"}
    with pytest.raises(RunDirLocked, match=rf"in use by process {p.pid} .*: pooling refused"):
        check_no_writer([free, busy], "pooling", [{"status": "complete"}, row])


def _cli(tmp_path, *args, timeout=600):
    env = {**os.environ, "PYTHONPATH": f"{ROOT}{os.pathsep}{os.environ.get('PYTHONPATH', '')}",
           "RFIDSTUDY_CACHE": str(tmp_path / "cache"), "COLUMNS": "200"}
    return subprocess.run([sys.executable, "-m", "pipeline", *map(str, args)], cwd=tmp_path, env=env,
                          capture_output=True, text=True, timeout=timeout)


@pytest.mark.slow
def test_replicates_are_not_pooled_while_an_earlier_worker_writes_one(tmp_path, writer):
    """Issue 54: a rerun while a killed run's worker lived pooled 1 of 3 with exit 0."""
    from pipeline.config import StudyConfig
    from pipeline.engine.study import Stage, run_study

    out = tmp_path / "run"  # the killed run's directory, one of its workers still writing
    run_study(StudyConfig(), out, stages=(Stage("replicates", lambda ctx: {}, ("seed",)),),
              manifest_extra=None, command_line=["rfidstudy", "run", "--replicates", "2"])
    p = writer(out / "replicates" / "1")
    res = _cli(tmp_path, "run", ROOT / "configs" / "tiny.toml", "--no-progress", "--replicates", "2",
               "--out", out)
    errors = [ln for ln in res.stderr.splitlines() if ln.startswith("error:")]
    assert res.returncode == 1 and len(errors) == 1, res.stdout + res.stderr
    assert f"{out / 'replicates' / '1'} is still being written by process {p.pid}" in errors[0]
    assert "pooling the replicates refused" in errors[0]
    assert not (out / "metrics.json").exists()
    assert (out / "replicates" / "0" / "metrics.json").is_file()  # the other one ran


@pytest.mark.slow
def test_placement_ranks_nothing_while_an_earlier_worker_writes_a_candidate(tmp_path, writer):
    from pipeline.apps.placement import candidates_of, load_placement

    spec_file = tmp_path / "placement.toml"
    spec_file.write_text(f'base = "{ROOT / "configs" / "tiny.toml"}"\nreplicates = 1\n'
                         'primary = "reads_per_pass"\npareto = ["link_margin_db", "never_read"]\n'
                         '[grid]\ntilt_deg = [0.0, 10.0, 20.0]\n'
                         "[study.downstream]\nenabled = false\n")
    names = [c.name for c in candidates_of(load_placement(spec_file))]
    out = tmp_path / "out"  # the killed placement's directory, one of its workers still writing
    out.mkdir()
    (out / "placement.json").write_text('{"tool": "rfidstudy", "kind": "placement"}')
    busy = out / "candidates" / names[1] / "0"
    p = writer(busy)
    res = _cli(tmp_path, "placement", spec_file, "--out", out, "--workers", "1")
    errors = [ln for ln in res.stderr.splitlines() if ln.startswith("error:")]
    assert res.returncode == 2 and len(errors) == 1, res.stdout + res.stderr
    assert f"{busy} is still being written by process {p.pid}" in errors[0], errors
    assert "ranking the candidates refused" in errors[0]
    assert not (out / "placement" / "ranking.csv").exists() and not list(out.glob("placement/*.csv"))
