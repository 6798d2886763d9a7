"""A study's ray tracing as Dask tasks on a cluster (``tracing.scheduler``, ``run --scheduler``).

Where one study outgrows one machine, the chunks of antenna positions its tracing stages
(``reads``, ``truth_traces``) would trace one after the other go to a Dask cluster
instead, one task per chunk (:mod:`propagation.chunkjobs`): every worker traces its chunk
with the study's tracer options, Dr.Jit variant and thread mode, and sends the paths
back; this process merges them into the shared propagation cache (``tracing.cache_dir``;
the workers need no access to it) as each arrives, and the stage continues exactly as
before. A chunk is the one :func:`propagation.pathsolve.trace_paths` cuts by the memory
budget, so the paths are the ones traced here (bit for bit with ``tracing.deterministic``).

Failures stop the stage with a message, never a hang: a task that raises, or whose worker
died (Dask's ``KilledWorker`` once the scheduler gave up retrying it), names the chunk
and the scheduler; a cluster left without workers for :data:`NO_WORKERS_S` seconds names
the scheduler; an address that cannot be reached within :data:`CONNECT_TIMEOUT_S` names
the key ``tracing.scheduler``.
"""

from __future__ import annotations

import contextlib
import dataclasses
import time
import uuid
from collections import Counter
from collections.abc import Iterator
from dataclasses import dataclass, field

from pipeline.config import ConfigError
from propagation.chunkjobs import chunk_runner
from propagation.chunkworker import run_chunk_job

__all__ = ["CONNECT_TIMEOUT_S", "HANDSHAKE_TIMEOUT_S", "NO_WORKERS_S", "DaskChunkRunner",
           "TraceTaskStats", "check_scheduler", "trace_tasks"]

#: Seconds to reach the scheduler before the stage stops.
CONNECT_TIMEOUT_S = 20.0
#: How long :func:`check_scheduler` waits for a TCP connection and for Dask's handshake [s].
HANDSHAKE_TIMEOUT_S = 10.0


def check_scheduler(address: str, what: str = "--scheduler") -> str:
    """The Dask scheduler address, checked before any work, or a one-line ConfigError.

    Refused, each with its own line: an empty address (leave the option out to run
    locally), a path to a file (an address is ``tcp://host:port``), an address without a
    port, a host that does not accept a TCP connection within
    :data:`HANDSHAKE_TIMEOUT_S`, and a server that accepts one but does not complete
    Dask's handshake (an HTTP server, anything else answering bytes): never a traceback,
    never a silent local run. A ``tls://`` address is checked up to its TCP connection
    (the handshake needs the cluster's certificates, which Dask's own config holds).

    Returns
    -------
    str
        The address with its scheme (``tcp://`` added where none was given).
    """
    import os
    import socket
    from urllib.parse import urlsplit


    text = str(address).strip()
    if not text:
        raise ConfigError(f"{what} '': an empty address; leave the option out to run locally")
    shown = text if len(text) <= 80 else text[:77] + "..."
    if os.path.exists(text):
        raise ConfigError(f"{what} {shown!r}: a path on this machine, not a scheduler address "
                          "(tcp://host:8786)")
    url = text if "://" in text else f"tcp://{text}"
    parts = urlsplit(url)
    try:
        host, port = parts.hostname, parts.port
    except ValueError:
        host, port = None, None
    if parts.scheme not in ("tcp", "tls") or not host or not port:
        raise ConfigError(f"{what} {shown!r}: not a scheduler address; expected tcp://host:port")
    try:
        socket.create_connection((host, port), timeout=HANDSHAKE_TIMEOUT_S).close()
    except OSError as exc:
        raise ConfigError(f"{what} {shown!r}: unreachable ({exc.strerror or type(exc).__name__})"
                          ) from None
    if parts.scheme == "tls":  # Dask's handshake needs the cluster's certificates
        return url
    import asyncio

    async def identity() -> dict:
        from distributed.comm import connect

        comm = await connect(url, timeout=HANDSHAKE_TIMEOUT_S)
        try:
            await comm.write({"op": "identity"})
            return await comm.read()
        finally:
            comm.abort()

    try:  # Dask's own handshake and one request, bounded as a whole
        info = asyncio.run(asyncio.wait_for(identity(), HANDSHAKE_TIMEOUT_S))
    except BaseException as exc:  # noqa: BLE001 - garbage bytes raise anything, MemoryError too
        if isinstance(exc, KeyboardInterrupt):
            raise
        info = {"error": type(exc).__name__}
    if not isinstance(info, dict) or info.get("type") != "Scheduler":
        why = info.get("error") if isinstance(info, dict) and "error" in info else "no scheduler identity"
        raise ConfigError(f"{what} {shown!r}: answers, but is not a Dask scheduler (no "
                          f"handshake within {HANDSHAKE_TIMEOUT_S:g} s: {why})")
    return url
#: Seconds a cluster may have no worker while tasks wait before the stage stops.
NO_WORKERS_S = 60.0
_POLL_S = 1.0


@dataclass
class TraceTaskStats:
    """What the cluster traced for a stage (the stage's info in the manifest).

    Attributes
    ----------
    scheduler : str
        The scheduler's address.
    n_tasks : int
        Chunks traced as tasks.
    by_worker : collections.Counter
        Tasks per worker address.
    """

    scheduler: str
    n_tasks: int = 0
    by_worker: Counter = field(default_factory=Counter)

    def as_dict(self) -> dict:
        """JSON-able: ``scheduler``, ``n_tasks``, ``by_worker`` (address -> tasks)."""
        return {"scheduler": self.scheduler, "n_tasks": self.n_tasks, "by_worker": dict(self.by_worker)}


def _trace_task(job, scene):
    """On a worker: the chunk's fresh paths and the worker's address."""
    from distributed import get_worker


    return run_chunk_job(dataclasses.replace(job, scene=scene)), get_worker().address


class DaskChunkRunner:
    """A :data:`propagation.chunkjobs.ChunkRunner` submitting every chunk to a Dask client.

    Parameters
    ----------
    client : distributed.Client
    stats : TraceTaskStats
        Counts the tasks by worker.
    task : callable, optional
        The function run per chunk, ``task(job, scene) -> (paths, worker address)``
        (default: trace it).
    """

    def __init__(self, client, stats: TraceTaskStats, task=None) -> None:
        self.client, self.stats, self.task = client, stats, task or _trace_task

    def __call__(self, jobs: list, finish) -> None:
        from distributed import wait
        from distributed.client import FuturesCancelledError

        if not jobs:
            return
        tag = uuid.uuid4().hex[:8]
        # the scene travels with each task (not scattered: data held by one worker is lost
        # with it, and Dask then cancels every task that needs it)
        futs = [self.client.submit(self.task, dataclasses.replace(job, scene=None), job.scene, pure=False,
                                   key=f"rfidstudy-trace-{tag}-{i}") for i, job in enumerate(jobs)]
        index = {f.key: i for i, f in enumerate(futs)}
        pending, idle_since = set(futs), None
        try:
            while pending:
                try:
                    with self.client.as_current():  # wait() asks for the current client
                        done, pending = wait(pending, timeout=_POLL_S, return_when="FIRST_COMPLETED")
                except TimeoutError:
                    done = set()
                except FuturesCancelledError:
                    done = {f for f in pending if f.status == "cancelled"}
                    pending = pending - done
                for fut in sorted(done, key=lambda f: index[f.key]):
                    i = index[fut.key]
                    if fut.status != "finished":
                        what = "was cancelled by the scheduler" if fut.status == "cancelled" else (
                            f"failed: {type(fut.exception()).__name__}: {fut.exception()}")
                        raise RuntimeError(
                            f"tracing task {i + 1}/{len(jobs)} ({jobs[i].describe()}) on the Dask "
                            f"cluster {self.stats.scheduler} {what}") from None
                    paths, worker = fut.result()
                    self.stats.n_tasks += 1
                    self.stats.by_worker[worker] += 1
                    finish(i, paths)
                if pending and not done:
                    if self.client.scheduler_info().get("workers"):
                        idle_since = None
                    elif idle_since is None:
                        idle_since = time.monotonic()
                    elif time.monotonic() - idle_since > NO_WORKERS_S:
                        raise RuntimeError(
                            f"the Dask cluster {self.stats.scheduler} has had no worker for "
                            f"{NO_WORKERS_S:.0f} s while {len(pending)} of {len(jobs)} tracing tasks "
                            "wait: start workers (dask worker ADDRESS --nthreads 1) and rerun to resume")
        finally:
            if pending:
                self.client.cancel(list(pending))


@contextlib.contextmanager
def trace_tasks(cfg, client=None) -> Iterator[TraceTaskStats | None]:
    """Within the block, the study's tracing runs as Dask tasks (when it has a scheduler).

    Parameters
    ----------
    cfg : pipeline.config.StudyConfig
        ``tracing.scheduler``: the scheduler's address; '' (and no ``client``): the block
        traces in this process and yields None.
    client : distributed.Client, optional
        An existing client (takes precedence over the address).

    Yields
    ------
    TraceTaskStats or None

    Raises
    ------
    RuntimeError
        The scheduler cannot be reached (naming ``tracing.scheduler``); a task failed or
        the cluster lost its workers (:class:`DaskChunkRunner`).
    """
    address = cfg.tracing.scheduler
    if client is None and not address:
        yield None
        return
    own = client is None
    if own:
        from distributed import Client

        try:
            client = Client(address, timeout=CONNECT_TIMEOUT_S, set_as_default=False)
        except (OSError, TimeoutError, ValueError) as exc:
            raise RuntimeError(f"tracing.scheduler {address!r}: cannot reach the Dask scheduler "
                               f"({type(exc).__name__}: {exc})") from None
    stats = TraceTaskStats(str(client.scheduler.address))
    try:
        with chunk_runner(DaskChunkRunner(client, stats)):
            yield stats
    finally:
        if own:
            client.close()
