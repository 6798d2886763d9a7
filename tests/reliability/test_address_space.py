"""A study under an address-space limit (``ulimit -v``) that its tracer budget cannot fit
stops before any work, in one line naming ``tracing.memory_budget_mb``, the budget and the
limit (issue 54: it segfaulted in the tracer, exit 139, with no message)."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest

from pipeline.config import ConfigError
from pipeline.engine.preflight import STUDY_ADDRESS_SPACE_MIB, check_address_space

ROOT = Path(__file__).resolve().parents[2]
LIMIT_MIB = 2560  # imports fit (0.6 GiB mapped); the default budget of 2,048 MiB does not


def _limit_address_space():
    import resource

    resource.setrlimit(resource.RLIMIT_AS, (LIMIT_MIB * 2**20, LIMIT_MIB * 2**20))


def _cli_under_limit(tmp_path, *args) -> subprocess.CompletedProcess:
    env = {**os.environ, "PYTHONPATH": f"{ROOT}{os.pathsep}{os.environ.get('PYTHONPATH', '')}",
           "RFIDSTUDY_CACHE": str(tmp_path / "cache"), "OPENBLAS_NUM_THREADS": "1",
           "OMP_NUM_THREADS": "1", "COLUMNS": "200"}
    return subprocess.run([sys.executable, "-m", "pipeline", *map(str, args)], cwd=tmp_path, env=env,
                          preexec_fn=_limit_address_space, capture_output=True, text=True, timeout=300)


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="RLIMIT_AS as Linux has it")
def test_a_run_under_a_ulimit_below_its_budget_stops_in_one_line(tmp_path):
    out = tmp_path / "run"
    proc = _cli_under_limit(tmp_path, "run", ROOT / "configs" / "tiny.toml", "--no-progress", "--out", out)
    output = proc.stdout + proc.stderr
    assert proc.returncode == 2, output
    lines = output.strip().splitlines()
    assert len(lines) == 1 and "Traceback" not in output, output
    assert lines[0].startswith("error: tracing.memory_budget_mb = 2,048 MiB"), output
    assert f"address-space limit (ulimit -v) of {LIMIT_MIB:,} MiB" in lines[0], output
    assert not out.exists()  # refused before the run directory is made


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="RLIMIT_AS as Linux has it")
def test_a_sweep_under_a_ulimit_below_its_budget_starts_no_worker(tmp_path):
    out = tmp_path / "sweep"
    proc = _cli_under_limit(tmp_path, "sweep", ROOT / "configs" / "sweep_example.toml", "--out", out)
    assert proc.returncode == 2, proc.stdout + proc.stderr
    assert proc.stderr.strip().splitlines() == [proc.stderr.strip()], proc.stderr
    assert proc.stderr.startswith("error: tracing.memory_budget_mb = 2,048 MiB"), proc.stderr
    assert f"(ulimit -v) of {LIMIT_MIB:,} MiB" in proc.stderr
    assert not list((out / "runs").glob("*/stages"))  # no point started


def test_the_budget_that_fits_is_named():
    gib = 2**30
    check_address_space(2048, limit_bytes=8 * gib)  # 2 + 3 GiB fit under 8
    with pytest.raises(ConfigError, match=r"tracing.memory_budget_mb = 2,048 MiB plus the 3,072 MiB .* "
                                          r"of 4,096 MiB: lower tracing.memory_budget_mb to at most 1,024"):
        check_address_space(2048, limit_bytes=4 * gib)
    with pytest.raises(ConfigError, match=r"of 2,048 MiB: raise the limit to at least 3,328 MiB"):
        check_address_space(256, limit_bytes=2 * gib)
    assert STUDY_ADDRESS_SPACE_MIB == 3072
