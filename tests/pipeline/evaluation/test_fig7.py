import json

import numpy as np
import pandas as pd
import pytest

from pipeline.evaluation import (
    FIG7_COLUMNS,
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


def test_fig7_chapter_error_by_hand_on_two_poses(tmp_path):
    # constant model: fs = (-55 + 80) / 50 = 0.5 everywhere, so the 10 cm average is 0.5
    sensor = _sensor(-55.0)
    reads = _reads([
        {"time_s": 0.00, "tag_id": "A", "rssi_dbm": -60.0},  # fs 0.40
        {"time_s": 0.05, "tag_id": "A", "rssi_dbm": -62.0},  # fs 0.36
        {"time_s": 0.12, "tag_id": "A", "rssi_dbm": -50.0},  # fs 0.60
        {"time_s": 0.13, "tag_id": "B", "rssi_dbm": -70.0, "read": False},  # not a read
    ])
    r = fig7_errors(reads, TAGS, sensor, radius_m=0.1, pose_times_s=[0.0, 0.1], d_max_m=3.0)
    t = r.table
    assert tuple(t.columns) == FIG7_COLUMNS
    assert t["pose"].tolist() == [0, 1]
    assert t["n_reads"].tolist() == [2, 1]
    np.testing.assert_allclose(t["fs_meas"], [0.38, 0.60], atol=1e-12)
    np.testing.assert_allclose(t["fs_model"], [0.5, 0.5], atol=1e-12)
    # chapter Sec. 5: Error = |fs_bar - s| x 100
    np.testing.assert_allclose(t["error_pct"], [12.0, 10.0], rtol=1e-12)
    # the relative error is kept apart: |fs_bar - s| / s x 100
    np.testing.assert_allclose(t["rel_error_pct"], [12.0 / 0.38, 10.0 / 0.6], rtol=1e-12)
    assert t["in_domain"].tolist() == [True, True]
    assert r.summary.mean == pytest.approx(11.0, rel=1e-12)
    assert r.summary.median == pytest.approx(11.0, rel=1e-12)
    d = r.to_dict()
    assert d["median_pct"] == pytest.approx(11.0) and d["mean_pct"] == pytest.approx(11.0)
    assert d["share_below_20pct"] == 1.0 and d["n_groups"] == 2
    assert d["per_antenna"]["0"]["n_groups"] == 2
    assert d["beyond_training_domain"]["n_groups"] == 0
    assert d["rel_error_median_pct"] == pytest.approx((12.0 / 0.38 + 10.0 / 0.6) / 2)
    json.dumps(d, allow_nan=False)
    r.write_table(tmp_path / "truth" / "fig7_errors.parquet")
    back = read_fig7_table(tmp_path / "truth" / "fig7_errors.parquet")
    np.testing.assert_allclose(back["error_pct"], t["error_pct"])


def test_fig7_relative_and_chapter_metrics_differ_where_the_measurement_is_weak():
    # model 0.5 everywhere; s = 0.2 (weak read) and s = 0.95 (strong read)
    sensor = _sensor(-55.0)
    reads = _reads([
        {"time_s": 0.0, "tag_id": "A", "rssi_dbm": -70.0},  # s = 0.20
        {"time_s": 1.0, "tag_id": "A", "rssi_dbm": -32.5},  # s = 0.95
    ])
    r = fig7_errors(reads, TAGS, sensor, radius_m=0.0, pose_times_s=[0.0, 0.5])
    t = r.table
    # chapter: 30 % and 45 %: the strong read is the worse one
    np.testing.assert_allclose(t["error_pct"], [30.0, 45.0], rtol=1e-12)
    # relative: 150 % and 47.4 %: the ranking flips, the weak read dominates
    np.testing.assert_allclose(t["rel_error_pct"], [150.0, 45.0 / 0.95], rtol=1e-12)
    assert np.argmax(t["error_pct"]) == 1 and np.argmax(t["rel_error_pct"]) == 0
    d = r.to_dict()
    assert d["median_pct"] == pytest.approx(37.5)
    assert d["rel_error_median_pct"] == pytest.approx((150.0 + 45.0 / 0.95) / 2)


def test_fig7_summary_recomputed_from_the_saved_table(tmp_path):
    # d-dependent model and readings over several poses and both tags, some beyond 3 m
    sensor = _sensor(-40.0, n=2.0)
    rng = np.random.default_rng(3)
    rows = []
    for k in range(30):
        x = -3.0 + 0.2 * k  # antenna moves along x: tag A at 2 m, so d_A from 5 m to 0.2 m
        for tag in ("A", "B"):
            for j in range(2):
                rows.append({"time_s": k + 0.1 * j, "tag_id": tag, "est_ant_x_m": x,
                             "rssi_dbm": float(rng.uniform(-80.0, -35.0)), "antenna": k % 2})
    r = fig7_errors(_reads(rows), TAGS, sensor, radius_m=0.1, pose_times_s=np.arange(30.0),
                    d_max_m=3.0, min_fs_meas=0.02)
    path = r.write_table(tmp_path / "fig7_errors.parquet")
    t = read_fig7_table(path)
    # independent recomputation from the stored fs_meas / fs_model
    err = np.abs(t["fs_model"].to_numpy() - t["fs_meas"].to_numpy()) * 100.0
    np.testing.assert_allclose(t["error_pct"], err, rtol=0, atol=1e-12)
    ins = t["d_est_m"].to_numpy() <= 3.0
    np.testing.assert_array_equal(t["in_domain"].to_numpy(bool), ins)
    assert 0 < ins.sum() < len(t)  # both sides of the split are populated
    d = r.to_dict()
    assert d["n_groups"] == ins.sum() and d["n_groups_total"] == len(t)
    assert d["median_pct"] == pytest.approx(np.median(err[ins]), rel=1e-12)
    assert d["mean_pct"] == pytest.approx(np.mean(err[ins]), rel=1e-12)
    assert d["p90_pct"] == pytest.approx(np.percentile(err[ins], 90), rel=1e-12)
    assert d["share_below_20pct"] == pytest.approx(np.mean(err[ins] < 20.0))
    out = d["beyond_training_domain"]
    assert out["n_groups"] == (~ins).sum()
    assert out["median_pct"] == pytest.approx(np.median(err[~ins]), rel=1e-12)
    assert out["share_below_20pct"] == pytest.approx(np.mean(err[~ins] < 20.0))
    meas = t["fs_meas"].to_numpy()
    rel = np.where(meas < 0.02, np.nan, err / meas)
    np.testing.assert_allclose(t["rel_error_pct"], rel, rtol=1e-12, equal_nan=True)
    assert d["rel_error_median_pct"] == pytest.approx(np.nanmedian(rel[ins]), rel=1e-12)
    # per pose / per antenna are of the in-domain groups
    assert set(r.per_pose["pose"]) == set(t.loc[ins, "pose"])
    for a, s in d["per_antenna"].items():
        sel = ins & (t["antenna"].astype(str).to_numpy() == a)
        assert s["median_pct"] == pytest.approx(np.median(err[sel]), rel=1e-12)
    # without a training domain every group is in it
    r_all = fig7_errors(_reads(rows), TAGS, sensor, radius_m=0.1, pose_times_s=np.arange(30.0))
    assert r_all.table["in_domain"].all() and r_all.to_dict()["d_max_m"] is None


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


def test_fig7_tiny_measurement_counts_for_chapter_metric_only_and_errors_are_named():
    sensor = _sensor(-55.0)
    reads = _reads([{"time_s": 0.0, "tag_id": "A", "rssi_dbm": -80.0}])  # fs_meas = 0
    r = fig7_errors(reads, TAGS, sensor)
    assert r.summary.n == 1 and r.table["error_pct"].iloc[0] == pytest.approx(50.0)
    assert np.isnan(r.table["rel_error_pct"].iloc[0]) and r.n_rel_excluded == 1
    assert r.to_dict()["rel_error_median_pct"] is None
    with pytest.raises(ValueError, match="tag_id.*'Z'"):
        fig7_errors(_reads([{"time_s": 0.0, "tag_id": "Z", "rssi_dbm": -50.0}]), TAGS, sensor)
    with pytest.raises(ValueError, match="missing column.*est_ant_yaw_rad"):
        fig7_errors(reads.drop(columns="est_ant_yaw_rad"), TAGS, sensor)
    with pytest.raises(ValueError, match="d_max_m"):
        fig7_errors(reads, TAGS, sensor, d_max_m=0.0)


def test_fig7_no_reads_gives_empty_table_and_json_able_summary():
    sensor = _sensor(-55.0)
    reads = _reads([{"time_s": 0.0, "tag_id": "A", "rssi_dbm": -50.0, "read": False}])
    r = fig7_errors(reads, TAGS, sensor, d_max_m=3.0)
    assert tuple(r.table.columns) == FIG7_COLUMNS and len(r.table) == 0
    d = r.to_dict()
    assert d["n_groups"] == 0 and d["median_pct"] is None
    json.dumps(d, allow_nan=False)
