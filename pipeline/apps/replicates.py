"""Replicated studies: the same study run n times on independent seed streams, pooled.

A study is one draw: its tour noise, MCL, reader noise, held-out tag layout and robot
filter runs all come from its ``seed``. With ``[replicates] n = N`` (``rfidstudy run
--replicates N``) the run directory holds N studies, ``replicates/<k>/`` (each a run
directory of its own, resumable and cached stage by stage), and the run directory's
``metrics.json`` and ``report.html`` pool them:

- replicate 0 has the study's ``seed`` (so it is the single study of the same config);
  replicate k >= 1 has the seed :func:`replicate_seed` spawns from it
  (:class:`numpy.random.SeedSequence` child k): independent streams, and replicate k's
  seed does not depend on N, so adding replicates keeps the ones already run;
- the replicates share the scene and the propagation cache (every trace one of them
  made that another needs is read, not traced again);
- they run in local worker processes (with one worker, one after the other in this
  process) or on the Dask scheduler the sweeps use
  (:func:`pipeline.apps.studypool.run_studies`);
- the pooled intervals resample (replicate, tag) and (replicate, filter run) units
  (:mod:`pipeline.evaluation.headline`); each replicate's own headline numbers are kept
  beside them (``per_replicate``), so the spread between replicates is visible;
- a replicate that fails is named with its error, the others are kept, and the pooled
  numbers say how many replicates they cover; with none complete the run fails.

The engine is the study's (:func:`pipeline.engine.study.run_study`) with the stages
:data:`STAGES`: ``replicates`` (runs the N studies; always, each skips what it has),
``pooled`` (``metrics.json``) and ``report``; :func:`pipeline.apps.studyrun.run_full_study`
runs them for ``n > 1``, and the stage package (:mod:`pipeline.stages`) does not know
this module.
"""

from __future__ import annotations

import logging

import numpy as np

from pipeline import runfiles
from pipeline.apps.studypool import run_studies
from pipeline.config import StudyConfig, config_to_dict, replace_path
from pipeline.engine.runstore import (
    RunDirLocked,
    atomic_write_json,
    check_no_writer,
    file_sha256,
    inside,
    read_run_json,
    regular_file,
)
from pipeline.engine.study import Stage, StageError
from pipeline.evaluation.headline import headline_estimates, headline_intervals
from pipeline.evaluation.metrics import nan_to_none
from pipeline.evaluation.units import UnitTables, concat_unit_tables
from pipeline.report.html import write_pooled_report
from pipeline.stages import resolve_cache_dir

__all__ = ["STAGES", "replicate_configs", "replicate_seed", "stage_pooled", "stage_replicates"]

log = logging.getLogger(__name__)

#: Where the replicates' index is written.
INDEX = runfiles.REPLICATES_INDEX
#: Each replicate's files the pooled numbers read (their digests enter the index).
POOLED_INPUTS = (runfiles.METRICS, *(runfiles.EVALUATION_TABLE.format(table=t) for t in
                                    ("rssi_links", "detection_attempts", "detection_cells",
                                     "fig7_groups")),
                 runfiles.TAG_ERRORS, runfiles.ROBOT_STEPS)


def replicate_seed(seed: int, k: int) -> int:
    """The seed of replicate ``k``: ``seed`` itself for k = 0, else 63 bits of the k-th
    child of ``SeedSequence(seed)`` (independent of how many replicates there are)."""
    if k == 0:
        return int(seed)
    child = np.random.SeedSequence(int(seed), spawn_key=(int(k),))
    hi, lo = (int(x) for x in child.generate_state(2, np.uint32))
    return ((hi << 32) | lo) & ((1 << 63) - 1)


def replicate_configs(cfg: StudyConfig) -> list[StudyConfig]:
    """The N single-study configs of a replicated study: replicate seeds, ``n = 1``, and
    the propagation cache pinned to one absolute directory for all."""
    base = replace_path(cfg, "replicates.n", 1)
    base = replace_path(base, "tracing.cache_dir", str(resolve_cache_dir(cfg)))
    return [replace_path(base, "seed", replicate_seed(cfg.seed, k))
            for k in range(cfg.replicates.n)]


def stage_replicates(ctx) -> dict:
    """Run (or resume) every replicate into ``replicates/<k>/``; write the index."""
    cfg = ctx.config
    rep = cfg.replicates
    configs = replicate_configs(cfg)
    dirs = [inside(ctx.store.root, f"replicates/{k}") for k in range(rep.n)]
    dirs[0].parent.mkdir(exist_ok=True)
    update = ctx.progress("replicates", total=rep.n)
    args = [(config_to_dict(c), str(d)) for c, d in zip(configs, dirs, strict=True)]
    rows = run_studies(args, scheduler=rep.scheduler or None, workers=rep.workers or None,
                       on_done=lambda i, row: update(advance=1) and False,
                       command="run --replicates")
    _check_no_writer(dirs, rows)
    entries = []
    for k, (c, d, row) in enumerate(zip(configs, dirs, rows, strict=True)):
        ok = row.get("status") == "complete"
        if not ok:
            log.warning("replicate %d (%s) failed: %s", k, d, row.get("error"))
        entries.append({"k": k, "seed": c.seed, "dir": f"replicates/{k}",
                        "status": row.get("status"), "error": row.get("error") or None,
                        # digests: so that the pooled stage re-runs when a replicate's
                        # numbers change (its cache key), not a check of what it reads
                        "digests": ({f: file_sha256(p) if regular_file(p := inside(d, f)) else None
                                     for f in POOLED_INPUTS}
                                    if ok else None)})
    atomic_write_json(ctx.out(INDEX), {"n": rep.n, "replicates": entries})
    n_ok = sum(e["status"] == "complete" for e in entries)
    if n_ok == 0:
        raise StageError(f"no replicate completed: {entries[0]['error']}")
    return {"complete": n_ok, "failed": [e["k"] for e in entries if e["status"] != "complete"]}


def _check_no_writer(dirs: list, rows: list) -> None:
    """Pool nothing while another process writes a replicate: a worker of an earlier,
    killed run still alive holds the replicate's lock (its study here refused to start),
    and pooling the others would say "2 of 3 replicates" with exit 0.

    Raises
    ------
    StageError
        Naming the replicate's folder and the process (its PID, as its lock says)
        (:func:`pipeline.engine.runstore.check_no_writer`).
    """
    try:
        check_no_writer(dirs, "pooling the replicates", rows)
    except RunDirLocked as exc:
        raise StageError(str(exc)) from None


def stage_pooled(ctx) -> dict:
    """Pool the complete replicates: intervals, comparisons and per-replicate numbers."""
    import pandas as pd


    cfg = ctx.config
    index = read_run_json(ctx.input(INDEX))
    done = [e for e in index["replicates"] if e["status"] == "complete"]
    failed = [{"k": e["k"], "seed": e["seed"], "error": e["error"]}
              for e in index["replicates"] if e["status"] != "complete"]
    tables, per_rep = {}, {}

    def read(path):
        if not regular_file(path):
            raise StageError(f"{path}: not a regular file; rerun the replicate")
        return pd.read_parquet(path)

    for e in done:
        root = inside(ctx.store.root, e["dir"])
        tables[e["k"]] = UnitTables.load(root, read_parquet=read)
        per_rep[e["k"]] = headline_estimates(tables[e["k"]],
                                             min_attempts=cfg.training.min_attempts)
    pooled = headline_intervals(concat_unit_tables(tables), seed=cfg.seed,
                                min_attempts=cfg.training.min_attempts, replicated=True)
    per_replicate = {
        key: {m: [per_rep[k].get(key, {}).get(m) for k in sorted(per_rep)] for m in sec["models"]}
        for key, sec in pooled["intervals"].items()}
    metrics = {
        "replicates": {"n": index["n"], "complete": [e["k"] for e in done],
                       "seeds": {str(e["k"]): e["seed"] for e in index["replicates"]},
                       "failed": failed,
                       "covers": f"{len(done)} of {index['n']} replicates"},
        **pooled,
        "per_replicate": {"replicates": sorted(per_rep), "metrics": per_replicate,
                          "how": "each replicate's own estimate of the metric (its units only)"},
    }
    atomic_write_json(ctx.out(runfiles.METRICS), nan_to_none(metrics))
    return {"covers": metrics["replicates"]["covers"]}


def stage_report(ctx) -> dict:
    """``report.html`` of a replicated study (:func:`pipeline.report.html.write_pooled_report`)."""
    metrics = read_run_json(ctx.input(runfiles.METRICS))
    write_pooled_report(metrics, ctx.out(runfiles.REPORT))
    return {}


STAGES: tuple[Stage, ...] = (
    Stage("replicates", stage_replicates, ("seed", "replicates.n", "tracing.cache_dir"), (),
          version=1, always=True, description="replicates"),
    Stage("pooled", stage_pooled, ("seed", "training.min_attempts"), ("replicates",), version=4,
          description="pooled metrics"),
    Stage("report", stage_report, (), ("pooled",), version=1, description="report"),
)
