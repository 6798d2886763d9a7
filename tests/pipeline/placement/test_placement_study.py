"""A real placement study on the tiny corridor: paired replicates, trace reuse, the ranked
answer with intervals, resumption that computes nothing, and a refused foreign directory.

The study runs one replicate per candidate (and one fresh replicate each to confirm): the
flow is the same for any count, and each replicate is a study of its own. How a
candidate's replicates are pooled (units ``r<k>/<id>``, two-stage intervals) is tested
on the session's tiny study read as three replicates
(:func:`test_replicates_pool_into_two_stage_intervals`), without running twelve studies."""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path

import numpy as np
import pytest

from pipeline.apps.placement import load_placement, run_placement
from pipeline.config import ConfigError, load_config
from pipeline.parallel import WORKERS_ENV

ROOT = Path(__file__).resolve().parents[3]


def _spec(tmp_path: Path, tilts: list[float]):
    p = tmp_path / f"placement_{len(tilts)}.toml"
    p.write_text(
        f'base = "{ROOT / "configs" / "tiny.toml"}"\n'
        "replicates = 1\n"
        "pareto = [\"read_rate\", \"rssi_rmse_db\"]\n"
        "[grid]\n"
        f"tilt_deg = {tilts}\n"
        "[study.tracing]\n"
        f'cache_dir = "{tmp_path / "cache"}"\n'  # a cold cache of its own
        "[study.downstream]\n"
        "enabled = false\n"  # its objectives are tested with the replicates' tables
        # what no assertion reads: the truth's site poses and field, the ANFIS epochs
        "[study.evaluation]\n"
        "n_site_poses = 2\n"
        "n_field_poses = 0\n"
        "[study.training]\n"
        "epochs = 1\n")
    return load_placement(p)


def test_placement_study(tmp_path, monkeypatch):
    # one worker, each study's stages one after the other: no fresh interpreter per wave
    # of candidates, nor per study for the truth's traces; nothing here looks at where a
    # study or a stage ran (tests/pipeline/test_study_side.py does)
    monkeypatch.setenv(WORKERS_ENV, "1")
    out = tmp_path / "out"
    first = run_placement(_spec(tmp_path, [0.0]), out, workers=1)
    cold = first.summary.set_index("candidate").loc["tilt0"]
    assert cold["n_sources_traced"] > 0  # a cold cache: the tours' antenna positions traced

    events = []
    res = run_placement(_spec(tmp_path, [0.0, 25.0]), out, workers=1, progress=events.append)
    s = res.summary.set_index("candidate")
    # an orientation-only candidate traces no new antenna position (the path cache is
    # keyed by position; tilt turns the antenna about its phase centre)
    assert s.loc["tilt25", "n_sources_traced"] == 0
    assert s.loc["tilt25", "n_replicates"] == 1
    ran = {e.candidate: e.n_stages_run for e in events}
    # tilt0's selection replicates were done (the first run confirmed nothing: one candidate)
    assert ran["tilt0"] == 0 and ran["tilt25"] > 0

    # replicates change the seed and nothing else; candidates share the replicate seeds
    # (replicate 1: the confirmation's fresh one)
    cfg = {(c, k): load_config(out / "candidates" / c / str(k) / "config.toml")
           for c in ("tilt0", "tilt25") for k in (0, 1)}
    assert cfg["tilt25", 0].seed != cfg["tilt25", 1].seed
    assert dataclasses.replace(cfg["tilt25", 1], seed=cfg["tilt25", 0].seed) == cfg["tilt25", 0]
    assert cfg["tilt0", 0].seed == cfg["tilt25", 0].seed
    assert cfg["tilt0", 1].seed == cfg["tilt25", 1].seed
    assert cfg["tilt0", 0].robot.antennas != cfg["tilt25", 0].robot.antennas

    # every objective with an interval around its estimate (or none, said so)
    for key in ("read_rate", "completeness", "surface_coverage", "rssi_rmse_db"):
        for c in ("tilt0", "tilt25"):
            v, lo, hi = s.loc[c, key], s.loc[c, f"{key}_low"], s.loc[c, f"{key}_high"]
            assert np.isfinite(v)
            assert lo <= v <= hi, (key, c, lo, v, hi)
    answer = json.loads((out / "placement" / "answer.json").read_text())
    assert answer["recommended"] in ("tilt0", "tilt25") and answer["runner_up"] in ("tilt0", "tilt25")
    best = answer["recommended"]
    other = answer["runner_up"]
    # the ranking follows the estimates; the margin is the runner-up minus the best
    sign = -1.0  # read_rate: higher is better
    assert sign * s.loc[best, "read_rate"] <= sign * s.loc[other, "read_rate"]
    assert answer["margin"]["estimate"] == pytest.approx(
        s.loc[other, "read_rate"] - s.loc[best, "read_rate"], abs=1e-12)
    assert answer["margin_exceeds_interval"] == (answer["margin"]["verdict"] == "worse")
    # with two candidates, a single best is exactly a runner-up worse at 95 %
    assert answer["single_best"] == answer["margin_exceeds_interval"]
    report = (out / "placement" / "report.html").read_text()
    assert (f"Recommended: {best}" if answer["single_best"] else "No single best") in report
    assert "None" not in report and "Selection rule" in report
    # the confirmation: both candidates again on a fresh seed (replicate 1), scored on it alone
    conf = answer["confirmation"]
    assert conf["candidates"][0] == best and conf["replicates"] == [1, 1]
    assert cfg[best, 1].seed not in {cfg["tilt0", 0].seed, cfg["tilt25", 0].seed}
    assert conf["estimates"][best]["n_units"] > 0 and set(conf["vs_selected"]) == {other}
    assert "Confirmation on fresh replicates 1-1" in report
    assert (out / "placement" / "figures" / "ranking.png").is_file()

    # a rerun computes nothing: no stage record changes but the scene stage's, which
    # always runs (it loads the scene and checks it against the record)
    def records():
        return {p: p.read_bytes() for p in out.glob("candidates/*/*/stages/*.json")
                if p.name != "scene.json"}

    before = records()
    assert len(before) > 20
    events.clear()
    run_placement(_spec(tmp_path, [0.0, 25.0]), out, workers=1, progress=events.append)
    assert records() == before
    assert [e.n_stages_run for e in events] == [0, 0, 0, 0]  # two candidates, two confirmed
    assert not np.isfinite(s.loc["tilt0", "tag_localisation_median_m"])  # downstream off: none

    # a directory holding someone's files is not a placement directory
    foreign = tmp_path / "foreign"
    foreign.mkdir()
    (foreign / "notes.txt").write_text("mine")
    with pytest.raises(ConfigError, match="not a placement study"):
        run_placement(_spec(tmp_path, [0.0]), foreign)
    assert sorted(p.name for p in foreign.iterdir()) == ["notes.txt"]


def test_replicates_pool_into_two_stage_intervals(tiny_study):
    """A candidate's replicates pooled: units ``r<k>/<id>``, every objective's interval the
    two-stage one over them (the replicate first). The session's tiny study (downstream
    on: every objective has its table) read as three replicates: the same units three
    times, so the estimates are the one study's."""
    from pipeline.apps.placement.objectives import (
        OBJECTIVES,
        compare_objective,
        load_candidate_data,
        objective_interval,
    )
    from pipeline.studyscene import link_budget

    run = tiny_study.run
    budget = link_budget(tiny_study.config)
    one = load_candidate_data({0: run}, budget)
    three = load_candidate_data({0: run, 1: run, 2: run}, budget)
    assert three.replicates == [0, 1, 2]
    units = three.inventory["unit"].astype(str)
    assert {u.split("/", 1)[0] for u in units} == {"r0", "r1", "r2"}
    for key, obj in OBJECTIVES.items():
        a = objective_interval(one, key, seed=1)
        b = objective_interval(three, key, seed=1)
        assert np.isfinite(a.estimate) and b.estimate == pytest.approx(a.estimate), key
        assert b.n_units == 3 * a.n_units > 0 and b.unit == obj.unit, key
        assert b.method == "two-stage percentile" and b.low <= b.estimate <= b.high, (key, b)
        assert a.method != b.method  # one replicate: its units resampled as independent
    same = compare_objective(three, three, "rssi_rmse_db", seed=1)
    assert same.difference.estimate == 0.0 and same.verdict == "not distinguishable at 95 %"
