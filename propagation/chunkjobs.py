"""Chunks of a trace as jobs another process can run (a Dask task on a cluster).

:func:`propagation.pathsolve.trace_paths` cuts the antenna positions it has to trace into
chunks (by the memory budget) and traces them one after the other. Inside
:func:`chunk_runner` it hands the chunks to a *runner* instead: a callable
``runner(jobs, finish)`` that gets every chunk as a :class:`ChunkJob` (the scene, the
chunk's positions and tags, the tracer options, the Dr.Jit variant and thread mode of
the calling process), runs :func:`propagation.chunkworker.run_chunk_job` on each
wherever it likes, and calls
``finish(index, paths)`` in the calling process as each one comes back, in any order.
``finish`` merges, caches and reports the paths exactly as the local loop does, so the
study continues as before, and since a job traces the same chunk with the same settings
the paths are the same (bit for bit with ``tracing.deterministic``: one Dr.Jit thread on
the CPU variant, in the worker too). :mod:`pipeline.engine.tracetasks` is the Dask runner.

The runner is process-local state (a :class:`contextvars.ContextVar`); nothing here
imports Dask, nor the tracer (:mod:`propagation.pathsolve` imports this module; the
worker's side, which traces a job, is :mod:`propagation.chunkworker`).
"""

from __future__ import annotations

import contextlib
import contextvars
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from typing import Any

import numpy as np

__all__ = ["ChunkJob", "ChunkRunner", "chunk_runner", "current_chunk_runner"]

#: ``runner(jobs, finish)``: run every :class:`ChunkJob`
#: (:func:`propagation.chunkworker.run_chunk_job`) and call
#: ``finish(index, paths)`` here for each, raising if any job failed.
ChunkRunner = Callable[[list, Callable[[int, list], None]], None]

_RUNNER: contextvars.ContextVar[ChunkRunner | None] = contextvars.ContextVar("chunk_runner", default=None)


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
