"""Chunks of a trace as jobs another process can run (a Dask task on a cluster).

:func:`propagation.pathsolve.trace_paths` cuts the antenna positions it has to trace into
chunks (by the memory budget) and traces them one after the other. Inside
:func:`chunk_runner` it hands the chunks to a *runner* instead: a callable
``runner(jobs, finish)`` that gets every chunk as a :class:`ChunkJob` (the scene, the
chunk's positions and tags, the tracer options, the Dr.Jit variant and thread mode of
the calling process), runs :func:`run_chunk_job` on each wherever it likes, and calls
``finish(index, paths)`` in the calling process as each one comes back, in any order.
``finish`` merges, caches and reports the paths exactly as the local loop does, so the
study continues as before, and since a job traces the same chunk with the same settings
the paths are the same (bit for bit with ``tracing.deterministic``: one Dr.Jit thread on
the CPU variant, in the worker too). :mod:`pipeline.tracetasks` is the Dask runner.

The runner is process-local state (a :class:`contextvars.ContextVar`); nothing here
imports Dask.
"""

from __future__ import annotations

import contextlib
import contextvars
import threading
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from typing import Any

import numpy as np

__all__ = ["ChunkJob", "ChunkRunner", "chunk_runner", "current_chunk_runner", "run_chunk_job"]

#: ``runner(jobs, finish)``: run every :class:`ChunkJob` (:func:`run_chunk_job`) and call
#: ``finish(index, paths)`` here for each, raising if any job failed.
ChunkRunner = Callable[[list, Callable[[int, list], None]], None]

_RUNNER: contextvars.ContextVar[ChunkRunner | None] = contextvars.ContextVar("chunk_runner", default=None)
# the last scene's tracer state in this (worker) process: (key, state)
_STATE: dict[str, Any] = {}
#: One job at a time per process: jobs share :data:`_STATE`'s Sionna scene, whose devices
#: each job places (a Dask worker started with several threads would run two at once).
_JOB_LOCK = threading.Lock()


@dataclass(frozen=True)
class ChunkJob:
    """One chunk of :func:`propagation.pathsolve.trace_paths`, self-contained.

    Attributes
    ----------
    scene : scenes.Scene
        The scene (its radio surfaces are traced).
    positions_m : numpy.ndarray
        The chunk's distinct antenna positions (k, 3) [m].
    receivers_m : numpy.ndarray
        The union of the tags they miss (r, 3) [m].
    options : propagation.TraceOptions
        Tracer and ray budget.
    frequency_hz : float
        Carrier frequency [Hz].
    lone_samples, lone_per_chunk, budget_bytes, completion_order : int
        As :func:`propagation.pathsolve.trace_paths` computed them.
    variant : str
        Dr.Jit variant of the calling process (the job selects it).
    deterministic : bool
        Whether the calling process traces on one Dr.Jit thread (the job does the same).
    need : numpy.ndarray or None
        (k, r) bool: the receivers each position misses (None: all).
    """

    scene: Any
    positions_m: np.ndarray
    receivers_m: np.ndarray
    options: Any
    frequency_hz: float
    lone_samples: int
    lone_per_chunk: int
    budget_bytes: int
    completion_order: int
    variant: str
    deterministic: bool
    need: np.ndarray | None = None

    def describe(self) -> str:
        """``"12 antenna positions from (x, y, z) m, 40 tags"``."""
        p = self.positions_m[0]
        return (f"{len(self.positions_m)} antenna positions from ({p[0]:.2f}, {p[1]:.2f}, "
                f"{p[2]:.2f}) m, {len(self.receivers_m)} tags")


def current_chunk_runner() -> ChunkRunner | None:
    """The runner set by :func:`chunk_runner` in this context, or None (trace here)."""
    return _RUNNER.get()


@contextlib.contextmanager
def chunk_runner(runner: ChunkRunner | None) -> Iterator[None]:
    """Within the block, :func:`propagation.trace_links` hands its chunks to ``runner``
    (None: traces them here, the default)."""
    token = _RUNNER.set(runner)
    try:
        yield
    finally:
        _RUNNER.reset(token)


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
    from propagation.backend import (
        CUDA_VARIANT,
        BackendError,
        backend_info,
        select_variant,
        set_deterministic,
    )
    from propagation.pathsolve import trace_one_chunk, tracer_state

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
