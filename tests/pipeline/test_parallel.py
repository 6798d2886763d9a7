"""pipeline.parallel: tasks in forked processes, results in task order, errors raised."""

from __future__ import annotations

import os
import threading

import pytest

from pipeline.parallel import WORKERS_ENV, fork_workers, map_forked

pytestmark = pytest.mark.parallel


@pytest.fixture(autouse=True)
def _forking_allowed(monkeypatch):
    """Each test starts where forking is allowed: no worker cap from the environment and
    no other thread of the test session (a lingering non-daemon thread would make every
    task run in place and the forking tests pass without forking)."""
    monkeypatch.delenv(WORKERS_ENV, raising=False)
    monkeypatch.setattr(threading, "enumerate", lambda: [threading.current_thread()])


def test_results_in_task_order_from_forked_children():
    assert fork_workers(2, 6) == 2  # else the rest would pass without forking
    offset = 7  # a closure: the children inherit it, nothing is pickled but the index
    out = map_forked(lambda i: (i + offset, os.getpid()), 6, workers=2)
    assert [v for v, _ in out] == [7, 8, 9, 10, 11, 12]
    pids = {p for _, p in out}
    assert os.getpid() not in pids  # run in children, not here


def test_one_worker_runs_here_in_order():
    seen = []
    out = map_forked(lambda i: seen.append(i) or os.getpid(), 3, workers=1)
    assert seen == [0, 1, 2] and set(out) == {os.getpid()}


def test_a_task_error_is_raised_here():
    assert fork_workers(2, 4) == 2

    def task(i):
        if i == 2:
            raise RuntimeError(f"task {i} failed")
        return i

    with pytest.raises(RuntimeError, match="task 2 failed"):
        map_forked(task, 4, workers=2)


def test_no_fork_while_another_non_daemon_thread_runs(monkeypatch):
    # only this test's threads count: others the test session may run are hidden
    mine = {threading.current_thread()}
    monkeypatch.setattr(threading, "enumerate", lambda: list(mine))
    stop = threading.Event()
    th = threading.Thread(target=stop.wait)
    th.start()
    mine.add(th)
    try:
        assert fork_workers(None, 8) == 1
        assert fork_workers(2, 8) == 1  # asked-for workers do not override the rule
    finally:
        stop.set()
        th.join()
    daemon = threading.Thread(target=stop.wait, daemon=True)  # a progress bar's refresh
    stop.clear()
    daemon.start()
    mine.discard(th)
    mine.add(daemon)
    try:
        assert fork_workers(None, 8) == min(8, len(os.sched_getaffinity(0)))
    finally:
        stop.set()
    with pytest.raises(ValueError, match="workers"):
        fork_workers(0, 3)
    assert fork_workers(5, 2) == 2


def test_no_fork_from_another_thread():
    # the fixture shows only the calling thread, so the thread rule alone cannot
    # refuse: only "not the main thread" can
    assert fork_workers(2, 8) == 2
    got = []
    th = threading.Thread(target=lambda: got.append(fork_workers(2, 8)))
    th.start()
    th.join()
    assert got == [1]


def test_environment_caps_the_workers(monkeypatch):
    monkeypatch.setenv(WORKERS_ENV, "1")
    assert fork_workers(None, 8) == 1 and fork_workers(4, 8) == 1
    monkeypatch.setenv(WORKERS_ENV, "2")
    assert fork_workers(4, 8) == 2  # the cap, not the 4 asked for
    assert fork_workers(4, 1) == 1  # nor more than the tasks
    for bad in ("zero", "0", "-1"):
        monkeypatch.setenv(WORKERS_ENV, bad)
        with pytest.raises(ValueError, match=WORKERS_ENV):
            fork_workers(None, 8)


class _Unpicklable(Exception):
    def __init__(self, handle):
        super().__init__("held a handle")
        self.handle = handle

    def __reduce__(self):
        raise TypeError("cannot pickle a handle")


def test_an_unpicklable_task_error_comes_back_as_its_traceback():
    assert fork_workers(2, 3) == 2

    def task(i):
        if i == 1:
            raise _Unpicklable(threading.Lock())
        return i

    with pytest.raises(RuntimeError, match="(?s)task 1 raised.*_Unpicklable: held a handle"):
        map_forked(task, 3, workers=2)


def test_an_unpicklable_task_error_travels_where_tblib_pickles_exception_chains():
    # Dask's distributed installs tblib's pickling support, which pickles an exception
    # with its __context__: a _TaskError raised inside the handler carried the
    # unpicklable exception along, and the worker died ("terminated abruptly"; the full
    # suite, after tests/pipeline/test_trace_tasks.py). Fails if _TaskError has a context.
    import copyreg

    pickling = pytest.importorskip("tblib.pickling_support")

    def task(i):
        if i == 1:
            raise _Unpicklable(threading.Lock())
        return i

    before = dict(copyreg.dispatch_table)
    pickling.install()  # as distributed does: every exception class, tracebacks too
    try:
        with pytest.raises(RuntimeError, match="(?s)task 1 raised.*_Unpicklable: held a handle"):
            map_forked(task, 3, workers=2)
    finally:  # the registrations are the process's: restore the table in place
        copyreg.dispatch_table.clear()
        copyreg.dispatch_table.update(before)


def _blas_threads() -> int:
    from threadpoolctl import threadpool_info

    # 0 where threadpoolctl sees no BLAS pool (NumPy built without one, or a library it
    # cannot inspect): the callers then skip, naming what could not be seen
    pools = [p["num_threads"] for p in threadpool_info() if p["user_api"] == "blas"]
    return max(pools, default=0)


def test_pool_processes_share_the_blas_threads(monkeypatch):
    # OpenBLAS's threads spin while waiting: n processes each get cpus // n threads
    from pipeline.parallel import blas_threads_per_process, usable_cpus

    monkeypatch.setattr("pipeline.parallel.usable_cpus", lambda: 4)
    assert [blas_threads_per_process(n) for n in (1, 2, 3, 4, 8)] == [4, 2, 1, 1, 1]
    monkeypatch.setattr("pipeline.parallel.usable_cpus", usable_cpus)
    here = _blas_threads()
    if here <= blas_threads_per_process(2):
        pytest.skip(f"this process has {here} BLAS thread(s): a limit could not be seen")
    assert fork_workers(2, 2) == 2
    out = map_forked(lambda i: _blas_threads(), 2, workers=2)
    assert out == [blas_threads_per_process(2)] * 2
    assert _blas_threads() == here  # this process keeps its own
