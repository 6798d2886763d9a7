"""Sweep files: expansion into study configs and errors naming the parameter."""

from __future__ import annotations

import os
from pathlib import Path

import pytest

from pipeline.apps.sweep import PARAMETERS, apply_parameter, expand_sweep, load_sweep
from pipeline.config import ConfigError, StudyConfig

ROOT = Path(__file__).resolve().parents[2]


def test_example_sweep_expands():
    plan = load_sweep(ROOT / "configs" / "sweep_example.toml")
    assert len(plan.configs) == 4  # 2 heights x 2 powers
    combos = {(c.robot.antennas[0].z_m, c.robot.antennas[1].z_m, c.reader.tx_power_dbm)
              for c in plan.configs}
    assert combos == {(0.5, 0.5, 24.0), (0.5, 0.5, 27.15), (0.9, 0.9, 24.0), (0.9, 0.9, 27.15)}
    assert all(c.seed == 11 for c in plan.configs)  # [study] override
    assert all(c.tour.max_length_m == 5.0 for c in plan.configs)  # base = tiny.toml
    assert len(set(plan.names)) == 4


def test_unknown_parameter_named_and_known_listed(tmp_path):
    p = tmp_path / "s.toml"
    p.write_text("[parameters]\nantenna_hight_m = [0.5]\n")
    with pytest.raises(ConfigError) as exc:
        load_sweep(p)
    msg = str(exc.value)
    assert "antenna_hight_m" in msg and str(p) in msg
    for known in PARAMETERS:
        assert known in msg


def test_unknown_sweep_key(tmp_path):
    p = tmp_path / "s.toml"
    p.write_text("bse = 'x.toml'\n[parameters]\ntx_power_dbm = [20.0]\n")
    with pytest.raises(ConfigError, match="unknown key.*bse"):
        load_sweep(p)


def test_upto_is_a_stage_and_not_for_replicated_points(tmp_path):
    p = tmp_path / "s.toml"
    p.write_text('upto = "evaluation"\n[parameters]\ntx_power_dbm = [20.0, 24.0]\n')
    assert load_sweep(p).upto == "evaluation"
    p.write_text('upto = "evaluaton"\n[parameters]\ntx_power_dbm = [20.0]\n')
    with pytest.raises(ConfigError, match="'evaluaton' is not a stage of point 0's study; "
                                          "its stages are scene, tour"):
        load_sweep(p)
    p.write_text('upto = "reads"\n[parameters]\ntx_power_dbm = [20.0]\n')
    with pytest.raises(ConfigError, match="stops before 'evaluation', which writes the metrics"):
        load_sweep(p)
    p.write_text('upto = "evaluation"\n[parameters]\nreplicates = [1, 3]\n')
    with pytest.raises(ConfigError, match=r"point 1 .*replicates.n = 3"):
        load_sweep(p)
    p.write_text('[parameters]\ntx_power_dbm = [20.0]\n')
    assert load_sweep(p).upto is None


def test_yaw_keeps_each_side_sign():
    cfg = apply_parameter(StudyConfig(), "antenna_yaw_deg", 60.0)
    assert [a.yaw_deg for a in cfg.robot.antennas] == [60.0, -60.0]


def test_antenna_count_and_bounds():
    cfg = apply_parameter(StudyConfig(), "antenna_count", 1)
    assert [a.name for a in cfg.robot.antennas] == ["left"]
    with pytest.raises(ConfigError, match="antenna_count = 3"):
        apply_parameter(StudyConfig(), "antenna_count", 3)


def test_dotted_key_parameter_and_bad_value():
    plan = expand_sweep(StudyConfig(), {"training.epochs": [2, 4]})
    assert [c.training.epochs for c in plan.configs] == [2, 4]
    with pytest.raises(ConfigError, match="training.epochs"):
        expand_sweep(StudyConfig(), {"training.epochs": ["many"]})


def test_zip_mode_needs_equal_lengths():
    plan = expand_sweep(StudyConfig(), {"tx_power_dbm": [20.0, 25.0], "antenna_tilt_deg": [0.0, 10.0]},
                        mode="zip")
    assert [(c.reader.tx_power_dbm, c.robot.antennas[0].tilt_deg) for c in plan.configs] == [
        (20.0, 0.0), (25.0, 10.0)]
    with pytest.raises(ConfigError, match="equal-length"):
        expand_sweep(StudyConfig(), {"tx_power_dbm": [20.0, 25.0], "antenna_tilt_deg": [0.0]},
                     mode="zip")


def test_a_sweep_worker_caps_its_studys_forks(monkeypatch):
    from pipeline.apps.studypool import _cap_nested_workers
    from pipeline.parallel import WORKERS_ENV

    for before, after in ((None, "2"), ("1", "1"), ("2", "2"), ("8", "2"), ("0", "2"),
                          ("two", "2"), ("²", "2")):  # "²".isdigit() but not a count
        if before is None:
            monkeypatch.delenv(WORKERS_ENV, raising=False)
        else:
            monkeypatch.setenv(WORKERS_ENV, before)
        _cap_nested_workers(2)
        assert os.environ[WORKERS_ENV] == after, before


def test_seed_and_replicates_are_ordinary_parameters():
    plan = expand_sweep(StudyConfig(), {"antenna_height_m": [0.5, 0.9], "seed": [1, 2, 3]})
    assert len(plan.configs) == 6
    assert sorted({c.seed for c in plan.configs}) == [1, 2, 3]
    # a seed changes the seed and nothing else
    a, b = plan.configs[0], plan.configs[1]
    assert a.seed != b.seed and a.robot == b.robot and a.tracing == b.tracing
    rep = expand_sweep(StudyConfig(), {"replicates": [3]})
    assert rep.configs[0].replicates.n == 3
    with pytest.raises(ConfigError, match="seed"):
        expand_sweep(StudyConfig(), {"seed": [1.5]})
    with pytest.raises(ConfigError, match="replicates"):
        expand_sweep(StudyConfig(), {"replicates": [0]})


def test_sweep_console_table_is_short_and_ranked():
    import pandas as pd

    from pipeline.apps.cli import _sweep_table

    summary = pd.DataFrame({
        "name": ["a", "b", "c"], "tx_power_dbm": [24.0, 27.15, 30.0],
        "status": ["complete", "complete", "failed"], "read_rate": [0.41, 0.83, float("nan")],
        "completeness": [0.5, 0.9, float("nan")], "a_long_column_nobody_reads": [1, 2, 3],
        "note": ["x" * 200] * 3})
    text = _sweep_table(summary, ["tx_power_dbm"])
    lines = text.splitlines()
    assert max(map(len, lines)) <= 80
    assert "a_long_column_nobody_reads" not in text and "note" not in text
    # too many columns for 80: whole columns go, never part of a number
    wide = summary.assign(**{f"p{k}_with_a_long_name": 1.23456 for k in range(6)})
    text = _sweep_table(wide, [f"p{k}_with_a_long_name" for k in range(6)] + ["tx_power_dbm"])
    assert max(map(len, text.splitlines())) <= 80
    header = text.splitlines()[0].split()
    assert all(h in wide.columns for h in header), header
    # best read rate first, the failed point last
    assert lines[1].split()[0] == "27.15" and "failed" in lines[-1]
