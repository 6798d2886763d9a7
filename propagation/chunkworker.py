"""A chunk of a trace run in this process: the worker's side of :mod:`propagation.chunkjobs`.

A runner (:data:`propagation.chunkjobs.ChunkRunner`, e.g. :mod:`pipeline.engine.tracetasks`'
Dask runner) calls :func:`run_chunk_job` wherever it runs a :class:`ChunkJob`; it traces
the chunk as the local loop of :func:`propagation.pathsolve.trace_paths` does. Apart from
:mod:`propagation.chunkjobs` so that the tracer can import the job description without
importing its own caller.
"""

from __future__ import annotations

import threading
from typing import Any

from propagation.backend import (
    CUDA_VARIANT,
    BackendError,
    backend_info,
    select_variant,
    set_deterministic,
)
from propagation.chunkjobs import ChunkJob
from propagation.pathsolve import trace_one_chunk, tracer_state

__all__ = ["run_chunk_job"]

# the last scene's tracer state in this (worker) process: (key, state)
_STATE: dict[str, Any] = {}
#: One job at a time per process: jobs share :data:`_STATE`'s Sionna scene, whose devices
#: each job places (a Dask worker started with several threads would run two at once).
_JOB_LOCK = threading.Lock()


def run_chunk_job(job: ChunkJob) -> list:
    """Trace one :class:`ChunkJob` in this process; the fresh path sets, one per position.

    Selects the job's Dr.Jit variant (a process that already runs another one refuses
    the job, naming both) and thread mode, then traces as the local loop of
    :func:`propagation.pathsolve.trace_paths` does. The scene's tracer state (its Sionna
    scene and planes) is kept for the next job of the same scene; jobs of one process
    run one after the other (a worker's threads would share that scene).

    Raises
    ------
    propagation.BackendError
        This process already runs another Dr.Jit variant.
    """
    with _JOB_LOCK:
        return _run_chunk_job(job)


def _run_chunk_job(job: ChunkJob) -> list:
    have = backend_info()["variant"]
    if have is None:
        select_variant("cuda" if job.variant == CUDA_VARIANT else "llvm")
    elif have != job.variant:
        raise BackendError(f"this worker traces with Dr.Jit variant {have!r}, the study with "
                           f"{job.variant!r}: start the workers with the study's backend")
    set_deterministic(job.deterministic)
    shared = job.options.method == "shared"
    area = float(job.options.completion_min_area_m2)
    most = int(job.options.completion_max_planes)
    key = f"{job.scene.content_hash()}|{job.frequency_hz!r}|{shared}|{job.completion_order}|{area!r}|{most}"
    if _STATE.get("key") != key:
        _STATE.clear()
        _STATE["state"] = tracer_state(job.scene, job.frequency_hz, shared, job.completion_order, area, most)
        _STATE["key"] = key
    return trace_one_chunk(_STATE["state"], job.positions_m, job.receivers_m, job.options,
                           job.lone_samples, job.lone_per_chunk, job.budget_bytes, job.completion_order,
                           job.need)
