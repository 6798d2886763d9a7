"""A run directory that never lies (issue 12), on the real tiny study.

One directory is run with ``evaluation.n_sample_poses = 2``, then with the default (1):
it must then hold exactly what a fresh run of the default config holds, file for file
and byte for byte (stage records and the manifest/report timestamps aside), and its
manifest must list exactly those files. Then ``evaluation.n_field_poses = 0`` leaves
no field behind, and re-fitting the models with the same inputs writes the same bytes
so that every later stage stays cached.

Traces are made on one thread (``tracing.deterministic``) so that the RSSI field, which
the truth_traces stage traces afresh in each run, is bit-identical between the two directories.
"""

from __future__ import annotations

import json
import math
from pathlib import Path

import pytest

from pipeline.apps.studyrun import run_full_study
from pipeline.config import load_config, replace_path

ROOT = Path(__file__).resolve().parents[2]

pytestmark = pytest.mark.slow


def _files(root: Path) -> set[str]:
    """The run directory's files, less the lock's housekeeping (not results)."""
    from pipeline.engine.runstore import HOUSEKEEPING

    return {p.relative_to(root).as_posix() for p in root.rglob("*")
            if p.is_file() and p.name not in HOUSEKEEPING}


def _numbers(obj, prefix=""):
    """Every leaf of a JSON document by its dotted path."""
    if isinstance(obj, dict):
        out = {}
        for k, v in obj.items():
            out.update(_numbers(v, f"{prefix}.{k}" if prefix else k))
        return out
    if isinstance(obj, list):
        out = {}
        for i, v in enumerate(obj):
            out.update(_numbers(v, f"{prefix}[{i}]"))
        return out
    return {prefix: obj}


def _same(a, b) -> bool:
    if isinstance(a, float) and isinstance(b, float) and math.isnan(a) and math.isnan(b):
        return True
    return a == b


def _manifest_files(run: Path) -> set[str]:
    return set(json.loads((run / "manifest.json").read_text())["files"])


@pytest.fixture(scope="module")
def study(tmp_path_factory):
    from propagation.backend import CUDA_VARIANT, ensure_variant

    if ensure_variant() == CUDA_VARIANT:  # one Mitsuba variant per process
        pytest.skip("a deterministic study traces on the CPU: this process chose CUDA")
    base = tmp_path_factory.mktemp("rundir")
    cfg = load_config(ROOT / "configs" / "tiny.toml")
    cfg = replace_path(cfg, "tracing.cache_dir", str(base / "cache"))
    cfg = replace_path(cfg, "tracing.deterministic", True)
    assert cfg.evaluation.n_sample_poses == 1 and cfg.evaluation.n_field_poses == 1
    reused, fresh = base / "reused", base / "fresh"
    run_full_study(replace_path(cfg, "evaluation.n_sample_poses", 2), reused, command_line=["pytest"])
    before = _files(reused)
    res = run_full_study(cfg, reused, command_line=["pytest"])
    run_full_study(cfg, fresh, command_line=["pytest"])
    return cfg, base, before, res


def test_a_smaller_config_leaves_what_a_fresh_run_leaves(study):
    cfg, base, before, res = study
    reused, fresh = base / "reused", base / "fresh"
    assert "truth" in res.ran and "tour" in res.cached
    assert before - _files(reused), "the 2-pose run wrote files the 1-pose run does not"
    assert _files(reused) == _files(fresh)
    for rel in sorted(_files(fresh)):
        if rel in ("manifest.json", "report.html") or rel.startswith("stages/"):
            continue  # timestamps, elapsed times
        assert (reused / rel).read_bytes() == (fresh / rel).read_bytes(), rel
    a = _numbers(json.loads((reused / "metrics.json").read_text()))
    b = _numbers(json.loads((fresh / "metrics.json").read_text()))
    assert a.keys() == b.keys()
    diff = [k for k in a if not _same(a[k], b[k])]
    assert not diff, diff[:10]


def test_the_manifest_lists_exactly_the_run_files(study):
    _, base, _, _ = study
    for run in (base / "reused", base / "fresh"):
        assert _manifest_files(run) == _files(run) - {"manifest.json"}
        man = json.loads((run / "manifest.json").read_text())
        assert man["status"] == "complete" and man["stage"] is None


def test_no_field_after_a_run_with_one(study):
    cfg, base, _, _ = study
    run = base / "reused"
    assert (run / "fields" / "field_00.npz").is_file()
    assert "coverage" in json.loads((run / "metrics.json").read_text())
    res = run_full_study(replace_path(cfg, "evaluation.n_field_poses", 0), run, command_line=["pytest"])
    assert res.changed_keys == ["evaluation.n_field_poses"]
    assert not (run / "fields" / "field_00.npz").exists()
    assert not list(run.rglob("field_*.npz"))
    assert "coverage" not in json.loads((run / "metrics.json").read_text())
    assert _manifest_files(run) == _files(run) - {"manifest.json"}
    run_full_study(cfg, run, command_line=["pytest"])  # back to the module's config


def test_refitting_the_models_writes_the_same_bytes_and_later_stages_skip(study):
    cfg, base, _, _ = study
    run = base / "fresh"
    models = {p: p.read_bytes() for p in (run / "models").glob("*.json")}
    assert models and not any(b"date_utc" in v for v in models.values())
    res = run_full_study(cfg, run, force=["models"], command_line=["pytest"])
    assert res.ran == ["models"]
    assert {p: p.read_bytes() for p in (run / "models").glob("*.json")} == models
    for later in ("truth", "evaluation", "figures", "report"):
        assert later in res.cached
