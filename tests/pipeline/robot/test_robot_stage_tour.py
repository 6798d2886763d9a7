"""stage_tour draws the robot's map once and both tours localise in it; lost track fails;
the two tours driven side by side (forked) give the files of one after the other."""

import json
from types import SimpleNamespace

import numpy as np
import pytest

import pipeline.robot as robot_pkg
import pipeline.stages.tour as tour_stage
import scenes
from pipeline.config import config_from_mapping
from pipeline.parallel import WORKERS_ENV, fork_workers
from pipeline.stages.tour import stage_tour

KEYS = {"position_error_median_m", "position_error_p90_m", "heading_error_median_deg",
        "mean_offset_along_m", "mean_offset_lateral_m", "mean_offset_x_m", "mean_offset_y_m",
        "n_poses"}


@pytest.fixture(scope="module")
def corridor_lab():
    return scenes.load("corridor_lab")


def _ctx(tmp_path, scene, **loc):
    cfg = config_from_mapping({
        "scene": "corridor_lab", "seed": 7,
        "tour": {"n_passes": 1, "lane_fractions": [0.0], "lane_changes_per_pass": 0,
                 "stops_per_pass": 0, "max_length_m": 5.0, "n_eval_poses": 20, "dt_s": 0.2},
        "localisation": {"n_particles": 100, **loc},
    })

    def out(rel):
        p = tmp_path / rel
        p.parent.mkdir(parents=True, exist_ok=True)
        return p

    # the scene is preloaded: stage_tour reads it through load_scene's memo
    return SimpleNamespace(config=cfg, memo={"scene": scene}, out=out,
                           progress=lambda *a, **k: (lambda *a, **k: None))


def test_one_map_for_both_tours(tmp_path, corridor_lab, monkeypatch):
    drawn, used = [], []
    real_draw, real_sim = robot_pkg.draw_robot_map, robot_pkg.simulate_localisation

    def draw(*a, **k):
        drawn.append(real_draw(*a, **k))
        return drawn[-1]

    def sim(*a, occupancy_map=None, **k):
        used.append(occupancy_map)
        return real_sim(*a, occupancy_map=occupancy_map, **k)

    # the stage's own names (it imports them at module level)
    monkeypatch.setattr(tour_stage, "draw_robot_map", draw)
    monkeypatch.setattr(tour_stage, "simulate_localisation", sim)
    monkeypatch.setenv(WORKERS_ENV, "1")  # the spies see this process only: no fork
    info = stage_tour(_ctx(tmp_path, corridor_lab, map_error_m=0.05))
    assert len(drawn) == 1 and len(used) == 2
    assert used[0] is drawn[0].occupancy_map and used[1] is drawn[0].occupancy_map
    with np.load(tmp_path / "tour/map_error.npz") as z:
        np.testing.assert_array_equal(z["offsets_m"], drawn[0].error.offsets_m)
        assert z["segments"].shape == (len(z["offsets_m"]), 2, 2) and float(z["scale"]) == 0.0
    assert np.std(drawn[0].error.offsets_m) > 0.01  # the walls really are off
    loc = json.loads((tmp_path / "tour/localisation.json").read_text())
    assert set(loc) == {"train", "eval"}
    for name in ("train", "eval"):
        assert set(loc[name]) == KEYS
        assert KEYS <= set(info[name])
        assert info[name]["position_error_median_m"] == loc[name]["position_error_median_m"]
        assert loc[name]["position_error_median_m"] < 0.5
    assert (tmp_path / "tour/train_track.npz").is_file()
    # the same study draws the same map: the map stream is seeded by (seed, "map") alone
    stage_tour(_ctx(tmp_path / "again", corridor_lab, map_error_m=0.05))
    np.testing.assert_array_equal(drawn[1].error.offsets_m, drawn[0].error.offsets_m)


def test_lost_track_fails_the_stage_naming_the_keys(tmp_path, corridor_lab):
    # a limit no real filter meets stands in for a diverged MCL
    ctx = _ctx(tmp_path, corridor_lab, max_position_error_median_m=1e-6)
    with pytest.raises(ValueError) as exc:
        stage_tour(ctx)
    msg = str(exc.value)
    for part in ("train tour", "localisation.max_position_error_median_m = 1e-06 m",
                 "localisation.map_error_m = 0.05", "localisation.sigma_hit_m = 0.1"):
        assert part in msg
    assert not (tmp_path / "tour").exists()  # nothing written before the check


@pytest.mark.parallel
def test_tours_side_by_side_write_what_one_after_the_other_writes(tmp_path, corridor_lab,
                                                                   monkeypatch):
    monkeypatch.delenv(WORKERS_ENV, raising=False)
    if fork_workers(None, 2) < 2:
        pytest.skip("this process cannot fork two workers (one CPU, or threads running)")
    forked = stage_tour(_ctx(tmp_path / "forked", corridor_lab, map_error_m=0.05))
    monkeypatch.setenv(WORKERS_ENV, "1")
    serial = stage_tour(_ctx(tmp_path / "serial", corridor_lab, map_error_m=0.05))
    assert forked == serial
    files = sorted(p.relative_to(tmp_path / "serial") for p in (tmp_path / "serial").rglob("*")
                   if p.is_file())
    assert {str(f) for f in files} >= {"tour/train_track.npz", "tour/eval_track.npz",
                                       "tour/localisation.json", "tour/map_error.npz"}
    for f in files:  # each tour brings its own stream: the same bytes either way
        assert (tmp_path / "forked" / f).read_bytes() == (tmp_path / "serial" / f).read_bytes(), f
