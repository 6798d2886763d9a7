import numpy as np
import pandas as pd
import pytest

from pipeline.evaluation import (
    BaselineSensorModel,
    CellGrid,
    LogDistanceModel,
    fig7_errors,
    fit_grid_count,
    read_fig7_table,
    tags_table,
)

RANGE = (-80.0, -30.0)


def _sensor(p0_dbm, n=0.0):
    gc = fit_grid_count([1.0], [0.0], [True], grid=CellGrid(3.0, 1.0, 90.0))
    return BaselineSensorModel(LogDistanceModel(p0_dbm=p0_dbm, n=n), gc, RANGE)


def _reads(rows):
    base = {"cycle": 0, "antenna": 0, "read": True,
            "est_ant_x_m": 0.0, "est_ant_y_m": 0.0, "est_ant_z_m": 1.0, "est_ant_yaw_rad": 0.0}
    return pd.DataFrame([{**base, **r} for r in rows])


TAGS = tags_table(["A", "B"], [[2.0, 0.0, 1.0], [0.0, 1.5, 1.0]])


def test_fig7_percentage_error_by_hand_on_two_poses(tmp_path):
    # constant model: fs = (-55 + 80) / 50 = 0.5 everywhere, so the 10 cm average is 0.5
    sensor = _sensor(-55.0)
    reads = _reads([
        {"time_s": 0.00, "tag_id": "A", "rssi_dbm": -60.0},  # fs 0.40
        {"time_s": 0.05, "tag_id": "A", "rssi_dbm": -62.0},  # fs 0.36
        {"time_s": 0.12, "tag_id": "A", "rssi_dbm": -50.0},  # fs 0.60
        {"time_s": 0.13, "tag_id": "B", "rssi_dbm": -70.0, "read": False},  # not a read
    ])
    r = fig7_errors(reads, TAGS, sensor, radius_m=0.1, pose_times_s=[0.0, 0.1])
    t = r.table
    assert t["pose"].tolist() == [0, 1]
    assert t["n_reads"].tolist() == [2, 1]
    np.testing.assert_allclose(t["fs_meas"], [0.38, 0.60], atol=1e-12)
    np.testing.assert_allclose(t["fs_model"], [0.5, 0.5], atol=1e-12)
    e0 = abs(0.5 - 0.38) / 0.38 * 100  # 31.58 %
    e1 = abs(0.5 - 0.60) / 0.60 * 100  # 16.67 %
    np.testing.assert_allclose(t["pct_error"], [e0, e1], rtol=1e-12)
    assert r.summary.mean == pytest.approx((e0 + e1) / 2, rel=1e-12)
    assert r.summary.median == pytest.approx((e0 + e1) / 2, rel=1e-12)
    d = r.to_dict()
    assert d["fraction_below_20pct"] == 0.5
    assert d["pct_error_per_antenna"]["0"]["n"] == 2
    r.write_table(tmp_path / "truth" / "fig7_errors.parquet")
    back = read_fig7_table(tmp_path / "truth" / "fig7_errors.parquet")
    np.testing.assert_allclose(back["pct_error"], t["pct_error"])


def test_fig7_uses_estimated_antenna_frame():
    # fs depends on d: -40 - 20 log10(d); radius 0 evaluates at the tag centre
    sensor = _sensor(-40.0, n=2.0)
    reads = _reads([{"time_s": 0.0, "tag_id": "A", "rssi_dbm": -50.0,
                     "true_ant_x_m": 1.5}])  # true pose must not matter
    r = fig7_errors(reads, TAGS, sensor, radius_m=0.0)
    fs_model = (-40.0 - 20 * np.log10(2.0) + 80.0) / 50.0  # d_est = 2 m
    assert r.table["fs_model"].iloc[0] == pytest.approx(fs_model, rel=1e-12)
    assert r.table["d_est_m"].iloc[0] == pytest.approx(2.0)
    # moving the estimated antenna 1 m closer changes the model's value to d = 1 m
    r2 = fig7_errors(reads.assign(est_ant_x_m=1.0), TAGS, sensor, radius_m=0.0)
    assert r2.table["fs_model"].iloc[0] == pytest.approx((-40.0 + 80.0) / 50.0, rel=1e-12)
    # with a 10 cm disc the average stays within the model's range over the disc
    r3 = fig7_errors(reads, TAGS, sensor, radius_m=0.1)
    lo = (-40.0 - 20 * np.log10(2.1) + 80.0) / 50.0
    hi = (-40.0 - 20 * np.log10(1.9) + 80.0) / 50.0
    assert lo < r3.table["fs_model"].iloc[0] < hi


def test_fig7_excludes_tiny_measurements_and_names_unknown_tags():
    sensor = _sensor(-55.0)
    reads = _reads([{"time_s": 0.0, "tag_id": "A", "rssi_dbm": -80.0}])  # fs_meas = 0
    r = fig7_errors(reads, TAGS, sensor)
    assert r.n_excluded == 1 and r.summary.n == 0 and np.isnan(r.table["pct_error"].iloc[0])
    with pytest.raises(ValueError, match="tag_id.*'Z'"):
        fig7_errors(_reads([{"time_s": 0.0, "tag_id": "Z", "rssi_dbm": -50.0}]), TAGS, sensor)
    with pytest.raises(ValueError, match="missing column.*est_ant_yaw_rad"):
        fig7_errors(reads.drop(columns="est_ant_yaw_rad"), TAGS, sensor)
