"""Fixtures of the whole suite.

``tiny_study``: one real tiny study per test session (``configs/tiny.toml``: corridor_lab,
5 m of route, low ray counts, 3 epochs; real MCL, real Sionna traces, real Parquet, real
ANFIS, real figures) with a propagation cache of its own, run as a user runs it: the
``rfidstudy run`` command in a process of its own, its console kept
(tests/pipeline/test_cli_study.py reads it). The study tests read its run directory; a
test that changes a run works on a copy (:func:`copy_run`), and one that counts the
cache's files on a copy of the cache (:func:`link_copy`): the run directory and the cache
are shared by every test of the session.

Under pytest-xdist the workers share it too: the first worker to finish collecting starts
building it in the background, in the session's temporary folder (the parent of the
workers' own), under a file lock, so that it runs beside the first tests; a test that needs
it waits for it (about a minute of CPU on a 2-core machine). Without xdist the first test
that needs it builds it. Nothing writes into the run directory after it is built; the
cache takes more traces (oracle, recorded studies), which several processes may do at once
(propagation.pathcache).

Each xdist worker runs with its share of the CPUs (:func:`pytest_configure`); a test of
processes or threads side by side is marked ``parallel`` and gets them all.
"""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
from dataclasses import dataclass
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]


@dataclass(frozen=True)
class TinyStudy:
    """The session's tiny study: its config, the run directory, the command's console."""

    config: object
    """The resolved :class:`pipeline.config.StudyConfig` (its cache under ``base``)."""
    base: Path
    """Folder holding ``run/`` and ``cache/`` (the study's own propagation cache)."""

    @property
    def run(self) -> Path:
        """The run directory (read it; copy it before changing anything)."""
        return self.base / "run"

    @property
    def console(self) -> list[str]:
        """What the command printed (stdout, then stderr), line by line, 80 columns wide."""
        return (self.base / "console.txt").read_text().splitlines()


def session_folder(tmp_path_factory) -> Path:
    """The test session's temporary folder, shared by its xdist workers (the parent of
    each worker's own basetemp), else the basetemp itself."""
    base = tmp_path_factory.getbasetemp()
    return base.parent if os.environ.get("PYTEST_XDIST_WORKER") else base


#: How the session's tiny study is built (:func:`build_tiny`): the command line's entry
#: point, as the ``rfidstudy`` script runs it, with the config and the cache of the study.
CLI_MAIN = "from pipeline.apps.cli import app; app(prog_name='rfidstudy')"
#: Building the tiny study in a process of its own (:func:`pytest_collection_finish`).
BUILD_MAIN = ("import sys; from pathlib import Path; from tests.conftest import build_tiny; "
              "build_tiny(Path(sys.argv[1]))")


def build_tiny(base: Path) -> None:
    """Run the tiny study into ``base/run`` with ``rfidstudy run``, in a process of its own,
    with every CPU; write ``base/console.txt`` (stdout, then stderr) when it succeeds,
    ``base/failed.txt`` (the exit code and the end of stderr) when it does not."""
    env = {k: v for k, v in os.environ.items() if k not in _SHARE_SET}
    env["COLUMNS"] = "80"
    try:
        proc = subprocess.run(
            [sys.executable, "-c", CLI_MAIN, "run", "configs/tiny.toml", "--out", str(base / "run"),
             "--set", f"tracing.cache_dir='{base / 'cache'}'"],
            cwd=ROOT, env=env, capture_output=True, text=True, timeout=900)
    except subprocess.TimeoutExpired as exc:  # a cold Dr.Jit kernel cache: about 2 minutes
        _write_whole(base / "failed.txt", f"timed out after {exc.timeout} s")
        return
    if proc.returncode != 0:
        _write_whole(base / "failed.txt", f"exit {proc.returncode}:\n{proc.stderr[-3000:]}")
    else:
        _write_whole(base / "console.txt", proc.stdout + proc.stderr)


def _write_whole(path: Path, text: str) -> None:
    """``path`` appears with all of ``text`` or not at all (another worker polls for it)."""
    from scenes.fileio import atomic_output

    with atomic_output(path) as tmp:
        tmp.write_text(text)


_BUILD: subprocess.Popen | None = None  # the tiny study's build, where this process started it


def _uses_tiny(item) -> bool:
    return "tiny_study" in getattr(item, "fixturenames", ())


def pytest_collection_finish(session):
    """Start building the tiny study in the background as soon as the session is known to
    need it (under xdist: by the first worker here), so that it runs beside the first
    tests rather than holding up the first that needs it."""
    global _BUILD
    if (session.config.option.collectonly or not os.environ.get("PYTEST_XDIST_WORKER")
            or not any(_uses_tiny(it) for it in session.items)):
        return  # nothing will run, or one process: built when first needed (tiny_study)
    from filelock import FileLock

    shared = session_folder(session.config._tmp_path_factory)
    base = shared / "tiny"
    with FileLock(str(shared / "tiny.lock")):
        if (base / "started").exists():
            return
        base.mkdir(parents=True, exist_ok=True)
        # a session of its own: the study's processes are killed as one group
        with open(base / "build.err", "w") as err:
            _BUILD = subprocess.Popen(
                [sys.executable, "-c", BUILD_MAIN, str(base)], cwd=ROOT,
                env={k: v for k, v in os.environ.items() if k not in _SHARE_SET},
                stdout=subprocess.DEVNULL, stderr=err, start_new_session=True)
        _write_whole(base / "started", str(_BUILD.pid))


def pytest_sessionfinish(session, exitstatus):
    """The background build ends with the session that started it: waited for where the
    session ran its course (another worker may be waiting for it), its whole process group
    killed where it stopped early (Ctrl-C, ``-x``, a collection error; a worker still
    waiting then sees it gone and builds the study itself)."""
    import signal

    if _BUILD is None or _BUILD.poll() is not None:
        return
    stopped = session.shouldstop or session.shouldfail or exitstatus not in (
        pytest.ExitCode.OK, pytest.ExitCode.TESTS_FAILED)
    if stopped:
        try:
            os.killpg(_BUILD.pid, signal.SIGKILL)
        except ProcessLookupError:
            pass
    _BUILD.wait()


def _running(pid: int) -> bool:
    try:
        with open(f"/proc/{pid}/stat") as fh:  # a zombie is dead, only not yet reaped
            return fh.read().split(")")[-1].split()[0] != "Z"
    except OSError:
        try:
            os.kill(pid, 0)
        except ProcessLookupError:
            return False
        return True


@pytest.fixture(scope="session")
def tiny_study(tmp_path_factory) -> TinyStudy:
    import time

    from filelock import FileLock

    from pipeline.config import load_config, replace_path

    shared = session_folder(tmp_path_factory)
    base = shared / "tiny"
    cfg = load_config(ROOT / "configs" / "tiny.toml")
    cfg = replace_path(cfg, "tracing.cache_dir", str(base / "cache"))
    done, failed, started = base / "console.txt", base / "failed.txt", base / "started"
    with FileLock(str(shared / "tiny.lock")):
        if not (done.is_file() or failed.is_file()):
            if started.is_file():  # built in the background: wait for it
                pid = int(started.read_text())
                while not (done.is_file() or failed.is_file()) and _running(pid):
                    time.sleep(0.2)
            if not (done.is_file() or failed.is_file()):  # not started, or it died
                base.mkdir(parents=True, exist_ok=True)
                build_tiny(base)
    if failed.is_file():
        err = base / "build.err"  # the background builder's own errors, if any
        extra = f"\n{err.read_text()[-2000:]}" if err.is_file() and err.stat().st_size else ""
        pytest.fail(f"the tiny study failed: {failed.read_text()}{extra}")
    return TinyStudy(cfg, base)


#: What each xdist worker's share of the CPUs is set with (:func:`pytest_configure`).
SHARE_ENV = ("RFIDSTUDY_WORKERS", "OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS")
_SHARE_SET: list[str] = []  # those of them set here (not by the user)
_SHARE_APPLIED: list[int] = []  # the share, where this process runs with one


def pytest_configure(config):
    """Under pytest-xdist, each worker process runs with its share of the CPUs, as a sweep's
    worker does (:func:`pipeline.apps.studypool`): ``RFIDSTUDY_WORKERS``, the BLAS threads
    and Dr.Jit's LLVM threads at :func:`pipeline.parallel.blas_threads_per_process` of the
    workers (one each with ``-n 2`` on 2 CPUs). The workers already keep every CPU busy; a study's
    forked tasks, a stage in a spawned interpreter beside the others, or OpenBLAS threads
    spinning beside another worker's only add their start-up (about 5 s of CPU per
    spawned interpreter). A test of those paths is marked ``parallel``
    (:func:`_parallel_tests_get_the_cpus`); the session's tiny study runs as a user runs
    it, with every CPU (:func:`tiny_study`)."""
    config.addinivalue_line("markers", "parallel: runs processes or threads side by side "
                            "(the xdist worker's share of the CPUs is lifted)")
    n = int(os.environ.get("PYTEST_XDIST_WORKER_COUNT", "0") or 0)
    if n < 2:
        return
    from pipeline.parallel import blas_threads_per_process, limit_blas_threads

    share = blas_threads_per_process(n)
    for name in SHARE_ENV:  # this process's children (stage processes, CLI runs, Dask)
        if name not in os.environ:  # a user's own setting stands
            os.environ[name] = str(share)
            _SHARE_SET.append(name)
    _SHARE_APPLIED.append(share)
    limit_blas_threads(share)  # this process's own pools
    # Dr.Jit's LLVM threads: two per process beside busy ones took 33 s of CPU for 28 s of
    # tracing (tests/propagation/test_tracing.py and test_anchored.py beside 3 busy loops)
    if "drjit" not in sys.modules and "DRJIT_LIBLLVM_PATH" not in os.environ:
        # Dr.Jit picks its libLLVM when imported: the one propagation.select_variant would
        from propagation.backend import BackendError, find_libllvm

        try:
            os.environ["DRJIT_LIBLLVM_PATH"] = find_libllvm()
        except BackendError:
            pass  # select_variant says so where a test traces
    import drjit as dr

    dr.set_thread_count(share)


@pytest.fixture(autouse=True)
def _parallel_tests_get_the_cpus(request, monkeypatch):
    """A test marked ``parallel`` runs with every CPU: the share set by
    :func:`pytest_configure` is lifted for it (and for the processes it starts)."""
    if request.node.get_closest_marker("parallel") is None or not _SHARE_APPLIED:
        yield
        return
    import drjit as dr

    from pipeline.parallel import WORKERS_ENV, limit_blas_threads, usable_cpus
    from propagation import backend

    for name in {*_SHARE_SET, WORKERS_ENV}:  # a cap of the user's too: these test the paths
        monkeypatch.delenv(name, raising=False)
    limits = limit_blas_threads(usable_cpus())
    threads = dr.thread_count()
    # set_deterministic(False) restores the thread count of its first call in the process:
    # one made here must not hand later tests every CPU
    state = dict(backend._state)
    dr.set_thread_count(usable_cpus())
    try:
        yield
    finally:
        limits.restore_original_limits()
        dr.set_thread_count(threads)
        if "default_threads" in state:
            backend._state["default_threads"] = state["default_threads"]
        else:
            backend._state.pop("default_threads", None)


def copy_run(study: TinyStudy, dest: Path, **kw) -> Path:
    """A copy of the tiny study's run directory at ``dest`` (``shutil.copytree`` keywords)."""
    shutil.copytree(study.run, dest, **kw)
    return dest


def link_copy(src: Path, dest: Path) -> Path:
    """``src`` copied to ``dest`` as hard links (a propagation cache: its files are written
    once under new names and never changed, so the copy costs no bytes and later writes
    into either folder do not show in the other)."""
    shutil.copytree(src, dest, copy_function=os.link)
    return dest


def draw_only(monkeypatch, *names: str) -> None:
    """The figures stage (and ``rfidstudy figures``) draws only ``names``: every figure
    of the tiny study is drawn by its own figures stage, every figure of a fake run by
    tests/pipeline/figures; a test of what re-runs needs the stage, not its twelve
    figures (about 20 s of CPU)."""
    import pipeline.figures.drawall as drawall

    monkeypatch.setattr(drawall, "FIGURES", {k: drawall.FIGURES[k] for k in names})
