"""Bad input raises ValueErrors that name the offending id, table or argument."""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest

from pipeline.acquisition.readlog import READ_COLUMNS
from pipeline.localisation import (
    ModelLikelihood,
    Observations,
    OracleLikelihood,
    localise_tags,
    observations_from_reads,
    run_rfid_mcl,
    tag_position_errors,
)
from pipeline.robot.kinematics import default_antennas
from propagation import LinkBudget


def _obs(n_slots: int = 6) -> Observations:
    t = np.arange(n_slots) * 0.25
    poses = np.column_stack([0.5 + 0.1 * np.arange(n_slots), np.ones(n_slots), np.full(n_slots, 0.7),
                             np.zeros(n_slots)])
    read = np.zeros((2, n_slots), dtype=bool)
    read[0, 2] = True
    rssi = np.where(read, -60.0, np.nan)
    return Observations(("E01", "E02"), t, np.arange(n_slots) % 2, poses, read, rssi,
                        np.ones(read.shape, dtype=bool))


def _robot_args(obs):
    odo = np.column_stack([0.3 + 0.1 * np.arange(obs.n_slots), np.ones(obs.n_slots),
                           np.zeros(obs.n_slots)])
    return odo, obs.slot_time_s, default_antennas(), [[0, 0, 5, 2]]


def test_robot_filter_tag_map_with_unknown_id(sensor):
    obs = _obs()
    tag_map = {"E01": (1.0, 0.0, 1.0), "X99": (2.0, 0.0, 1.0)}
    with pytest.raises(ValueError, match="X99"):
        run_rfid_mcl(ModelLikelihood(sensor), obs, tag_map, *_robot_args(obs),
                     np.random.default_rng(0))


def test_robot_filter_odometry_must_cover_the_slots(sensor):
    obs = _obs()
    odo, t, mounts, free = _robot_args(obs)
    with pytest.raises(ValueError, match="odometry"):
        run_rfid_mcl(ModelLikelihood(sensor), obs, {"E01": (1, 0, 1)}, odo[:3], t[:3], mounts,
                     free, np.random.default_rng(0))


def test_truth_map_ids_must_match_the_posteriors(sensor):
    obs = _obs()
    cand = np.array([[1.0, 0.0, 1.0], [2.0, 0.0, 1.0]])
    post = localise_tags(obs, cand, {"m": ModelLikelihood(sensor)})["m"]
    with pytest.raises(ValueError, match="E02"):  # no true position for E02
        tag_position_errors(post, {"E01": (1.0, 0.0, 1.0)})
    with pytest.raises(ValueError, match="E77"):  # a map id the log does not know
        tag_position_errors(post, {"E01": (1, 0, 1), "E02": (2, 0, 1), "E77": (3, 0, 1)})


def test_empty_read_log_names_the_table():
    empty = pd.DataFrame({c: pd.Series(dtype=t) for c, t in READ_COLUMNS.items()})
    with pytest.raises(ValueError, match="eval_reads.*empty"):
        observations_from_reads(empty)
    with pytest.raises(ValueError, match="my_reads.*missing column.*est_ant_yaw_rad"):
        observations_from_reads(empty.drop(columns=["est_ant_yaw_rad"]), table="my_reads")


def test_requested_tag_not_in_log_is_named():
    df = pd.DataFrame({"time_s": [0.0], "cycle": [0], "antenna": [0], "tag_id": ["E01"],
                       "read": [True], "rssi_dbm": [-60.0], "est_ant_x_m": [0.0],
                       "est_ant_y_m": [0.0], "est_ant_z_m": [0.7], "est_ant_yaw_rad": [0.0]})
    with pytest.raises(ValueError, match="E05"):
        observations_from_reads(df, tag_ids=["E01", "E05"])
    with pytest.raises(ValueError, match="E05"):
        _obs().select(["E05"])


def test_bad_candidates_gains_and_priors(sensor):
    obs = _obs()
    cand = np.array([[1.0, 0.0, 1.0], [2.0, 0.0, 1.0]])
    lk = ModelLikelihood(sensor)
    with pytest.raises(ValueError, match="candidates"):
        localise_tags(obs, cand[:, :2], {"m": lk})
    orc = OracleLikelihood(LinkBudget(), miss_probability=0.05, rssi_noise_db=1.0)
    with pytest.raises(ValueError, match="oracle gains have shape"):
        localise_tags(obs, cand, {"o": orc.with_gains(np.zeros((obs.n_slots, 3)))})
    with pytest.raises(ValueError, match="NaN"):
        orc.with_gains(np.full((obs.n_slots, 2), np.nan))
    with pytest.raises(ValueError, match="excludes every candidate"):
        localise_tags(obs, cand, {"m": lk}, log_prior=np.full(2, -np.inf))
    with pytest.raises(ValueError, match="ModelLikelihood or OracleGains"):
        localise_tags(obs, cand, {"m": sensor})


def test_observation_shapes_are_checked():
    with pytest.raises(ValueError, match="tags x slots"):
        Observations(("a",), [0.0, 1.0], [0, 1], np.zeros((2, 4)), np.zeros((1, 3), bool),
                     np.zeros((1, 2)), np.ones((1, 2), bool))
    with pytest.raises(ValueError, match="did not attempt"):
        Observations(("a",), [0.0], [0], np.zeros((1, 4)), [[True]], [[-60.0]], [[False]])
