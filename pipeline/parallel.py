"""Independent tasks side by side in forked processes (figures, tour MCL, tag posteriors and
robot-filter runs).

A forked child inherits this process's memory, so a task needs no pickling of its inputs
(models, read logs, occupancy maps): :func:`map_forked` keeps the task function in a
module global for the children and sends them only task indices; only the results
travel back (pickled). Fork is used only where it is safe here: not when another Python
non-daemon thread runs (a Dask worker's threads: a lock held at the fork would stay
held in the child), not from a thread other than the main one, not from a daemonic
process (which may not have children), and not on a platform without fork; there the
tasks run one after the other in this process, whatever number of workers was asked
for. A daemon helper thread (the progress bars' refresh) does not prevent forking: a
child restores the interpreter's own ``sys.stdout`` / ``sys.stderr`` (a progress display
replaces them by proxies that write through its console and its lock) and logs through
a plain handler on the real stderr, so no lock such a thread may hold at the fork is
ever needed in the child. Results never depend on the number of workers: each task
brings its own random stream.

The environment variable ``RFIDSTUDY_WORKERS`` caps the processes of one call (a sweep
sets it in its own worker processes, so that points side by side do not each fork one
process per CPU).
"""

from __future__ import annotations

import ctypes
import gc
import logging
import multiprocessing
import os
import pickle
import sys
import threading
import traceback
from collections.abc import Callable
from typing import Any

__all__ = ["WORKERS_ENV", "blas_threads_per_process", "die_with_parent", "fork_workers",
           "limit_blas_threads", "map_forked", "one_blas_thread", "usable_cpus"]

#: Environment variable capping the processes of one :func:`map_forked` call.
WORKERS_ENV = "RFIDSTUDY_WORKERS"

# the task function of the running map_forked call, read by the forked children
_TASK: Callable[[int], Any] | None = None


def usable_cpus() -> int:
    """CPUs this process may run on (its affinity mask where the platform has one)."""
    if hasattr(os, "sched_getaffinity"):
        return max(1, len(os.sched_getaffinity(0)))
    return max(1, os.cpu_count() or 1)


def blas_threads_per_process(n_processes: int) -> int:
    """BLAS threads for each of ``n_processes`` processes sharing this machine's CPUs.

    OpenBLAS (NumPy's) starts one thread per CPU in every process, and its threads spin
    while they wait: two processes with a full pool each on 2 CPUs halved the speed of
    the downstream stage's tag work (8.1 s alone, 15.9 s beside the robot-filter runs; the
    stage 33.9 -> 26.8 s with one thread each). So each gets ``usable_cpus() //
    n_processes`` (at least 1).
    """
    return max(1, usable_cpus() // max(1, int(n_processes)))


def limit_blas_threads(n_threads: int):
    """Cap this process's BLAS thread pools (OpenBLAS, MKL, ...) at ``n_threads``.

    Returns
    -------
    threadpoolctl.threadpool_limits
        Call its ``restore_original_limits()`` to undo (or use it as a context manager).
    """
    from threadpoolctl import threadpool_limits

    return threadpool_limits(limits=max(1, int(n_threads)), user_api="blas")


_BLAS = None  # the BLAS libraries loaded at the first one_blas_thread() call


def one_blas_thread():
    """A context manager holding this process's BLAS pools at one thread, for many small
    solves (a maximum-likelihood fit of ten parameters: L-BFGS-B's vector operations took
    22 ms a call with OpenBLAS's threads waking for them on a busy 2-CPU machine, 0.5 ms
    with one). Unlike :func:`limit_blas_threads` (60 ms a call: it looks for the libraries
    every time) the libraries are found once, at the first call (NumPy's and SciPy's are
    loaded by then), and each later call costs microseconds."""
    global _BLAS
    if _BLAS is None:
        from threadpoolctl import ThreadpoolController

        _BLAS = ThreadpoolController()
    return _BLAS.limit(limits=1, user_api="blas")


def _worker_cap() -> int | None:
    raw = os.environ.get(WORKERS_ENV, "").strip()
    if not raw:
        return None
    try:
        cap = int(raw)
    except ValueError:
        raise ValueError(f"environment variable {WORKERS_ENV} must be an integer >= 1, "
                         f"got {raw!r}") from None
    if cap < 1:
        raise ValueError(f"environment variable {WORKERS_ENV} must be an integer >= 1, got {raw!r}")
    return cap


def fork_workers(workers: int | None, n_tasks: int) -> int:
    """Processes to use for `n_tasks` independent tasks.

    Parameters
    ----------
    workers : int or None
        Asked for; None: one per usable CPU. Either way 1 where forking is not safe
        (module doc), and at most ``RFIDSTUDY_WORKERS`` where that is set.
    n_tasks : int

    Returns
    -------
    int
        In ``[1, max(1, n_tasks)]``.
    """
    n_tasks = max(1, int(n_tasks))
    if workers is not None and int(workers) < 1:
        raise ValueError(f"workers must be >= 1 (or None for one per CPU), got {workers!r}")
    n = usable_cpus() if workers is None else int(workers)
    cap = _worker_cap()
    if cap is not None:
        n = min(n, cap)
    if n <= 1 or not _fork_is_safe():
        return 1
    return min(n, n_tasks)


def _fork_is_safe() -> bool:
    me = threading.current_thread()
    if me is not threading.main_thread():
        return False
    if any(t is not me and not t.daemon for t in threading.enumerate()):
        return False
    return (not multiprocessing.current_process().daemon
            and "fork" in multiprocessing.get_all_start_methods())


def die_with_parent() -> None:
    """End this worker process when its parent dies, by any signal (``kill -9`` too).

    Linux's ``prctl(PR_SET_PDEATHSIG, SIGTERM)``: the kernel sends SIGTERM when the
    parent goes, so a killed study, sweep or placement leaves no worker finishing its
    work and idling at a gigabyte; a parent already gone ends the worker now.
    Elsewhere a no-op (no such call; the pool's broken pipe ends the worker at its next
    task instead)."""
    import ctypes
    import signal

    parent = os.getppid()
    if not sys.platform.startswith("linux"):
        return
    try:
        libc = ctypes.CDLL(None, use_errno=True)
        libc.prctl(1, int(signal.SIGTERM), 0, 0, 0)  # 1 = PR_SET_PDEATHSIG
    except (OSError, AttributeError):
        return
    if os.getppid() != parent:  # the parent died before the call took effect
        os._exit(1)


def _child_init(blas_threads: int) -> None:
    die_with_parent()  # a forked task never outlives the study that forked it
    limit_blas_threads(blas_threads)  # the processes of a pool share the CPUs
    # a progress display may have replaced the streams by proxies writing through its
    # console, whose lock another (unforked) thread may have held at the fork
    if sys.__stdout__ is not None:
        sys.stdout = sys.__stdout__
    if sys.__stderr__ is not None:
        sys.stderr = sys.__stderr__
    # the handlers that print to the terminal are replaced by one on the restored stderr,
    # at the lowest of their levels (WARNING where there were none, as Python's last
    # resort): the parent's console shows no INFO without -v, nor may the children's
    # (other handlers stay: a task's lines still reach run.log, on the project's loggers,
    # and a user's log file)
    root = logging.getLogger()
    consoles = [h for h in root.handlers if _prints_to_terminal(h)]
    levels = [h.level for h in consoles]
    for h in consoles:
        root.removeHandler(h)
    console = logging.StreamHandler(sys.stderr)
    console.setLevel(min(levels) if levels else logging.WARNING)
    console.setFormatter(logging.Formatter("%(levelname)s %(name)s: %(message)s"))
    root.addHandler(console)


def _prints_to_terminal(handler: logging.Handler) -> bool:
    """Whether a logging handler writes to this process's stdout or stderr (a
    ``StreamHandler`` on them, or a Rich handler whose console does)."""
    stream = getattr(handler, "stream", None)
    if stream is None and hasattr(handler, "console"):  # rich.logging.RichHandler
        stream = getattr(handler.console, "file", None)
    if stream is None:
        return False
    return any(stream is s for s in (sys.stdout, sys.stderr, sys.__stdout__, sys.__stderr__))


class _TaskError(Exception):
    """A task's exception that cannot travel back pickled, as its formatted traceback."""


def _call(i: int):
    try:
        return _TASK(i)
    except Exception as exc:
        try:
            pickle.loads(pickle.dumps(exc))
        except Exception:
            text = f"task {i} raised (unpicklable exception):\n" + "".join(traceback.format_exception(exc))
        else:
            raise
    # raised outside the handler, so it carries no __context__: where tblib's pickling
    # support is installed (Dask's distributed installs it), an exception is pickled with
    # its chain, and the unpicklable one in it killed the worker
    raise _TaskError(text)


def _before_fork() -> None:
    """Collect garbage, freeze the survivors and give freed heap back to the OS before
    forking: the children share the parent's pages copy-on-write, and the collector's
    walks over inherited objects, or a heap full of freed blocks, make them copies. On the
    warehouse-scale study the downstream stage's forked tasks followed a tracing stage that
    left the parent at 3.9 GB resident; glibc's ``malloc_trim`` returns what is free there
    (other C libraries: skipped). :func:`map_forked` unfreezes when its pool is done."""
    gc.collect()
    gc.freeze()
    try:
        ctypes.CDLL(None).malloc_trim(0)
    except (OSError, AttributeError):  # not glibc
        pass


def map_forked(task: Callable[[int], Any], n_tasks: int, workers: int | None = None) -> list:
    """``[task(0), ..., task(n_tasks - 1)]``, computed in forked processes.

    Parameters
    ----------
    task : callable int -> result
        Any callable (a closure is fine: the children inherit it); its result must pickle.
    n_tasks : int
    workers : int or None
        See :func:`fork_workers`; 1 runs every task here, in order.

    Returns
    -------
    list
        The results in task order. The first task error is raised here after the pool
        has stopped (the remaining tasks are cancelled); an exception that cannot be
        pickled comes back as a RuntimeError carrying its traceback.
    """
    global _TASK
    n = fork_workers(workers, n_tasks)
    if n <= 1 or n_tasks <= 1:
        return [task(i) for i in range(int(n_tasks))]
    from concurrent.futures import ProcessPoolExecutor

    if _TASK is not None:  # a task that maps again: run its inner tasks in place
        return [task(i) for i in range(int(n_tasks))]
    _TASK = task
    _before_fork()
    try:
        with ProcessPoolExecutor(max_workers=n,
                                 mp_context=multiprocessing.get_context("fork"),
                                 initializer=_child_init,
                                 initargs=(blas_threads_per_process(n),)) as pool:
            futures = [pool.submit(_call, i) for i in range(int(n_tasks))]
            try:
                return [f.result() for f in futures]
            except _TaskError as exc:
                pool.shutdown(wait=True, cancel_futures=True)
                raise RuntimeError(str(exc)) from None
            except BaseException:
                pool.shutdown(wait=True, cancel_futures=True)
                raise
    finally:
        _TASK = None
        gc.unfreeze()
