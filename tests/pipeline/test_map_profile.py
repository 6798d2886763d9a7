"""`rfidstudy run MAP.yaml`: a map given alone runs with the map-scale profile; --set wins."""

from __future__ import annotations

import tomllib
from importlib.resources import files

from pipeline.apps.cli import resolve_target
from pipeline.apps.profiles import map_scale_profile
from tests.conftest import ROOT

WAREHOUSE = ROOT / "data" / "real_maps" / "nav2_warehouse" / "warehouse.yaml"


def test_a_bare_map_takes_the_map_scale_profile():
    cfg = resolve_target(str(WAREHOUSE))
    profile = map_scale_profile()
    assert cfg.scene == str(WAREHOUSE.resolve())
    assert cfg.tracing.max_depth == profile["tracing"]["max_depth"] == 2
    assert cfg.tracing.completion_min_area_m2 == 0.1 and cfg.tour.n_passes == 1
    # the user's key wins over the profile's
    cfg = resolve_target(str(WAREHOUSE), ["tracing.max_depth=3", "training.epochs=50"])
    assert cfg.tracing.max_depth == 3 and cfg.training.epochs == 50
    assert cfg.tracing.samples_per_src == 2000  # the rest of the profile stays


def test_the_profile_is_the_bundled_scale_case_and_ships_with_the_package():
    """The profile is configs/warehouse_large.toml's study settings (the measured 30 x 50 m
    case), less its scene, seed and evaluation-pose count (tour.eval_max_spacing_m decides),
    plus a cap on the completion's planes that warehouse_large (115 planes) is under."""
    text = files("pipeline.apps.profiles").joinpath("map_scale.toml").read_text("utf-8")
    profile = tomllib.loads(text)
    large = tomllib.loads((ROOT / "configs" / "warehouse_large.toml").read_text())
    for section, keys in profile.items():
        for key, value in keys.items():
            if (section, key) == ("tracing", "completion_max_planes"):
                assert value >= 115  # binds on real maps' jagged walls, not on warehouse_large
                continue
            assert large[section][key] == value, (section, key)
    # a scene TOML or a bundled scene is not a bare map: the default study
    assert resolve_target("warehouse_small").tracing.max_depth == 5
