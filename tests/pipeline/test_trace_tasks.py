"""A study's ray tracing as Dask tasks (``tracing.scheduler``) on a real LocalCluster: the
same gains bit for bit as tracing in this process (deterministic mode), the chunks really
traced by the workers, and a dead worker stopping the trace with a message."""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np
import pytest

distributed = pytest.importorskip("distributed")

import propagation  # noqa: E402
import scenes  # noqa: E402
from pipeline.apps.cli import resolve_target  # noqa: E402
from pipeline.engine.tracetasks import DaskChunkRunner, TraceTaskStats, trace_tasks  # noqa: E402
from pipeline.studyscene import select_backend, trace_options  # noqa: E402
from propagation.chunkjobs import chunk_runner  # noqa: E402

ROOT = Path(__file__).resolve().parents[2]
# 8 positions 0.4 m apart (they share chains) and 4 alone; a 3.5 MiB budget cuts them into
# chunks of 4 sharing positions (2 x 450 kB each at 500 rays, depth 2), so three tasks
POSES = np.array([[3.0 + 0.4 * k, 1.2, 1.0, 0.3 * k] for k in range(8)]
                 + [[x, 1.0, 1.1, -1.0] for x in (12.0, 15.0, 18.0, 21.0)])


@pytest.fixture(scope="module")
def cfg():
    return resolve_target(str(ROOT / "configs" / "tiny.toml"),
                          ["tracing.deterministic=true", "tracing.memory_budget_mb=3.5"])


@pytest.fixture
def deterministic(cfg):
    select_backend(cfg)  # llvm, one Dr.Jit thread here; the workers follow the job
    yield
    propagation.set_deterministic(False)


def _trace(cfg, cache_dir):
    sc = scenes.load("corridor_lab")
    return propagation.trace_links(sc, POSES, sc.tags.positions_m[:16], trace_options(cfg),
                                   tag_normals=sc.tags.normals[:16], cache_dir=cache_dir)


def test_tracing_on_a_local_dask_cluster_gives_the_same_gains(cfg, deterministic, tmp_path):
    here = _trace(cfg, tmp_path / "here")
    assert here.n_solver_calls == 3
    with distributed.LocalCluster(n_workers=2, threads_per_worker=1, processes=True,
                                  dashboard_address=None) as cluster, \
            distributed.Client(cluster, set_as_default=False) as client:  # as the stage's own
        with trace_tasks(cfg, client=client) as stats:
            there = _trace(cfg, tmp_path / "there")
            again = _trace(cfg, tmp_path / "there")  # from the cache the tasks filled
        workers = set(client.scheduler_info()["workers"])
    assert np.array_equal(there.gain, here.gain) and np.array_equal(there.h, here.h)
    assert np.array_equal(there.n_paths, here.n_paths) and there.n_traced_sources == 12
    assert np.all(np.isfinite(here.gain_db)) and here.gain.max() > 0
    # every chunk ran as a task on a worker of the cluster, none here
    assert stats.n_tasks == 3 and sum(stats.by_worker.values()) == 3
    assert set(stats.by_worker) <= workers
    # the paths came back into this process's cache: a second call traces nothing
    assert again.n_traced_sources == 0 and stats.n_tasks == 3
    assert len(list((tmp_path / "there").rglob("pack-*.npz"))) == 3


def _die(job, scene):
    os._exit(3)  # the worker process dies mid-task


def test_a_dead_worker_fails_with_a_message_not_a_hang(cfg, deterministic, tmp_path):
    import dask

    with dask.config.set({"distributed.scheduler.allowed-failures": 0}), \
            distributed.LocalCluster(n_workers=1, threads_per_worker=1, processes=True,
                                     dashboard_address=None) as cluster, \
            distributed.Client(cluster, set_as_default=False) as client:
        stats = TraceTaskStats(cluster.scheduler_address)
        with chunk_runner(DaskChunkRunner(client, stats, task=_die)), \
                pytest.raises(RuntimeError, match=r"tracing task \d/3 \(4 antenna positions from .*\) on "
                                                  r"the Dask cluster tcp://\S+ failed: KilledWorker") as err:
            _trace(cfg, tmp_path / "cache")
    assert "\n" not in str(err.value)


def test_an_unreachable_scheduler_names_the_key(cfg, monkeypatch):
    import pipeline.engine.tracetasks as tt

    monkeypatch.setattr(tt, "CONNECT_TIMEOUT_S", 1.0)
    bad = resolve_target(str(ROOT / "configs" / "tiny.toml"), ['tracing.scheduler="tcp://127.0.0.1:9"'])
    with pytest.raises(RuntimeError, match=r"tracing.scheduler 'tcp://127.0.0.1:9': cannot reach"), \
            trace_tasks(bad):
        pass
