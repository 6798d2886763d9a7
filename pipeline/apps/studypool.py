"""Studies side by side: local worker processes or a Dask cluster, one summary row each.

:func:`run_studies` runs :func:`run_point` on each ``(config dict, run directory)``: in
local spawned worker processes (``concurrent.futures``; the CPUs shared between them,
:func:`_cap_nested_workers`), in this process one after the other with one local worker,
or, with a ``client`` or ``scheduler`` address, on a Dask distributed cluster. Its callers sit above it: a sweep's points (:mod:`pipeline.apps.sweep`),
a replicated study's replicates (:mod:`pipeline.apps.replicates`) and a placement's candidate
studies (:mod:`pipeline.apps.placement.runner`). Each study is one study
(:func:`pipeline.stages.run_study_stages`) unless the caller passes the ``runner`` that
runs it: a sweep's point may be a replicated study
(:func:`pipeline.apps.studyrun.run_full_study`), and this module imports neither.
"""

from __future__ import annotations

import concurrent.futures as cf
import logging
import multiprocessing
import os
from collections.abc import Callable
from pathlib import Path
from typing import TYPE_CHECKING

from pipeline.config import StudyConfig
from pipeline.configschema import from_dict
from pipeline.engine.preflight import check_address_space
from pipeline.engine.runlog import PROJECT_LOGGERS
from pipeline.parallel import WORKERS_ENV, die_with_parent, usable_cpus
from pipeline.stages import run_study_stages
from pipeline.stages.summary import run_summary

if TYPE_CHECKING:
    from pipeline.engine.study import StudyResult

__all__ = ["run_point", "run_studies"]

log = logging.getLogger(__name__)


def run_point(config: dict, run_dir: str, command: str = "sweep", upto: str | None = None,
              runner: Callable[..., StudyResult] | None = None,
              summarise: bool = True) -> dict:
    """Run one study (a sweep point, a replicate, a placement candidate's replicate; in a
    worker process, or in this one) and return its row.

    Parameters
    ----------
    config : dict
        The point's study config as a nested dict (:func:`config_to_dict`).
    run_dir : str
        Its run directory.
    command : str
        The command named in the point's manifest.
    upto : str, optional
        The last stage to run (:func:`pipeline.stages.stages_upto`; None: all of them).
    runner : callable, optional
        ``runner(config, run_dir, **kwargs)`` runs the study: a module-level function (it
        travels to the worker by name). None: :func:`pipeline.stages.run_study_stages`,
        one study; a sweep passes :func:`pipeline.apps.studyrun.run_full_study`, which runs a
        replicated point's replicates.
    summarise : bool
        Add the summary numbers of :func:`pipeline.stages.summary.run_summary` (a sweep's
        table; read from ``metrics.json``, so only for a study that ran the stage writing
        it: the caller checks ``upto``, :func:`pipeline.apps.sweep.load_sweep`).

    Returns
    -------
    dict
        ``status`` ("complete" or "failed"), ``error``, ``elapsed_s``, ``stages_ran`` and
        the summary numbers; a failed point's ``stage`` and ``kind`` (the exception's
        type; stage "summary" where only its summary failed).
    """
    # the stage package: loaded in the worker, not by every importer of the pool

    cfg = from_dict(StudyConfig, config, source=f"sweep point {run_dir}")
    try:
        res = (runner or run_study_stages)(cfg, run_dir, progress=False, upto=upto,
                                           command_line=["rfidstudy", command, "(point)"])
    except Exception as exc:  # one failed point must not sink the sweep
        log.error("sweep point %s failed: %s", run_dir, exc)
        return {"status": "failed", "error": str(exc), "elapsed_s": float("nan"),
                "stage": getattr(exc, "stage", None),
                "kind": getattr(exc, "kind", None) or type(exc).__name__}
    row = {"status": "complete", "error": "", "elapsed_s": res.elapsed_s,
           "stages_ran": len(res.ran)}
    if not summarise:
        return row
    try:
        row.update(run_summary(run_dir))
    except Exception as exc:  # a summary that cannot be read fails its point, not the sweep
        log.error("sweep point %s: its summary failed: %s", run_dir, exc)
        row.update(status="failed", error=f"summary: {exc}", stage="summary",
                   kind=type(exc).__name__)
    return row


def run_studies(args: list, *, scheduler: str | None = None, workers: int | None = None,
                client=None, on_done: Callable[[int, dict], bool | None] | None = None,
                command: str = "sweep", upto: str | None = None,
                runner: Callable[..., StudyResult] | None = None,
                summarise: bool = True) -> list[dict | None]:
    """Run studies side by side: :func:`run_point` (with ``runner``) on each ``(config
    dict, run dir)`` of ``args``, in local spawned worker processes (``workers``, default
    min(len, 2); the CPUs shared between them) or on a Dask cluster (``client`` or
    ``scheduler``). One local worker (``workers=1``, or one study to run) runs the
    studies one after the other in this process: a spawned interpreter would only add
    its imports (about 5 s of CPU each time, measured in the closing note of issue 55)
    and the studies would still run one at a time. The price is the worker's isolation:
    a study that crashes the interpreter (a segfault, an out-of-memory kill) takes the
    caller with it, as a single ``rfidstudy run`` would, and the peak memory its records
    give is this process's peak so far, not the study's own. ``summarise``: see
    :func:`run_point`.

    Returns :func:`run_point`'s rows in the order of ``args``. ``on_done(i, row)`` is
    called after each; when it returns True the local studies not yet started are
    cancelled (their rows stay None) and those under way finish. On a Dask cluster every
    submitted study runs to its end (a stop is not passed on). Local workers inherit the
    address-space limit: a tracer budget it cannot hold is a ConfigError before any
    starts (:func:`pipeline.engine.preflight.check_address_space`)."""
    if client is not None or scheduler:
        return _run_dask(args, scheduler, client, on_done, command, upto, runner, summarise)

    # the workers inherit ulimit -v: a budget over it would segfault each one, silently
    budgets = [a[0].get("tracing", {}).get("memory_budget_mb", 0.0) for a in args]
    check_address_space(max(budgets, default=0.0))
    rows: list = [None] * len(args)
    n_workers = workers or min(len(args), 2)
    if n_workers <= 1:
        for i, a in enumerate(args):
            rows[i] = run_point(*a, command, upto, runner, summarise)
            if on_done and on_done(i, rows[i]):
                break  # the rest never run: their rows stay None
        return rows
    ctx = multiprocessing.get_context("spawn")
    # studies side by side share the CPUs (never more side by side than studies)
    nested = max(1, usable_cpus() // max(1, min(n_workers, len(args))))
    with cf.ProcessPoolExecutor(max_workers=n_workers, mp_context=ctx,
                                initializer=_cap_nested_workers,
                                initargs=(nested, _project_log_levels())) as ex:
        futs = {ex.submit(run_point, *a, command, upto, runner, summarise): i
                for i, a in enumerate(args)}
        for fut in cf.as_completed(futs):
            if fut.cancelled():
                continue
            i = futs[fut]
            rows[i] = fut.result()
            if on_done and on_done(i, rows[i]):
                for f in futs:
                    f.cancel()  # not started: never run; under way: finishes
    return rows


def _project_log_levels() -> dict[str, int]:
    """The levels set on the project's loggers here (the command line sets INFO, DEBUG
    with ``-v``), for a spawned worker to set alike."""
    return {name: logging.getLogger(name).level for name in PROJECT_LOGGERS
            if logging.getLogger(name).level != logging.NOTSET}


def _cap_nested_workers(cap: int, log_levels: dict[str, int] | None = None) -> None:
    """In a sweep's worker process: a study's own forked tasks use at most ``cap`` CPUs,
    the project's loggers pass what the caller's pass (``log_levels``; a spawned
    interpreter starts at WARNING, so its studies' ``run.log`` would miss their INFO
    lines, which a study run in the caller's process has), and the worker ends with the
    sweep, placement or replicated run that started it
    (:func:`pipeline.parallel.die_with_parent`)."""
    for name, level in (log_levels or {}).items():
        logging.getLogger(name).setLevel(level)
    die_with_parent()
    current = os.environ.get(WORKERS_ENV, "").strip()
    # a user's smaller cap stands; anything else (unset, larger, not a count) is replaced
    if not (current.isdecimal() and 1 <= int(current) <= cap):
        os.environ[WORKERS_ENV] = str(cap)


def _run_dask(args, scheduler, client, on_done, command="sweep", upto=None, runner=None,
              summarise=True):
    from distributed import Client, as_completed

    own = client is None
    if own:
        client = Client(scheduler)
    try:
        futs = [client.submit(run_point, *a, command, upto, runner, summarise, pure=False,
                              key=f"rfidstudy-point-{i}-{Path(a[1]).name}")
                for i, a in enumerate(args)]
        index = {f.key: i for i, f in enumerate(futs)}
        rows: list = [None] * len(args)
        # a stop asked by on_done is not passed on: Dask cannot interrupt a study under
        # way on a worker, and one cancelled there would still hold its run directory's
        # lock when the caller submits it again; every submitted study runs to its end
        for fut in as_completed(futs):
            i = index[fut.key]
            rows[i] = fut.result()
            if on_done:
                on_done(i, rows[i])
        return rows
    finally:
        if own:
            client.close()
