"""Two real ``rfidstudy run`` processes at once (issue 33): into one run directory, and
into two run directories sharing one fresh propagation cache.

Slow: three tiny studies with deterministic tracing (bit-reproducible traces, so a trace
written by the other process is the trace this one would have made).
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
TINY = str(ROOT / "configs" / "tiny.toml")

pytestmark = pytest.mark.slow


def _start(out: Path, cache: Path) -> subprocess.Popen:
    env = {**os.environ, "RFIDSTUDY_CACHE": str(cache), "COLUMNS": "80"}
    return subprocess.Popen([sys.executable, "-m", "pipeline", "run", TINY, "--no-progress", "--out",
                             str(out), "--set", "tracing.deterministic=true"],
                            cwd=ROOT, env=env, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)


def _finish(proc: subprocess.Popen) -> tuple[int, str]:
    out, _ = proc.communicate(timeout=900)
    return proc.returncode, out


def test_two_runs_sharing_a_fresh_cache_give_the_metrics_of_a_solo_run(tmp_path):
    rc, out = _finish(_start(tmp_path / "solo", tmp_path / "cache_solo"))
    assert rc == 0, out
    a, b = _start(tmp_path / "a", tmp_path / "shared"), _start(tmp_path / "b", tmp_path / "shared")
    for proc in (a, b):
        rc, out = _finish(proc)
        assert rc == 0, out
    solo = json.loads((tmp_path / "solo" / "metrics.json").read_text())
    for d in ("a", "b"):
        assert json.loads((tmp_path / d / "metrics.json").read_text()) == solo, d
    # no half-written file is left in the shared cache: every atomic write was renamed
    assert not [p for p in (tmp_path / "shared").rglob("*") if p.name.endswith(".tmp")]


def test_two_runs_into_one_directory_one_refused_and_the_directory_stays_resumable(tmp_path):
    cache = tmp_path / "cache"
    rc, out = _finish(_start(tmp_path / "warm", cache))  # the traces, so both start at once
    assert rc == 0, out
    run = tmp_path / "run"
    first, second = _start(run, cache), _start(run, cache)
    results = sorted([_finish(first), _finish(second)], key=lambda r: r[0])
    (rc_ok, _), (rc_refused, refused) = results
    assert rc_ok == 0, results
    assert rc_refused == 2 and "in use by process" in refused and "Traceback" not in refused
    assert len(refused.strip().splitlines()) == 1
    assert json.loads((run / "manifest.json").read_text())["status"] == "complete"
    rc, again = _finish(_start(run, cache))  # a plain rerun: nothing wedged, all cached
    assert rc == 0 and "stages run: none" in again, again
