"""A stage in a process of its own, running beside the stages before it.

Stages that do not depend on each other can run at the same time: ``truth_traces``
(the truth's traces at tag sites, whose antenna poses it computes from the evaluation
path) reads nothing of the study's ``tour`` (MCL, on one core) and ``reads`` (the reader
simulation's tracing, whose kernel compiling and NumPy bookkeeping leave a core idle),
nor they of it. The runner (:func:`pipeline.engine.study.run_study`) starts a stage
marked ``own_process`` in a *spawned* process (a fresh interpreter: the parent's Dr.Jit
threads and locks are never inherited, so either stage may trace) as soon as its
upstream stages are done, while the runner's stages go on in this process, and commits
it where it stands in the order. The child runs at a lower priority
(:data:`SIDE_NICENESS`) and both processes use half the BLAS threads
(:func:`pipeline.parallel.blas_threads_per_process`). The child writes its outputs only
into its own staging directory (and shares the propagation cache, which several processes may fill) and sends
back its summary (or its error); nothing it computes depends on the process it runs in
(each stage draws from its own seeded stream), so its outputs are those of a run one
after the other. On Linux the child ends with its parent (``PR_SET_PDEATHSIG``): a
killed run leaves no process writing into a staging directory the next run reuses.

Side by side only where it can help and is allowed: more than one usable CPU, the
environment variable ``RFIDSTUDY_WORKERS`` not set to 1 (a sweep's worker process caps
it), and not inside a daemonic process (which may not have children, e.g. a Dask
worker).
"""

from __future__ import annotations

import logging
import multiprocessing
import os
import pickle
import sys
import time
import traceback
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from pipeline.engine.runlog import (
    RUN_LOG,
    final_paths_in_logs,
    is_file_handler,
    log_to_file,
    peak_rss_mib,
    reproducible_outputs,
    utc_now,
)
from pipeline.engine.runstore import RunStore
from pipeline.engine.stagedef import (
    StageContext,
    StageError,
    check_outputs,
    record_or_reason,
    stage_inputs_hash,
)
from pipeline.parallel import (
    WORKERS_ENV,
    blas_threads_per_process,
    limit_blas_threads,
    usable_cpus,
)

__all__ = ["Side", "StageProcess", "StageProcessError", "finish_side", "side_by_side_allowed", "start_side"]

log = logging.getLogger(__name__)

_LOGGERS = ("", "pipeline", "scenes", "propagation", "fuzzymodel")


class StageProcessError(RuntimeError):
    """The stage's process failed; ``cause`` is its exception where it could travel back.

    Attributes
    ----------
    kind : str
        Type name of the stage's exception (``"KeyboardInterrupt"`` when it was interrupted,
        ``"ProcessDied"`` when the process ended without a word).
    detail : str
        Its message.
    cause : BaseException or None
        The exception itself, when it could be pickled.
    child_traceback : str
        Its traceback in the stage's process, formatted.
    """

    def __init__(self, kind: str, detail: str, cause: BaseException | None = None,
                 child_traceback: str = ""):
        super().__init__(f"{kind}: {detail}")
        self.kind, self.detail, self.cause = kind, detail, cause
        self.child_traceback = child_traceback


#: Niceness added to a stage's own process. It is waited for where it stands in the
#: order (truth_traces: after the reads), and the runner's stages are the critical path
#: (the tour's MCL, the reads' tracing, whose single-threaded NumPy between the tracer's
#: kernels leaves a core idle): at a lower priority the stage beside takes the CPU they
#: leave and yields the rest: of +0, +5 and +10, +10 gives the shortest cold default
#: study on 2 cores and the least idle CPU (timings: CHANGELOG.md, 2026-11-29).
SIDE_NICENESS = 10


def side_by_side_allowed() -> bool:
    """Whether a stage may run in a spawned process beside another (module doc)."""
    raw = os.environ.get(WORKERS_ENV, "").strip()
    if raw.isdecimal() and int(raw) <= 1:
        return False
    return usable_cpus() > 1 and not multiprocessing.current_process().daemon


def _log_levels() -> dict[str, int]:
    """The loggers' levels, and under ``"console"`` the lowest level a console handler of
    this process shows (the side process's stderr shows what the console shows here; its
    INFO lines go to run.log only, unless -v)."""
    levels = {name: logging.getLogger(name).level for name in _LOGGERS}
    shown = [h.level for h in logging.getLogger().handlers if not is_file_handler(h)]
    levels["console"] = min(shown) if shown else logging.WARNING
    return levels


def _end_with_parent() -> None:
    """Linux: SIGTERM this process when its parent dies (a killed run's child must not
    go on writing into the run directory); elsewhere nothing."""
    if not sys.platform.startswith("linux"):
        return
    import ctypes
    import signal

    parent = os.getppid()
    try:
        libc = ctypes.CDLL(None, use_errno=True)
        libc.prctl(1, int(signal.SIGTERM), 0, 0, 0)  # PR_SET_PDEATHSIG
    except (OSError, AttributeError):
        return
    if os.getppid() != parent:  # the parent died before the call
        os._exit(1)


def _child(conn, func, stage: str, config, root: str, staged: str, levels: dict) -> None:
    """Body of the spawned process: run ``func`` on a context of its own, report back."""
    _end_with_parent()
    if hasattr(os, "nice"):
        os.nice(SIDE_NICENESS)

    levels = dict(levels)
    handler = logging.StreamHandler(sys.stderr)
    handler.setFormatter(logging.Formatter(f"%(levelname)s [{stage}] %(message)s"))
    handler.setLevel(levels.pop("console", logging.WARNING))
    logging.getLogger().addHandler(handler)
    for name, level in levels.items():
        logging.getLogger(name).setLevel(level)
    limit_blas_threads(blas_threads_per_process(2))  # this process and the runner's
    store = RunStore(root)
    ctx = StageContext(config, store, stage, Path(staged), None, {})
    t0 = time.perf_counter()
    try:
        # run.log first: final_paths_in_logs rewrites the paths of every handler present
        with log_to_file(store.path(RUN_LOG)), reproducible_outputs(), \
                final_paths_in_logs(Path(staged), store.root):  # appended beside the runner's
            log.info("stage %s: started in process %d", stage, os.getpid())
            info = func(ctx) or {}
        msg = ("ok", info, time.perf_counter() - t0, peak_rss_mib())
    except BaseException as exc:  # noqa: BLE001 - everything goes back to the runner
        try:
            cause = pickle.loads(pickle.dumps(exc))
        except Exception:  # noqa: BLE001 - an unpicklable exception travels as text
            cause = None
        msg = ("error", type(exc).__name__, str(exc), cause, "".join(traceback.format_exception(exc)))
    try:
        conn.send(msg)
    finally:
        conn.close()


class StageProcess:
    """One stage running in a spawned process (:func:`pipeline.engine.study.run_study` drives it).

    Parameters
    ----------
    func : callable
        The stage's function (module level: it travels pickled by reference).
    stage : str
        The stage's name.
    config : StudyConfig
        The study config.
    root, staged : pathlib.Path
        The run directory and the stage's (empty) staging directory.
    """

    def __init__(self, func, stage: str, config, root: Path, staged: Path):
        # two processes share the CPUs until this one is waited for or stopped: half the
        # BLAS threads here too (parallel.blas_threads_per_process), restored then
        self._blas = limit_blas_threads(blas_threads_per_process(2))
        ctx = multiprocessing.get_context("spawn")
        self.stage = stage
        try:
            self._recv, send = ctx.Pipe(duplex=False)
            self._proc = ctx.Process(target=_child, name=f"rfidstudy-{stage}",
                                     args=(send, func, stage, config, str(root), str(staged),
                                           _log_levels()))
            self._proc.start()
        except BaseException:
            self._restore_blas()
            raise
        send.close()  # the child holds the only sending end: its death ends recv()

    def _restore_blas(self) -> None:
        if self._blas is not None:
            self._blas.restore_original_limits()
            self._blas = None

    def result(self) -> tuple[dict, float, float]:
        """Wait for the stage.

        Returns
        -------
        info : dict
            What the stage's function returned.
        elapsed_s : float
            Its wall time in the child [s].
        peak_rss_mib : float
            The child's peak resident memory [MiB].

        Raises
        ------
        StageProcessError
            The stage raised (its exception as ``cause`` where it pickles), was
            interrupted, or its process died without reporting (killed, out of memory).
        """
        try:
            msg = self._recv.recv()
        except EOFError:
            msg = None
        finally:
            self._recv.close()
        try:
            self._proc.join()
        finally:
            self._restore_blas()
        if msg is None:
            raise StageProcessError("ProcessDied", f"the process of stage {self.stage!r} ended "
                                    f"without a result (exit code {self._proc.exitcode})")
        if msg[0] == "error":
            raise StageProcessError(msg[1], msg[2], msg[3], msg[4])
        return msg[1], float(msg[2]), float(msg[3])

    def stop(self) -> None:
        """End the process now (its staging directory is the caller's to discard)."""
        try:
            if self._proc.is_alive():
                self._proc.terminate()
                self._proc.join(10)
                if self._proc.is_alive():
                    self._proc.kill()
                    self._proc.join()
            self._recv.close()
        finally:
            self._restore_blas()


@dataclass
class Side:
    """A stage running in its own process: what :func:`finish_side` commits."""

    stage: Any
    inputs_hash: str
    staged: Path
    proc: Any
    task: Any = None


def start_side(st, config, store, digests, force, prog) -> Side | None:
    """Start ``st`` in its own process if it may run beside the stage now starting: it
    is marked ``own_process``, needs none of that stage's outputs (every upstream of it
    is done) and must run."""
    if st is None or not st.own_process or st.always or any(u not in digests for u in st.upstream):
        return None
    if not side_by_side_allowed():
        return None
    try:  # it travels to the new interpreter by reference
        pickle.dumps((st.func, config))
    except Exception as exc:  # noqa: BLE001 - any reason means: run it in order, here
        log.debug("stage %s runs in this process: %s", st.name, exc)
        return None
    inputs_hash = stage_inputs_hash(st, config, digests)
    rec, reason = record_or_reason(st, store, force, inputs_hash)
    if rec is not None:
        return None
    staged = store.staging(st.name)
    try:
        proc = StageProcess(st.func, st.name, config, store.root, staged)
    except Exception as exc:  # noqa: BLE001 - no process (resources, platform): in order, here
        store.discard(st.name)
        log.warning("stage %s could not start a process of its own (%s: %s); it runs after "
                    "the stage before it", st.name, type(exc).__name__, exc)
        return None
    log.info("stage %s: running in its own process (%s)", st.name, reason)
    task = None if prog is None else prog.add_task(f"{st.name}: {st.description} (own process)",
                                                   total=1)
    return Side(st, inputs_hash, staged, proc, task)


def finish_side(side: Side, store, result, prog, failed):
    """Wait for the stage's process and commit its outputs (its ``StageRecord``); a failure
    there is the stage's failure, given to ``failed(failure)`` for the manifest first."""
    st = side.stage
    try:
        info, elapsed_s, peak = side.proc.result()
    except StageProcessError as exc:
        store.discard(st.name)
        if exc.kind == "KeyboardInterrupt":
            raise KeyboardInterrupt from None
        log.debug("stage %s, in its own process:\n%s", st.name, exc.child_traceback)
        failed({"stage": st.name, "error": f"{exc.kind}: {exc.detail}"})
        raise StageError(f"stage {st.name!r} failed: {exc.kind}: {exc.detail} "
                         f"(earlier stages' outputs in {store.root} are intact; "
                         "fix the cause and rerun to resume)",
                         stage=st.name, kind=exc.kind) from (exc.cause or exc)
    if prog is not None and side.task is not None:
        prog.update(side.task, completed=1)
    try:
        check_outputs(st, side.staged)
    except ValueError as exc:
        store.discard(st.name)
        failed({"stage": st.name, "error": f"ValueError: {exc}"})
        raise StageError(f"stage {st.name!r} failed: {exc} (earlier stages' outputs in "
                         f"{store.root} are intact)", stage=st.name, kind="ValueError") from exc
    rec = store.commit(st.name, side.inputs_hash, side.staged, elapsed_s, peak, utc_now(), info)
    result.ran.append(st.name)
    return rec
