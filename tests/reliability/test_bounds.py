"""Every size-like key has an upper bound, checked before any work, named in the error.

A few zeros too many (``tracing.max_depth = 1000`` took 20.5 GB before the kernel killed
it; ``robot_runs = 1e9`` ran on with no end) stop at config time: exit code 2, one line
naming the key and its bound, and no run directory made.
"""

from __future__ import annotations

from pathlib import Path

import pytest
from typer.testing import CliRunner

from pipeline.apps.cli import app
from pipeline.config import ConfigError, StudyConfig, replace_path

ROOT = Path(__file__).resolve().parents[2]

SIZES = ["tracing.max_depth", "tracing.samples_per_src", "tracing.shared_samples_per_src",
         "tracing.min_samples_per_position",
         "tracing.field_samples_per_tx", "training.epochs", "localisation.n_particles",
         "tour.n_passes", "tour.n_eval_poses", "downstream.robot_particles",
         "downstream.robot_runs", "evaluation.n_sample_poses", "evaluation.grid_n_d",
         "evaluation.grid_n_alpha", "evaluation.n_eval_tags", "evaluation.n_site_poses",
         "reader.read_rate_hz", "tracing.memory_budget_mb", "training.n_clusters",
         "localisation.laser_beams", "localisation.n_beams_used", "tour.lane_changes_per_pass",
         "tour.stops_per_pass"]


@pytest.mark.parametrize("key", SIZES)
def test_an_oversized_key_stops_before_any_work_naming_it(tmp_path, key):
    out = tmp_path / "run"
    res = CliRunner().invoke(app, ["run", str(ROOT / "configs" / "tiny.toml"), "--no-progress",
                                   "--set", f"{key}=1000000000", "--out", str(out)])
    assert res.exit_code == 2, res.output
    line = res.output.strip().splitlines()[-1]
    assert key.split(".")[-1] in line and "upper bound" in line and "Traceback" not in res.output
    assert not out.exists()


def test_the_bound_is_a_bound_not_a_default():
    # the defaults and the paper-scale sizes stay inside their bounds
    assert replace_path(StudyConfig(), "tracing.max_depth", 10).tracing.max_depth == 10
    with pytest.raises(ConfigError, match=r"max_depth = 11: more than its upper bound 10"):
        replace_path(StudyConfig(), "tracing.max_depth", 11)


def test_too_many_tags_stop_before_any_tracing():
    """1e5 tags never answered (each is traced from every antenna position): more than
    MAX_TAGS stop when the tags are made and when a scene is checked, naming the count."""
    import numpy as np

    import scenes
    from scenes.tags import MAX_TAGS, TagSet, make_tags, validate_tags

    n = MAX_TAGS + 1
    with pytest.raises(ValueError, match=rf"many.toml: tag: {n:,} tags, more than the {MAX_TAGS:,}"):
        make_tags(None, [{"id": f"t{i}", "position_m": [0.0, 0.0, 1.0]} for i in range(n)],
                  "many.toml: tag")
    scene = scenes.load("corridor_lab")
    normals = np.tile([1.0, 0.0, 0.0], (n, 1))
    scene.tags = TagSet(np.array([f"t{i}" for i in range(n)]), np.zeros((n, 3)), normals)
    with pytest.raises(ValueError, match=rf"corridor_lab: {n:,} tags"):
        validate_tags(scene)
    # a bad tag set names a few ids, not every one (a one-line message)
    with pytest.raises(ValueError) as exc:
        TagSet(np.array([f"t{i}" for i in range(n)]), np.zeros((n, 3)), np.zeros((n, 3)))
    assert f"and {n - 5:,} more" in str(exc.value) and len(str(exc.value)) < 200


def test_too_many_antennas_is_named():
    ants = [{"name": f"a{i}", "z_m": 0.7} for i in range(17)]
    with pytest.raises(ConfigError, match=r"antennas has 17 entries: more than its upper bound 16"):
        replace_path(StudyConfig(), "robot.antennas", ants)


@pytest.mark.parametrize("key, value, words", [
    ("reader.gen2.q_step", 0.9, "q_step must be in [0.1, 0.5]"),
    ("evaluation.n_field_poses", 5, "n_field_poses = 5 is more than n_sample_poses = 4"),
])
def test_values_outside_their_documented_range_are_refused(key, value, words):
    with pytest.raises(ConfigError) as err:
        replace_path(StudyConfig(), key, value)
    assert words in str(err.value)


@pytest.mark.parametrize("sets, words", [
    # within every key's bound, but one antenna position would not fit the memory budget:
    # the tracer used to trace it anyway (one source is the smallest chunk)
    (["tracing.max_depth=10", "tracing.samples_per_src=5000000"],
     "tracing.samples_per_src = 5,000,000 at tracing.max_depth = 10 needs about 15,736 MiB"),
    (["tracing.shared_samples_per_src=3000000"],
     "tracing.shared_samples_per_src = 3,000,000 at tracing.max_depth = 2 needs about 5,150 MiB"),
    # a float is no ray count (it once ended in a Mitsuba TypeError)
    (["tracing.samples_per_src=1e12"], "tracing.samples_per_src: must be an integer"),
])
def test_a_trace_that_cannot_fit_its_memory_budget_stops_naming_the_memory(tmp_path, sets, words):
    out = tmp_path / "run"
    args = ["run", str(ROOT / "configs" / "tiny.toml"), "--no-progress", "--out", str(out)]
    for s in sets:
        args += ["--set", s]
    res = CliRunner().invoke(app, args)
    assert res.exit_code == 2, res.output
    assert words in res.output and "Traceback" not in res.output
    if "MiB" in words:
        assert "raise tracing.memory_budget_mb" in res.output
    assert not out.exists()


def test_duplicate_tag_ids_are_found_in_linear_time():
    """100,000 tags with one id twice: named at once (a per-id ``list.count`` took
    minutes), and a repeated id is named, not merged."""
    import time

    from scenes.spec import SceneSpec, TagSpec
    from scenes.spec_toml import check_spec

    tags = tuple(TagSpec(id=f"T{i}", position_m=(float(i % 50), 1.0, 1.0), normal=(0.0, -1.0, 0.0))
                 for i in range(100_000))
    spec = SceneSpec(name="many", tags=tags + (tags[7],))
    t0 = time.perf_counter()
    with pytest.raises(Exception, match=r"duplicate tag ids \['T7'\]"):
        check_spec(spec, "many.toml")
    assert time.perf_counter() - t0 < 5.0  # linear: ~0.1 s; the quadratic check: minutes


def test_a_scene_length_beyond_any_site_is_refused_by_name():
    """``length_m = 1e300`` (and a coordinate likewise) overflowed every extent computed
    from it; it stops at the scene file, naming the key and the bound."""
    from scenes.spec import SpecError
    from scenes.spec_toml import spec_from_dict

    with pytest.raises(SpecError, match=r"key 'length_m': 1e\+300 is beyond .*MAX_EXTENT_M"):
        spec_from_dict({"name": "x", "corridor": {"length_m": 1e300, "width_m": 2.0}}, "x.toml")
    with pytest.raises(SpecError, match=r"key 'position_m'"):
        spec_from_dict({"name": "x", "corridor": {"length_m": 10.0, "width_m": 2.0},
                        "tag": [{"id": "T1", "position_m": [1e9, 1.0, 1.0],
                                 "normal": [0.0, 1.0, 0.0]}]}, "x.toml")
