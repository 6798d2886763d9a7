"""ReadLog Parquet files: contract columns, round trip, atomic writes, track interpolation."""

import numpy as np
import pandas as pd
import pytest

from pipeline.acquisition import (
    POSE_COLUMNS,
    READ_COLUMNS,
    PoseTrack,
    ReadLog,
    as_pose_track,
    interpolate_poses,
)

CONTRACT_READ_COLUMNS = (
    "time_s cycle antenna tag_id read rssi_dbm true_ant_x_m true_ant_y_m true_ant_z_m "
    "true_ant_yaw_rad est_ant_x_m est_ant_y_m est_ant_z_m est_ant_yaw_rad d_true_m "
    "alpha_true_rad d_est_m alpha_est_rad gain_db tag_power_dbm powered in_range"
).split()
CONTRACT_POSE_COLUMNS = (
    "time_s true_x_m true_y_m true_theta_rad odom_x_m odom_y_m odom_theta_rad "
    "est_x_m est_y_m est_theta_rad"
).split()


def _log(n=6):
    rng = np.random.default_rng(3)
    reads = pd.DataFrame({c: np.zeros(n) for c in READ_COLUMNS})
    reads["read"] = rng.random(n) < 0.5
    reads["rssi_dbm"] = np.where(reads["read"], -50.5, np.nan)
    reads["tag_id"] = pd.Categorical(["t0", "t1"] * (n // 2), categories=["t0", "t1"])
    reads["gain_db"] = -np.inf
    reads = reads.astype(READ_COLUMNS)
    poses = pd.DataFrame({c: rng.random(4) for c in POSE_COLUMNS}).astype(POSE_COLUMNS)
    return ReadLog(reads, poses, {"scene": "x", "n_pairs_traced": 0})


def test_contract_columns_present():
    assert set(CONTRACT_READ_COLUMNS) <= set(READ_COLUMNS)
    assert list(POSE_COLUMNS) == CONTRACT_POSE_COLUMNS


def test_roundtrip_and_no_temp_files(tmp_path):
    log = _log()
    log.write(tmp_path)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["poses.parquet", "reads.parquet"]
    back = ReadLog.read(tmp_path)
    pd.testing.assert_frame_equal(back.reads, log.reads)
    pd.testing.assert_frame_equal(back.poses, log.poses)
    assert back.metadata == log.metadata
    log.write(tmp_path, prefix="eval_")
    assert (tmp_path / "eval_reads.parquet").is_file()


def test_missing_column_and_file_named(tmp_path):
    log = _log()
    with pytest.raises(ValueError, match="in_range"):
        ReadLog(log.reads.drop(columns=["in_range"]), log.poses)
    with pytest.raises(FileNotFoundError, match="reads.parquet"):
        ReadLog.read(tmp_path)


def test_interpolate_poses_heading_shortest_arc():
    t = np.array([0.0, 1.0])
    poses = np.array([[0.0, 0.0, np.deg2rad(170)], [2.0, 1.0, np.deg2rad(-170)]])
    q = interpolate_poses(t, poses, np.array([0.5]))
    # Halfway from +170 deg to -170 deg across the +-180 seam is 180 deg, not 0 deg.
    np.testing.assert_allclose(q[0, :2], [1.0, 0.5])
    np.testing.assert_allclose(abs(q[0, 2]), np.pi, atol=1e-12)


def test_as_pose_track_tuple_and_errors():
    true = np.zeros((3, 3))
    tr = as_pose_track((true, true + 0.1, np.arange(3.0)))
    assert isinstance(tr, PoseTrack) and np.all(np.isnan(tr.odom_poses))
    with pytest.raises(ValueError, match="strictly increasing"):
        PoseTrack(np.array([0.0, 0.0, 1.0]), true, true, true)
    with pytest.raises(ValueError, match="est_poses"):
        PoseTrack(np.arange(3.0), true, np.zeros((2, 3)), true)
    with pytest.raises(TypeError, match="t_s"):
        as_pose_track(object())


def test_as_pose_track_from_robot_results():
    from pipeline.robot.mcl import LocalizationResult
    from pipeline.robot.trajectory import Trajectory

    t = np.arange(4.0)
    true = np.column_stack([t, np.ones(4), np.zeros(4)])
    traj = Trajectory.from_poses(t, true)
    tr = as_pose_track(traj)
    np.testing.assert_array_equal(tr.est_poses, true)  # no localisation: est = true
    fields = dict.fromkeys(LocalizationResult.__dataclass_fields__)
    fields.update(
        t_s=t,
        true_poses=true,
        odometry_poses=true + 0.2,
        estimated_poses=true + 0.1,
        n_updates=0,
        n_resamples=0,
        n_injected=0,
    )
    res = LocalizationResult(**fields)
    tr = as_pose_track(res)
    np.testing.assert_allclose(tr.est_poses - tr.true_poses, 0.1)
    np.testing.assert_allclose(tr.odom_poses - tr.true_poses, 0.2)
