import json
import math

import numpy as np
import pytest

from pipeline.evaluation import brier_score, error_stats, nan_to_none, percentile_summary


def test_perfect_prediction_has_zero_error():
    ref = np.linspace(-80, -40, 11)
    s = error_stats(ref, ref)
    assert s.n == 11
    assert s.mae == 0.0 and s.rmse == 0.0 and s.bias == 0.0 and s.max_abs == 0.0
    assert s.correlation == pytest.approx(1.0)


def test_offset_of_3db_gives_bias_and_mae_3db():
    ref = np.linspace(-80, -40, 11)
    s = error_stats(ref + 3.0, ref)
    # exact up to float rounding of (x + 3) - x
    assert s.bias == pytest.approx(3.0, abs=1e-12)
    assert s.mae == pytest.approx(3.0, abs=1e-12)
    assert s.rmse == pytest.approx(3.0, abs=1e-12)
    s = error_stats(ref - 3.0, ref)
    assert s.bias == pytest.approx(-3.0, abs=1e-12)


def test_error_stats_by_hand_and_nan_dropped():
    s = error_stats([1.0, 2.0, np.nan, 5.0], [0.0, 4.0, 1.0, np.inf])
    # pairs kept: (1,0), (2,4): errors +1, -2
    assert s.n == 2
    assert s.mae == pytest.approx(1.5)
    assert s.rmse == pytest.approx(math.sqrt(2.5))
    assert s.bias == pytest.approx(-0.5)
    assert s.max_abs == 2.0


def test_empty_gives_nan_and_null_in_json():
    s = error_stats([], [])
    assert s.n == 0 and math.isnan(s.mae)
    d = s.to_dict()
    assert d["mae"] is None
    json.dumps(d, allow_nan=False)


def test_brier_score_known_values():
    assert brier_score([1.0, 0.0], [True, False]) == 0.0
    assert brier_score([0.5, 0.5, 0.5, 0.5], [1, 0, 1, 1]) == pytest.approx(0.25)
    # constant base rate b scores b(1-b)
    o = np.array([1, 1, 1, 0])
    assert brier_score(np.full(4, 0.75), o) == pytest.approx(0.75 * 0.25)
    with pytest.raises(ValueError, match="boolean"):
        brier_score([0.5], [2])
    with pytest.raises(ValueError, match="shape"):
        brier_score([0.5, 0.2], [1])


def test_percentile_summary_and_nan_to_none():
    p = percentile_summary([10.0, 20.0, np.nan, 30.0])
    assert (p.n, p.mean, p.median, p.max) == (3, 20.0, 20.0, 30.0)
    assert p.p90 == pytest.approx(28.0)  # linear interpolation between 20 and 30
    out = nan_to_none({"a": np.float32(1.5), "b": [np.nan, np.int64(2)], "c": np.bool_(True)})
    assert out == {"a": 1.5, "b": [None, 2], "c": True}
