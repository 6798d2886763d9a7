"""MCL error and bias summary per track, and the lost-track check."""

import numpy as np
import pandas as pd
import pytest

from pipeline.evaluation.localisation import (
    LocalisationSummary,
    check_tracking,
    localisation_errors,
    localisation_summary,
    pose_error_summary,
    pose_offsets,
)

KEYS = {"position_error_median_m", "position_error_p90_m", "heading_error_median_deg",
        "mean_offset_along_m", "mean_offset_lateral_m", "mean_offset_x_m", "mean_offset_y_m",
        "n_poses"}


def _up_and_back(n=100):
    x = np.linspace(0.0, 10.0, n)
    up = np.column_stack([x, np.full(n, 1.0), np.zeros(n)])
    back = np.column_stack([x[::-1], np.full(n, 1.4), np.full(n, np.pi)])
    return np.vstack([up, back])


def test_world_shift_is_lateral_with_opposite_signs_on_the_two_legs():
    true = _up_and_back()
    est = true + [0.0, 0.05, 0.0]  # the map's walls are 5 cm north: every pose 5 cm north
    off = pose_offsets(true, est)
    n = len(true) // 2
    np.testing.assert_allclose(off["lateral_m"][:n], 0.05, atol=1e-12)  # driving +x: to the left
    np.testing.assert_allclose(off["lateral_m"][n:], -0.05, atol=1e-12)  # driving -x: to the right
    np.testing.assert_allclose(off["along_m"], 0.0, atol=1e-12)
    s = pose_error_summary(true, est)
    assert s.mean_offset_y_m == pytest.approx(0.05)
    assert s.mean_offset_x_m == pytest.approx(0.0, abs=1e-12)
    assert s.mean_offset_lateral_m == pytest.approx(0.0, abs=1e-12)
    assert s.position_error_median_m == pytest.approx(0.05)
    assert s.n_poses == len(true)


def test_forward_offset_heading_error_and_percentiles():
    true = _up_and_back(50)
    th = true[:, 2]
    d = np.linspace(0.0, 0.2, len(true))  # est ahead of the truth by d along the heading
    est = true + np.column_stack([d * np.cos(th), d * np.sin(th), np.full(len(true), np.deg2rad(2))])
    s = pose_error_summary(true, est)
    assert s.mean_offset_along_m == pytest.approx(0.1)
    assert s.mean_offset_lateral_m == pytest.approx(0.0, abs=1e-12)
    assert s.position_error_median_m == pytest.approx(np.median(d))
    assert s.position_error_p90_m == pytest.approx(np.percentile(d, 90))
    assert s.heading_error_median_deg == pytest.approx(2.0)
    est[:, 2] = true[:, 2] - np.deg2rad(2) + 2 * np.pi  # wrapped, and negative
    assert pose_error_summary(true, est).heading_error_median_deg == pytest.approx(2.0)


def test_table_version_matches_and_dict_has_the_reported_keys():
    true = _up_and_back(30)
    est = true + np.random.default_rng(0).normal(0, 0.03, true.shape)
    df = pd.DataFrame({"time_s": np.arange(len(true)) * 0.1,
                       **{f"true_{c}": true[:, i] for i, c in enumerate(("x_m", "y_m", "theta_rad"))},
                       **{f"est_{c}": est[:, i] for i, c in enumerate(("x_m", "y_m", "theta_rad"))}})
    s = localisation_summary(df)
    assert s == pose_error_summary(true, est)
    d = s.to_dict()
    assert set(d) == KEYS and all(isinstance(v, (int, float)) for v in d.values())
    assert d["position_error_median_m"] == pytest.approx(
        localisation_errors(df).position_summary.median)
    empty = pose_error_summary(np.zeros((0, 3)), np.zeros((0, 3))).to_dict()
    assert empty["n_poses"] == 0 and empty["mean_offset_y_m"] is None
    with pytest.raises(ValueError, match="differ"):
        pose_offsets(np.zeros((3, 3)), np.zeros((2, 3)))


def test_check_tracking_names_the_limits_the_error_and_the_causes():
    ok = LocalisationSummary(100, 0.05, 0.1, 0.5, 0.0, 0.01, 0.0, 0.01)
    check_tracking(ok, 0.5, 1.0)  # tracking: no error
    lost = LocalisationSummary(100, 0.8, 2.5, 5.0, 0.3, 0.1, 0.3, 0.1)
    with pytest.raises(ValueError) as exc:
        check_tracking(lost, 0.5, 1.0, track="eval tour",
                       median_key="localisation.max_position_error_median_m",
                       p90_key="localisation.max_position_error_p90_m",
                       causes={"localisation.map_error_m": 0.3, "localisation.sigma_hit_m": 0.1})
    msg = str(exc.value)
    for part in ("eval tour", "median 0.800 m > localisation.max_position_error_median_m = 0.5 m",
                 "p90 2.500 m > localisation.max_position_error_p90_m = 1 m",
                 "localisation.map_error_m = 0.3", "localisation.sigma_hit_m = 0.1"):
        assert part in msg
    only_p90 = LocalisationSummary(100, 0.1, 1.5, 1.0, 0.0, 0.0, 0.0, 0.0)
    with pytest.raises(ValueError, match="p90 1.500 m") as exc:
        check_tracking(only_p90, 0.5, 1.0)
    assert "median" not in str(exc.value)
