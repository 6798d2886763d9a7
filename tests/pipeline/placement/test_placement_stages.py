"""A placement runs only the stages its objectives need, answers in the engineer's units,
and stops at the second candidate that fails alike (real tiny-corridor studies).

The three candidates' studies up to their reads run once (:func:`inventory`, the
inventory objectives' placement); the placements whose training fails start from a copy
of its candidate directories (a study's run directory is its cache: their scene, tour
and reads stages are done, the truth's traces and the training run)."""

from __future__ import annotations

import json
import re
import shutil
from pathlib import Path

import numpy as np
import pytest

from pipeline.apps.placement import load_placement, run_placement
from pipeline.apps.placement.runner import MARKER, PlacementStopped
from pipeline.parallel import WORKERS_ENV

ROOT = Path(__file__).resolve().parents[3]


@pytest.fixture(scope="module")
def cache(tiny_study) -> Path:
    # the session's tiny study's cache: its tour is the 0-degree candidate's (replicate 0
    # has the base seed, the mounts are the base's), so no selection study here traces
    return Path(tiny_study.config.tracing.cache_dir)


def _spec(tmp_path: Path, cache: Path, head: str, study: str = ""):
    p = tmp_path / "placement.toml"
    p.write_text(
        f'base = "{ROOT / "configs" / "tiny.toml"}"\n'
        "replicates = 1\n"
        f"{head}\n"
        "[grid]\n"
        "tilt_deg = [0.0, 10.0, 20.0]\n"  # orientation only: the traces are shared
        "[study.tracing]\n"
        f'cache_dir = "{cache}"\n'
        "[study.downstream]\n"
        "enabled = false\n"
        f"{study}")
    return load_placement(p)


@pytest.fixture(scope="module")
def inventory(tmp_path_factory, cache):
    """The inventory objectives' placement: three candidates' studies up to their reads
    (no confirmation: nothing here reads its fresh replicates). Read it; copy it
    (:func:`_copy_candidates`) before running anything in it."""
    tmp = tmp_path_factory.mktemp("inventory")
    spec = _spec(tmp, cache, 'primary = "reads_per_pass"\n'
                             'pareto = ["link_margin_db", "never_read"]\n'
                             "confirm_top = 0")
    out = tmp / "out"
    return run_placement(spec, out, workers=1), out


def _copy_candidates(src: Path, dest: Path) -> Path:
    """A placement directory at ``dest`` holding ``src``'s marker and candidates' studies
    (not its answer)."""
    dest.mkdir()
    shutil.copy2(src / MARKER, dest / MARKER)
    shutil.copytree(src / "candidates", dest / "candidates")
    return dest


def test_inventory_objectives_run_no_model_and_answer_in_engineering_units(inventory):
    res, out = inventory
    runs = sorted(out.glob("candidates/*/0"))
    assert len(runs) == 3
    for run in runs:  # up to the reads, nothing after them
        stages = {p.stem for p in (run / "stages").glob("*.json")}
        assert stages == {"scene", "tour", "reads"}, (run, stages)
    s = res.summary.set_index("candidate")
    for key in ("reads_per_pass", "link_margin_db", "never_read", "read_rate"):
        for c in s.index:
            v, lo, hi = s.loc[c, key], s.loc[c, f"{key}_low"], s.loc[c, f"{key}_high"]
            assert np.isfinite(v) and lo <= v <= hi, (key, c, lo, v, hi)
    assert (s["n_tags"] > 0).all() and (s["never_read_n"] <= s["n_tags"]).all()
    # reads per pass is the reads over (tag, pass) of the one pass: recount it from the log
    import pandas as pd

    best = res.answer["recommended"]
    reads = pd.read_parquet(out / "candidates" / best / "0" / "reads.parquet")
    assert res.answer["studies_ran_upto"] == "reads"
    assert s.loc[best, "reads_per_pass"] <= reads["read"].sum() / s.loc[best, "n_tags"] + 1e-9
    # model objectives were never asked for: none, not a failure
    assert not np.isfinite(s.loc[best, "rssi_rmse_db"])
    figs = out / "placement" / "figures"
    assert (figs / f"readmap_{best}.png").is_file() and (figs / f"never_read_{best}.png").is_file()
    report = (out / "placement" / "report.html").read_text()
    assert "reads per tag per pass" in report and "link margin" in report
    assert "tags never read in the tour" in report


def _one_stage_at_a_time(monkeypatch):
    """The candidates' studies run their stages one after the other: the truth's traces
    (cached) in the study's own process, not in a fresh interpreter started per study;
    nothing here looks at where a stage ran (tests/pipeline/test_study_side.py does)."""
    monkeypatch.setenv(WORKERS_ENV, "1")


def test_a_model_only_the_pareto_needs_is_dropped_not_fatal(tmp_path, cache, inventory,
                                                            monkeypatch):
    # 100 rules on a 5 m tour: fewer samples than rules, every candidate fails
    _one_stage_at_a_time(monkeypatch)
    spec = _spec(tmp_path, cache, 'primary = "read_rate"\npareto = ["read_rate", "rssi_rmse_db"]',
                 "[study.training]\nn_clusters = 100\n")
    out = _copy_candidates(inventory[1], tmp_path / "out")
    res = run_placement(spec, out, workers=1)
    a = res.answer
    # the tour is too short for 100 rules: the training sets (or the fit) fail
    assert len(a["dropped"]) == 1 and re.match(r"stage (training_sets|models) failed",
                                               a["dropped"][0])
    assert "too few training samples" in a["dropped"][0] and "earlier stages" not in a["dropped"][0]
    assert "rssi_rmse_db" in a["dropped"][0]
    assert a["studies_ran_upto"] == "reads"
    s = res.summary.set_index("candidate")
    assert np.isfinite(s["read_rate"]).all()  # every candidate ranked on its reads
    assert a["recommended"] in s.index
    assert "Not computed" in (out / "placement" / "report.html").read_text()


def test_two_candidates_failing_alike_stop_the_placement(tmp_path, cache, inventory, monkeypatch):
    _one_stage_at_a_time(monkeypatch)
    spec = _spec(tmp_path, cache, 'primary = "rssi_rmse_db"\npareto = ["read_rate", "rssi_rmse_db"]',
                 "[study.training]\nn_clusters = 100\n")
    out = _copy_candidates(inventory[1], tmp_path / "out")
    with pytest.raises(PlacementStopped, match=r"stage (training_sets|models) failed with \w+Error in candidates "
                                                r"tilt\S+ and tilt\S+"):
        run_placement(spec, out, workers=1)
    marker = json.loads((out / "placement.json").read_text())
    assert len(marker["candidates"]) == 3 and marker["file"]["primary"] == "rssi_rmse_db"  # this run's
    assert not (out / "placement" / "answer.json").exists()  # no answer from failures


def test_one_worker_runs_the_position_waves_in_order_as_one_batch(tmp_path):
    """One local worker runs the studies one after the other: the position waves go to it
    as one batch, the first wave first (its siblings find the positions traced), so one
    worker serves them all, in its caller's process; more workers keep the waves apart."""
    from pipeline.apps.placement.candidates import candidates_of
    from pipeline.apps.placement.runner import _Runner, position_waves

    spec = _spec(tmp_path, tmp_path / "cache", 'pareto = ["read_rate", "never_read"]')
    cands = candidates_of(spec)
    waves = position_waves(cands)
    assert [[c.name for c in w] for w in waves] == [["tilt0"], ["tilt10", "tilt20"]]
    assert _Runner(spec, tmp_path, 1, None, None, None)._waves(cands) == [waves[0] + waves[1]]
    assert _Runner(spec, tmp_path, 2, None, None, None)._waves(cands) == waves
    assert _Runner(spec, tmp_path, 1, "tcp://scheduler:8786", None, None)._waves(cands) == waves
