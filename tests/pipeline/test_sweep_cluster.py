"""A two-point sweep of real tiny studies on a real Dask LocalCluster (2 worker processes).

The points are the session's tiny study at two transmit powers: the tx power enters the
reads after tracing, so both read every trace from the tiny study's cache; the downstream
benchmark, which nothing here reads, is off, and the points stop after ``evaluation``
(``upto``): the summary reads their metrics, not their figures (drawn by the tiny study's
own figures stage)."""

from __future__ import annotations

import json
from pathlib import Path

import pandas as pd
import pytest

from pipeline.apps.sweep import load_sweep, run_sweep

ROOT = Path(__file__).resolve().parents[2]


def _sweep_file(tmp_path: Path, cache: str, upto: str = "") -> Path:
    p = tmp_path / "sweep.toml"
    p.write_text(
        f'base = "{(ROOT / "configs" / "tiny.toml").as_posix()}"\n'
        + (f'upto = "{upto}"\n' if upto else "")
        + "[parameters]\n"
        "tx_power_dbm = [24.0, 27.15]\n"
        "[study.downstream]\n"
        "enabled = false\n"
        "[study.tracing]\n"
        f'cache_dir = "{Path(cache).as_posix()}"\n'
    )
    return p


def test_sweep_on_local_dask_cluster(tiny_study, tmp_path):
    distributed = pytest.importorskip("distributed")
    plan = load_sweep(_sweep_file(tmp_path, tiny_study.config.tracing.cache_dir, "evaluation"))
    assert len(plan.configs) == 2
    with distributed.LocalCluster(n_workers=2, threads_per_worker=1, processes=True,
                                  dashboard_address=None) as cluster, \
            distributed.Client(cluster) as client:
        res = run_sweep(plan, tmp_path / "out", client=client)
    df = res.summary
    assert list(df["status"]) == ["complete", "complete"], df.get("error")
    assert list(df["tx_power_dbm"]) == [24.0, 27.15]
    # more power reads at least as many tags: the sweep carries the physics through
    assert df["tag_coverage"].iloc[1] >= df["tag_coverage"].iloc[0]
    for col in ("read_rate", "tag_coverage", "surface_coverage", "completeness", "ssm_rmse_db"):
        assert df[col].notna().all(), col
    assert json.loads((tmp_path / "out" / "sweep.json").read_text())["upto"] == "evaluation"
    back = pd.read_parquet(tmp_path / "out" / "summary.parquet")
    assert list(back["run"]) == plan.names
    assert (tmp_path / "out" / "summary.csv").is_file()
    assert (tmp_path / "out" / "sweep_tx_power_dbm.png").read_bytes()[:4] == b"\x89PNG"
    for name in plan.names:
        run = tmp_path / "out" / "runs" / name
        assert (run / "metrics.json").is_file()
        # stopped after evaluation: no figures, no report
        assert not (run / "figures").exists() and not (run / "report.html").exists()


@pytest.mark.slow
def test_sweep_on_local_processes(tiny_study, tmp_path):
    plan = load_sweep(_sweep_file(tmp_path, tiny_study.config.tracing.cache_dir))
    res = run_sweep(plan, tmp_path / "out", workers=2)
    assert list(res.summary["status"]) == ["complete", "complete"]
