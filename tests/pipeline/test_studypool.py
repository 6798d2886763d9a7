"""run_studies on local workers: one runs the studies in this process, in order; two run
them in spawned worker processes that share the CPUs. The study is a stand-in that
records where it ran (the pool's own logic is what is tested; real studies run through
it in tests/pipeline/test_replicates.py, placement/ and test_sweep_cluster.py)."""

from __future__ import annotations

import json
import logging
import os
from pathlib import Path
from types import SimpleNamespace

import pytest

from pipeline.apps.studypool import run_studies
from pipeline.config import StudyConfig, config_to_dict
from pipeline.parallel import WORKERS_ENV, usable_cpus

pytestmark = pytest.mark.parallel


def fake_study(config, run_dir, **kwargs):
    """A study that writes where and how it ran; the one in a folder named ``bad`` fails.
    Module-level: it travels to a spawned worker by name."""
    run = Path(run_dir)
    if run.name == "bad":
        raise ValueError("planted failure")
    run.mkdir(parents=True, exist_ok=True)
    (run / "ran.json").write_text(json.dumps({
        "pid": os.getpid(), "upto": kwargs.get("upto"), "workers": os.environ.get(WORKERS_ENV),
        "log_level": logging.getLogger("pipeline").getEffectiveLevel()}))
    return SimpleNamespace(elapsed_s=0.0, ran=["scene"])


def _args(tmp_path: Path, names) -> list:
    cfg = config_to_dict(StudyConfig())
    return [(cfg, str(tmp_path / n)) for n in names]


def test_one_worker_runs_here_in_order_and_stops_when_asked(tmp_path):
    seen = []

    def on_done(i, row):
        seen.append(i)
        return i == 1  # stop after the failure

    rows = run_studies(_args(tmp_path, ["a", "bad", "c"]), workers=1, runner=fake_study,
                       upto="scene", summarise=False, on_done=on_done)
    assert seen == [0, 1]
    assert rows[0] == {"status": "complete", "error": "", "elapsed_s": 0.0, "stages_ran": 1}
    assert rows[1]["status"] == "failed" and rows[1]["kind"] == "ValueError"
    assert "planted failure" in rows[1]["error"]
    assert rows[2] is None and not (tmp_path / "c").exists()  # never started
    ran = json.loads((tmp_path / "a" / "ran.json").read_text())
    assert ran["pid"] == os.getpid() and ran["upto"] == "scene"


def test_two_workers_run_in_spawned_processes_sharing_the_cpus(tmp_path, monkeypatch):
    monkeypatch.delenv(WORKERS_ENV, raising=False)
    project = logging.getLogger("pipeline")
    level = project.level
    project.setLevel(logging.INFO)  # as the command line sets it
    try:
        rows = run_studies(_args(tmp_path, ["a", "b"]), workers=2, runner=fake_study,
                           upto="scene", summarise=False)
    finally:
        project.setLevel(level)
    assert [r["status"] for r in rows] == ["complete", "complete"]
    ran = [json.loads((tmp_path / n / "ran.json").read_text()) for n in "ab"]
    assert all(r["pid"] != os.getpid() and r["upto"] == "scene" for r in ran)
    # two studies side by side: each worker's own forks capped at its share of the CPUs
    assert all(r["workers"] == str(max(1, usable_cpus() // 2)) for r in ran)
    # and their studies' run.log holds the INFO lines, as a study run here does
    assert [r["log_level"] for r in ran] == [logging.INFO, logging.INFO]
