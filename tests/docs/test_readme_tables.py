"""The numbers docs/results.md quotes from one run are written by scripts/readme_tables.py
from that run's directory, naming the run and its commit (issue 37, item 10)."""

from __future__ import annotations

import json
import runpy
import shutil
import subprocess
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]


def _run_dir(tmp_path: Path, commit: str | None = "0123456789abcdef") -> Path:
    """A run directory with the files the single-run block reads, numbers chosen so that
    the budget decomposes exactly: 5^2 = 3^2 + 4^2 + 0."""
    run = tmp_path / "default-at-x"
    (run / "downstream").mkdir(parents=True)
    by_size = {"x0.5": {"d_bin_m": 0.125, "alpha_bin_deg": 5.0, "n_links": 9, "rmse_db": 1.5,
                        "anfis_rmse_db": 2.5},
               "x4": {"d_bin_m": 1.0, "alpha_bin_deg": 40.0, "n_links": 300, "rmse_db": 7.5,
                      "anfis_rmse_db": 7.25}}
    metrics = {
        "fig7": {"anfis": {"radius_m": 0.1, "d_max_m": 3.0, "median_pct": 9.87, "n_groups": 393,
                           "beyond_training_domain": {"n_groups": 295, "median_pct": 24.9}}},
        "in_sample": {"models": {"anfis": {"rssi_dbm": {"mae": 4.25}},
                                 "baselines": {"detection": {"mae": 0.042}}}},
        "heldout": {"models": {"anfis": {"rssi_dbm": {"mae": 5.52, "n": 396}},
                               "grid_count": {"detection": {"mae": 0.146}}}},
        "localisation": {"eval": {"position_error_median_m": 0.0457}},
        "error_budget": {
            "representation_bound": {"rmse_db": 3.0, "d_bin_m": 0.25, "alpha_bin_deg": 10.0,
                                     "n_cells": 25},
            "model_form": {"rmse_db": 5.0, "between_cells_db": 4.0, "within_cells_db2": 0.0},
            "localisation": {"rmse_db": 4.9, "step_db": -0.1},
            "n_links": {"value": 165}, "reader_noise": {"rmse_db": 0.94},
            "total": {"rmse_db": 7.09}, "by_cell_size": by_size}}
    (run / "metrics.json").write_text(json.dumps(metrics))
    (run / "downstream" / "scores.json").write_text(json.dumps({"info": {"n_candidates": 69596}}))
    (run / "config.toml").write_text("[training]\nmin_attempts = 5\n")
    src = {"commit": commit, "dirty": False} if commit else {"commit": None, "why": "no git"}
    (run / "manifest.json").write_text(json.dumps({"source": src}))
    return run


def _main():
    return runpy.run_path(str(ROOT / "scripts" / "readme_tables.py"))["main"]


def test_single_run_block_is_written_from_the_run_and_names_it(tmp_path):
    run = _run_dir(tmp_path)
    doc = tmp_path / "results.md"
    doc.write_text("intro 4.80\n<!-- single-run:begin -->\nSTALE 4.80 dB\n<!-- single-run:end -->\n"
                   "rest\n")
    assert _main()([str(run), "--single-run", "--write", str(doc)]) == 0
    text = doc.read_text()
    assert text.startswith("intro 4.80\n") and text.endswith("rest\n") and "STALE" not in text
    block = text.split("<!-- single-run:begin -->")[1]
    assert "run `default-at-x` at commit 0123456" in block
    # every number from the files: bound, model, the exact split and its shares
    assert "scores 3.00 dB" in block and "true poses scores 5.00 dB" in block
    assert "5.00² = 3.00² + 4.00² + 0.00" in block
    assert "So 36 % of" in block and "64 % is the model's cell means" in block
    assert "MCL poses 4.90 dB (−0.10 dB; MCL errs by 4.6 cm" in block
    assert "the 295 groups beyond it" in block and "(median 25 %)" in block
    assert "69,596 candidate sites" in block and "at least 5 of them" in block
    # the bound binds only where the model is near constant: ANFIS beats it at 1 m x 40 deg
    assert "At 1 m × 40° ANFIS beats it" in block
    assert "On all 396 held-out links ANFIS's RMSE is 7.09 dB" in block


def test_a_run_without_a_commit_needs_one_named(tmp_path, capsys):
    run = _run_dir(tmp_path, commit=None)
    assert _main()([str(run), "--single-run"]) == 2
    assert "records no commit" in capsys.readouterr().err
    assert _main()([str(run), "--single-run", "--commit", "fedcba987654"]) == 0
    assert "at commit fedcba9" in capsys.readouterr().out


def test_results_md_quotes_the_budget_only_inside_the_written_block():
    text = (ROOT / "docs" / "results.md").read_text()
    begin, end = "<!-- single-run:begin -->", "<!-- single-run:end -->"
    assert text.count(begin) == 1 and text.count(end) == 1
    inside = text.split(begin)[1].split(end)[0]
    outside = text.replace(begin + inside + end, "")
    assert "**Error budget**" in inside and "**Error budget**" not in outside
    assert "written by scripts/readme_tables.py" in inside and "at commit" in inside


@pytest.mark.skipif(shutil.which("git") is None, reason="git not installed")
def test_manifest_source_is_the_checkout_commit():
    from pipeline.stages.common import source_revision

    head = subprocess.run(["git", "-C", str(ROOT), "rev-parse", "HEAD"], capture_output=True,
                          text=True)
    if head.returncode != 0:
        pytest.skip("not a git checkout")
    src = source_revision()
    assert src["commit"] == head.stdout.strip() and isinstance(src["dirty"], bool)


@pytest.mark.skipif(shutil.which("git") is None, reason="git not installed")
def test_source_revision_checks_the_checkout_and_untracked_sources(tmp_path):
    from pipeline.stages.common import source_revision

    def git(*args, cwd=tmp_path / "repo"):
        subprocess.run(["git", "-c", "user.name=t", "-c", "user.email=t@t", *args], cwd=cwd,
                       check=True, capture_output=True)

    repo = tmp_path / "repo"
    (repo / "pipeline").mkdir(parents=True)
    (repo / "pipeline" / "a.py").write_text("x = 1\n")
    git("init", "-q", cwd=tmp_path)  # an enclosing checkout: not the package's own
    nested = source_revision(repo)
    assert nested["commit"] is None and "not the top" in nested["why"]
    git("init", "-q")
    git("add", ".")
    git("commit", "-qm", "c")
    clean = source_revision(repo)
    assert isinstance(clean["commit"], str) and len(clean["commit"]) == 40
    assert clean["dirty"] is False
    (repo / "notes.txt").write_text("not source\n")  # untracked outside the sources
    assert source_revision(repo)["dirty"] is False
    (repo / "scenes").mkdir()
    (repo / "scenes" / "new.py").write_text("y = 2\n")  # untracked source
    assert source_revision(repo)["dirty"] is True
    (repo / "scenes" / "new.py").unlink()
    (repo / "pipeline" / "a.py").write_text("x = 2\n")  # tracked and changed
    assert source_revision(repo)["dirty"] is True
    assert "no pipeline/" in source_revision(tmp_path / "elsewhere")["why"]
