"""pipeline.parallel: tasks in forked processes, results in task order, errors raised."""

from __future__ import annotations

import os
import threading

import pytest

from pipeline.parallel import fork_workers, map_forked


def test_results_in_task_order_from_forked_children():
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
    def task(i):
        if i == 2:
            raise RuntimeError(f"task {i} failed")
        return i

    with pytest.raises(RuntimeError, match="task 2 failed"):
        map_forked(task, 4, workers=2)


def test_no_fork_while_another_non_daemon_thread_runs():
    stop = threading.Event()
    th = threading.Thread(target=stop.wait)
    th.start()
    try:
        assert fork_workers(None, 8) == 1
    finally:
        stop.set()
        th.join()
    daemon = threading.Thread(target=stop.wait, daemon=True)  # a progress bar's refresh
    stop.clear()
    daemon.start()
    try:
        assert fork_workers(None, 8) == min(8, len(os.sched_getaffinity(0)))
    finally:
        stop.set()
    with pytest.raises(ValueError, match="workers"):
        fork_workers(0, 3)
    assert fork_workers(5, 2) == 2
