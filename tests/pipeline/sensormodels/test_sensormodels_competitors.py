import json
import re

import numpy as np
import pytest

from pipeline.evaluation.cells import CellGrid
from pipeline.evaluation.interface import SensorLike, check_sensor
from pipeline.sensormodels import (
    COMPETITORS,
    MODEL_CLASSES,
    Joho2009Model,
    fit_competitors,
    load_competitor,
)

METHODS = ("fs", "fs_dbm", "fT", "rho")


@pytest.fixture(scope="module")
def models(synth):
    reads = synth.as_reads(*synth.sample(60_000, seed=12))
    return fit_competitors(reads, synth.RSSI_RANGE, d_max_m=3.0,
                           grid=CellGrid(3.0, 0.25, 15.0), rng=np.random.default_rng(0), dz_m=0.0)


@pytest.fixture(scope="module")
def saved(models, tmp_path_factory):
    root = tmp_path_factory.mktemp("models")
    return {name: m.save(root / f"{name}.json") for name, m in models.items()}


def test_fit_competitors_gives_the_three_sensor_like_models(models, synth):
    assert tuple(models) == COMPETITORS
    for name, m in models.items():
        assert isinstance(m, MODEL_CLASSES[name]) and isinstance(m, SensorLike)
        assert check_sensor(m, name) is m
        assert m.rssi_range_dbm == synth.RSSI_RANGE
        # all three see the cone: likely inside at 1 m, unlikely behind the antenna
        assert m.fT(1.0, 0.0) > 0.5 > 0.15 > m.fT(1.0, np.pi)


def test_pose_selects_the_geometry_columns(synth):
    reads = synth.as_reads(*synth.sample(20_000, seed=13))
    reads["alpha_true_rad"] = reads["alpha_est_rad"] + np.pi  # true poses face the other way
    est = fit_competitors(reads, synth.RSSI_RANGE, d_max_m=3.0, rng=np.random.default_rng(0),
                          dz_m=0.0)
    true = fit_competitors(reads, synth.RSSI_RANGE, d_max_m=3.0, rng=np.random.default_rng(0),
                           pose="true", dz_m=0.0)
    for name in COMPETITORS:
        assert est[name].fT(1.0, 0.0) > 0.5 and true[name].fT(1.0, np.pi) > 0.5
    with pytest.raises(ValueError, match="rng"):
        fit_competitors(reads, synth.RSSI_RANGE, d_max_m=3.0)
    with pytest.raises(ValueError, match="missing column"):
        fit_competitors(reads.drop(columns="rssi_dbm"), synth.RSSI_RANGE, d_max_m=3.0,
                        rng=np.random.default_rng(0), dz_m=0.0)
    with pytest.raises(ValueError, match="tag heights"):  # never a silent in-plane tag
        fit_competitors(reads, synth.RSSI_RANGE, d_max_m=3.0, rng=np.random.default_rng(0))


@pytest.mark.parametrize("name", COMPETITORS)
def test_shapes_broadcast(models, name):
    m = models[name]
    d = np.linspace(0.05, 3.5, 11)
    a = np.linspace(-np.pi, np.pi, 11)
    for meth in METHODS:
        f = getattr(m, meth)
        flat = f(d, a)
        assert flat.shape == (11,)
        grid = f(d[:, None], a[None, :4])  # (n, 1) with (1, k) -> (n, k)
        assert grid.shape == (11, 4)
        for j in range(4):  # each column is the flat evaluation at that bearing
            np.testing.assert_array_equal(grid[:, j], f(d, np.full(11, a[j])))
        assert f(d[:, None], a[3]).shape == (11, 1)
        assert np.ndim(f(1.0, 0.2)) == 0
        assert np.isnan(f(np.nan, 0.0)) and np.isnan(f(1.0, np.nan))
    # bearings are wrapped: alpha and alpha + 2 pi are the same direction
    np.testing.assert_array_equal(m.fT(d, a[::-1] * 0.9 + 2 * np.pi), m.fT(d, a[::-1] * 0.9))
    np.testing.assert_array_equal(m.rho(d, a), m.fs(d, a) * m.fT(d, a))
    assert np.all((m.fT(d, a) >= 0) & (m.fT(d, a) <= 1))
    assert np.all((m.fs(d, a) >= 0) & (m.fs(d, a) <= 1))


@pytest.mark.parametrize("name", COMPETITORS)
def test_load_competitor_dispatches_on_kind(models, saved, name):
    back = load_competitor(saved[name])
    assert type(back) is type(models[name])
    rng = np.random.default_rng(2)
    d, a = rng.uniform(0, 4, 500), rng.uniform(-4, 4, 500)
    for meth in METHODS:  # identical, NaN where both are NaN (fs_dbm of Vorst)
        np.testing.assert_array_equal(getattr(back, meth)(d, a), getattr(models[name], meth)(d, a))
    assert back.to_dict() == json.loads(saved[name].read_text())


@pytest.mark.parametrize("have", COMPETITORS)
@pytest.mark.parametrize("want", COMPETITORS)
def test_loading_another_kind_names_file_and_both_kinds(saved, have, want):
    if have == want:
        return
    with pytest.raises(ValueError) as exc:
        MODEL_CLASSES[want].load(saved[have])
    msg = str(exc.value)
    assert str(saved[have]) in msg and repr(have) in msg and repr(want) in msg


def test_files_that_are_no_competitor(saved, tmp_path, models):
    # another project file (a SensorModel or the baselines) has no "kind"
    other = tmp_path / "sensor.json"
    other.write_text(json.dumps({"format": "rfidstudy.fuzzymodel.sensor/1", "ssm": {}}))
    for fn in (load_competitor, Joho2009Model.load):
        with pytest.raises(ValueError, match=re.escape(str(other)) + ".*no 'kind'.*fuzzymodel"):
            fn(other)
    bad = tmp_path / "bad.json"
    bad.write_text(json.dumps({**json.loads(saved["liu2006"].read_text()), "kind": "hahnel2004"}))
    with pytest.raises(ValueError, match="unknown sensor model kind 'hahnel2004'"):
        load_competitor(bad)
    broken = tmp_path / "broken.json"
    broken.write_text("{")
    with pytest.raises(ValueError, match="not valid JSON"):
        load_competitor(broken)
    with pytest.raises(FileNotFoundError, match="does not exist"):
        load_competitor(tmp_path / "absent.json")
    extra = tmp_path / "extra.json"
    d = json.loads(saved["liu2006"].read_text())
    d["params"]["colour"] = "red"
    extra.write_text(json.dumps(d))
    with pytest.raises(ValueError, match="colour"):
        load_competitor(extra)
