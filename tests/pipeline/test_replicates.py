"""Replicated studies (pipeline.apps.replicates): seeds, config, and a real two-replicate tiny
study pooled, then grown to three with one replicate that cannot run."""

from __future__ import annotations

import json
import zlib
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from pipeline.apps.replicates import replicate_configs, replicate_seed
from pipeline.config import ConfigError, config_from_mapping, load_config, replace_path
from tests.conftest import copy_run, draw_only

ROOT = Path(__file__).resolve().parents[2]


def test_replicate_seeds_are_distinct_streams_and_do_not_depend_on_n():
    seeds = [replicate_seed(2011, k) for k in range(200)]
    assert seeds[0] == 2011 and len(set(seeds)) == 200
    assert all(0 <= s < 2**63 for s in seeds)
    # the stage streams of two replicates (pipeline.studyscene.stage_rng) differ
    draws = {tuple(np.random.default_rng([s, zlib.crc32(b"tour")]).integers(0, 2**31, 4))
             for s in seeds}
    assert len(draws) == 200
    cfg = replace_path(load_config(ROOT / "configs" / "tiny.toml"), "replicates.n", 3)
    more = replace_path(cfg, "replicates.n", 5)
    assert [c.seed for c in replicate_configs(cfg)] == [c.seed for c in replicate_configs(more)][:3]
    assert all(c.replicates.n == 1 for c in replicate_configs(cfg))
    assert len({c.tracing.cache_dir for c in replicate_configs(more)}) == 1


@pytest.mark.parametrize("value, match", [(0, "replicates.n must be >= 1"),
                                          (-3, "replicates.n must be >= 1"),
                                          (1.5, "must be an integer"),
                                          (True, "must be an integer")])
def test_bad_replicate_counts_are_refused(value, match):
    with pytest.raises(ConfigError, match=match):
        config_from_mapping({"replicates": {"n": value}})
    with pytest.raises(ConfigError, match="workers"):
        config_from_mapping({"replicates": {"workers": -1}})


def test_two_replicates_pooled_then_a_third_that_fails(tiny_study, tmp_path, monkeypatch):
    """Replicate 0 has the study's own seed: it is the single study of the same config, so
    the session's tiny study (copied into ``replicates/0``, same cache) is replicate 0
    finished; the replicated run resumes it (every stage cached) and runs replicate 1."""
    from pipeline.apps.studyrun import run_full_study

    # one worker: the replicates one after the other in this process (the pool's spawned
    # workers: tests/pipeline/test_studypool.py)
    cfg = replace_path(replace_path(tiny_study.config, "replicates.n", 2), "replicates.workers", 1)
    # replicate 1's figures stage draws one figure (in this process: the monkeypatch holds);
    # the pooled report reads the replicates' numbers, not their figures
    draw_only(monkeypatch, "scene_top_view")
    run = tmp_path / "run"
    copy_run(tiny_study, run / "replicates" / "0")
    # force_dir: the run directory holds replicates/0 and no manifest of its own yet
    res = run_full_study(cfg, run, progress=False, command_line=["pytest"], force_dir=True)
    assert res.ran == ["replicates", "pooled", "report"]
    m = json.loads((run / "metrics.json").read_text())
    assert m["replicates"]["covers"] == "2 of 2 replicates" and not m["replicates"]["failed"]
    seeds = m["replicates"]["seeds"]
    assert seeds["0"] == cfg.seed and seeds["1"] == replicate_seed(cfg.seed, 1)
    # each replicate is a study of its own, on its own held-out layout
    held = [pd.read_parquet(run / "replicates" / k / "scene" / "tags.parquet").query("split == 'eval'")
            for k in ("0", "1")]
    assert not np.allclose(held[0][["x_m", "y_m", "z_m"]].to_numpy(),
                           held[1][["x_m", "y_m", "z_m"]].to_numpy())
    own = [json.loads((run / "replicates" / k / "metrics.json").read_text()) for k in ("0", "1")]
    assert own[0] == json.loads((tiny_study.run / "metrics.json").read_text())  # resumed as is
    tag = m["intervals"]["tag_localisation.median_m"]
    assert tag["unit"] == "replicate x tag" and tag["n_units"] == 32
    # two replicates: the replicate is the top-level unit, and one difference between two
    # replicates is no interval (pipeline.evaluation.intervals.MIN_REPLICATES)
    assert tag["models"]["anfis"]["low"] is None and "2 replicates" in tag["models"]["anfis"]["note"]
    assert np.isfinite(tag["models"]["anfis"]["estimate"])
    per = m["per_replicate"]["metrics"]["tag_localisation.median_m"]["anfis"]
    assert per == pytest.approx([o["tag_localisation"]["anfis"]["median_m"] for o in own])
    rmse = m["per_replicate"]["metrics"]["heldout.rssi_rmse_db"]["anfis"]
    assert rmse == pytest.approx([o["heldout"]["models"]["anfis"]["rssi_dbm"]["rmse"] for o in own])
    # the pooled robot sample: every filter run of both replicates
    rob = m["intervals"]["robot_localisation.median_m"]
    assert rob["n_units"] == 2 * cfg.downstream.robot_runs
    assert "replicate 1" in (run / "report.html").read_text()

    # the README's tables are written from such a run, between their markers only
    import runpy

    readme = tmp_path / "README.md"
    readme.write_text("intro\n<!-- headline-tables:begin -->\nold\n<!-- headline-tables:end -->\nrest\n")
    tables = runpy.run_path(str(ROOT / "scripts" / "readme_tables.py"))
    assert tables["main"]([str(run), "--write", str(readme)]) == 0
    text = readme.read_text()
    assert text.startswith("intro\n") and text.endswith("rest\n") and "old" not in text
    est = m["intervals"]["heldout.rssi_mae_db"]["models"]["anfis"]
    assert f"{est['estimate']:.2f}" in text
    assert "From 2 of 2 replicates" in text

    # a third replicate whose directory is taken by a file: named, the others kept
    (run / "replicates" / "2").write_text("not a run directory")
    res = run_full_study(replace_path(cfg, "replicates.n", 3), run, progress=False,
                         command_line=["pytest"])
    m3 = json.loads((run / "metrics.json").read_text())
    assert m3["replicates"]["covers"] == "2 of 3 replicates"
    assert [f["k"] for f in m3["replicates"]["failed"]] == [2]
    assert "is a file" in m3["replicates"]["failed"][0]["error"]
    assert m3["intervals"]["tag_localisation.median_m"]["n_units"] == 32
    # the two complete replicates were not run again
    for k in ("0", "1"):
        man = json.loads((run / "replicates" / k / "manifest.json").read_text())
        assert man["status"] == "complete"
    assert (run / "replicates" / "2").read_text() == "not a run directory"


def test_every_complete_replicate_is_pooled(tiny_study, tmp_path, monkeypatch):
    """The pooled stage on two replicates that differ: the session's tiny study, and a copy
    of it whose held-out tags' localisation errors are doubled. The replicates' studies are
    finished; a stand-in for the runner reports them complete (real replicates run in
    :func:`test_two_replicates_pooled_then_a_third_that_fails`). Pooling only replicate 0,
    or one replicate twice, gives its own numbers: this test fails on either."""
    import pipeline.apps.replicates as replicates
    from pipeline.apps.studyrun import run_full_study

    run = tmp_path / "run"
    for k in ("0", "1"):
        copy_run(tiny_study, run / "replicates" / k)
    errors = run / "replicates" / "1" / "downstream" / "tag_errors.parquet"
    doubled = pd.read_parquet(errors)
    doubled["error_m"] *= 2.0
    doubled.to_parquet(errors)
    ran = []
    monkeypatch.setattr(replicates, "run_studies", lambda args, **kw: ran.extend(args) or [
        {"status": "complete", "error": None} for _ in args])
    cfg = replace_path(tiny_study.config, "replicates.n", 2)
    res = run_full_study(cfg, run, progress=False, command_line=["pytest"], force_dir=True)
    assert res.ran == ["replicates", "pooled", "report"]
    assert [d for _, d in ran] == [str(run / "replicates" / k) for k in ("0", "1")]
    m = json.loads((run / "metrics.json").read_text())
    assert m["replicates"]["covers"] == "2 of 2 replicates"
    per = m["per_replicate"]["metrics"]["tag_localisation.median_m"]["anfis"]
    assert per[1] == pytest.approx(2.0 * per[0]) and per[0] > 0
    tag = m["intervals"]["tag_localisation.median_m"]
    assert tag["unit"] == "replicate x tag" and tag["n_units"] == 32
    pooled = tag["models"]["anfis"]["estimate"]
    assert per[0] < pooled < per[1]  # the median of both replicates' 32 errors
