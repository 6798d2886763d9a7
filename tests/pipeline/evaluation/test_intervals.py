"""Cluster-bootstrap intervals and paired comparisons (pipeline.evaluation.intervals,
pipeline.evaluation.headline) on synthetic problems with a known answer."""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest

from pipeline.evaluation.headline import headline_intervals
from pipeline.evaluation.intervals import (
    MIN_UNITS,
    expanded_level,
    multiplicity,
    paired_difference,
    unit_interval,
    weighted_mean,
    weighted_quantile,
)
from pipeline.evaluation.units import UnitTables, concat_unit_tables


def test_weighted_quantile_is_numpys_on_the_repeated_sample():
    rng = np.random.default_rng(0)
    v = rng.normal(size=23)
    v[3] = v[7]  # ties
    w = rng.integers(0, 4, size=(40, 23)).astype(float)
    w[:, 0] += 1  # never an empty resample
    for q in (0.0, 0.1, 0.5, 0.9, 1.0):
        got = weighted_quantile(v, w, q)
        want = [np.quantile(np.repeat(v, row.astype(int)), q) for row in w]
        np.testing.assert_allclose(got, want, rtol=0, atol=1e-12)
    assert weighted_quantile(v, np.ones(23), 0.5) == np.median(v)
    assert np.isnan(weighted_quantile(v, np.zeros(23), 0.5))


def test_multiplicity_counts_each_unit():
    idx = np.array([[0, 0, 2, 3], [1, 1, 1, 1]])
    np.testing.assert_array_equal(multiplicity(idx, 4), [[2, 0, 1, 1], [0, 4, 0, 0]])
    np.testing.assert_array_equal(multiplicity(np.array([2, 2, 0]), 3), [1, 0, 2])


def _clustered_rmse(rng, n_units=20):
    """Errors e = b_unit + noise, b ~ N(0, 1), noise ~ N(0, 1): every observation has
    E[e^2] = 2, so the pooled RMSE estimates sqrt(2) whatever the units' sizes."""
    sizes = rng.integers(3, 12, size=n_units)
    codes = np.repeat(np.arange(n_units), sizes)
    e = rng.normal(size=n_units)[codes] + rng.normal(size=codes.size)
    sq = np.bincount(codes, e * e, minlength=n_units)
    cnt = np.bincount(codes, minlength=n_units).astype(float)
    return lambda w: np.sqrt((w @ sq) / (w @ cnt))


def test_interval_coverage_is_nominal_on_clustered_data():
    """Nominal 95 %: the interval holds the true RMSE in 90-98 % of 300 data sets of 80
    units (a replicated study's 5 x 16 held-out tags).

    The band: 300 Bernoulli(0.95) trials have a standard deviation of 1.3 points, and a
    bootstrap interval undercovers by a point or two (seen on 1,000 data sets: 94 % with
    80 units, 92 % with 30, 91 % with 16, module doc); a bootstrap that resampled
    observations instead of units covers ~70 % here (the control below)."""
    rng = np.random.default_rng(11)
    hits = 0
    n = 300
    for _ in range(n):
        iv = unit_interval(_clustered_rmse(rng, 80), 80, rng, n_resamples=1000)
        assert iv.method == "BCa"
        hits += iv.low <= np.sqrt(2.0) <= iv.high
    assert 0.90 <= hits / n <= 0.98, hits / n


def test_expanded_level():
    assert expanded_level(16) == pytest.approx(0.9723, abs=1e-4)
    assert expanded_level(80) == pytest.approx(0.9548, abs=1e-4)
    assert expanded_level(100000) == pytest.approx(0.95, abs=1e-4)


def test_observation_bootstrap_would_undercover():
    """The control of the coverage test: treating every observation as a unit (what a
    bootstrap over read attempts does) covers far less than 95 % on the same data."""
    rng = np.random.default_rng(12)
    hits = 0
    for _ in range(100):
        sizes = rng.integers(3, 12, size=20)
        codes = np.repeat(np.arange(20), sizes)
        e = rng.normal(size=20)[codes] + rng.normal(size=codes.size)
        iv = unit_interval(lambda w, e=e: np.sqrt(weighted_mean(e * e, w)), e.size, rng,
                           n_resamples=500)
        hits += iv.low <= np.sqrt(2.0) <= iv.high
    assert hits / 100 < 0.88


def test_paired_difference_finds_a_planted_difference_and_no_other():
    rng = np.random.default_rng(3)
    codes = np.repeat(np.arange(16), 30)
    e = rng.normal(size=16)[codes] + rng.normal(size=codes.size)

    def mae(err):
        s = np.bincount(codes, np.abs(err), minlength=16)
        c = np.bincount(codes, minlength=16).astype(float)
        return lambda w: (w @ s) / (w @ c)

    same = paired_difference(mae(e), mae(e.copy()), 16, rng)
    assert same.verdict == "not distinguishable at 95 %"
    assert same.difference.estimate == 0.0 and same.difference.method == "degenerate"
    worse = paired_difference(mae(np.abs(e) + 0.3), mae(e), 16, rng)
    assert worse.verdict == "worse" and worse.difference.low > 0
    assert worse.difference.estimate == pytest.approx(0.3)
    better = paired_difference(mae(0.7 * e), mae(e), 16, rng)
    assert better.verdict == "better" and better.difference.high < 0
    # the direction of the metric: a higher share is better
    share = paired_difference(lambda w: weighted_mean(np.ones(16), w),
                              lambda w: weighted_mean(np.arange(16) % 2, w), 16, rng,
                              lower_is_better=False)
    assert share.verdict == "better"


def test_too_few_units_give_no_interval():
    rng = np.random.default_rng(0)
    iv = unit_interval(lambda w: weighted_mean(np.arange(3.0), w), 3, rng, unit="filter run")
    assert iv.low is None and iv.high is None and iv.method == "none"
    assert iv.estimate == 1.0 and f"at least {MIN_UNITS}" in iv.note
    assert iv.to_dict()["note"].startswith("3 filter runs")


def _tables(rng, n_tags=16, scale=1.0):
    tags = [f"T{i:02d}" for i in range(n_tags)]
    codes = np.repeat(np.arange(n_tags), 25)
    e = rng.normal(size=n_tags)[codes] * 2 + rng.normal(size=codes.size) * 3
    unit = np.asarray(tags)[codes]
    rssi = pd.concat([pd.DataFrame({"model": "anfis", "unit": unit, "error_db": e}),
                      pd.DataFrame({"model": "twin", "unit": unit, "error_db": e}),
                      pd.DataFrame({"model": "scaled", "unit": unit, "error_db": e * scale})])
    cells = np.repeat(np.arange(4), codes.size // 4 + 1)[: codes.size]
    att = pd.DataFrame({"model": "anfis", "unit": unit, "cell": cells,
                        "read": rng.random(codes.size) < 0.5, "p_true": np.full(codes.size, 0.5),
                        "ft": np.full(codes.size, 0.4)})
    dcells = pd.DataFrame({"model": "anfis", "cell": np.arange(4), "ft_centre": 0.4})
    fig7 = pd.DataFrame({"model": "anfis", "unit": unit, "error_pct": np.abs(e) * 5})
    tag_err = pd.DataFrame({"model": ["anfis"] * n_tags + ["twin"] * n_tags,
                            "unit": tags * 2, "error_m": np.tile(rng.random(n_tags), 2)})
    return UnitTables(rssi, att, dcells, fig7, tag_err, None)


def test_headline_intervals_from_unit_tables():
    rng = np.random.default_rng(5)
    t = _tables(rng, scale=1.5)
    out = headline_intervals(t, seed=1, min_attempts=5, n_resamples=500)
    iv = out["intervals"]
    e = t.rssi_links.query("model == 'anfis'")["error_db"].to_numpy()
    rmse = iv["heldout.rssi_rmse_db"]["models"]["anfis"]
    assert rmse["estimate"] == pytest.approx(np.sqrt(np.mean(e * e)))
    assert rmse["low"] < rmse["estimate"] < rmse["high"] and rmse["n_units"] == 16
    # p_detect 0.5 in every cell, fT 0.4 at every centre: MAE 0.1, given without an
    # interval (the cell MAE's bootstrap is biased, headline.CELL_MAE_NOTE)
    det = iv["heldout.detection_mae"]["models"]["anfis"]
    assert det["estimate"] == pytest.approx(0.1) and det["low"] is None
    assert det["note"].startswith("not resampled")
    assert "heldout.detection_mae" not in out["comparisons"]["metrics"]
    tag = iv["tag_localisation.median_m"]["models"]["anfis"]
    assert tag["estimate"] == pytest.approx(t.tag_errors["error_m"][:16].median())
    cmp_ = out["comparisons"]["metrics"]
    assert cmp_["heldout.rssi_abs_bias_db"]["twin"]["verdict"] == "not distinguishable at 95 %"
    assert cmp_["tag_localisation.median_m"]["twin"]["verdict"] == "not distinguishable at 95 %"
    assert cmp_["heldout.rssi_mae_db"]["scaled"]["verdict"] == "worse"
    assert cmp_["heldout.rssi_rmse_db"]["scaled"]["estimate"] == pytest.approx(
        0.5 * rmse["estimate"])
    assert "robot_localisation.median_m" not in iv  # no robot table: left out, not faked


def test_replicates_pool_as_units_of_their_own():
    rng = np.random.default_rng(6)
    a, b = _tables(rng), _tables(rng)
    pooled = concat_unit_tables({0: a, 1: b})
    assert pooled.rssi_links["unit"].nunique() == 32
    assert set(pooled.detection_attempts["cell"]) == set(range(8))  # cells per replicate
    out = headline_intervals(pooled, seed=1, min_attempts=5, n_resamples=300, replicated=True)
    rmse = out["intervals"]["heldout.rssi_rmse_db"]
    assert rmse["n_units"] == 32 and rmse["unit"] == "replicate x tag"
    e = pooled.rssi_links.query("model == 'anfis'")["error_db"].to_numpy()
    assert rmse["models"]["anfis"]["estimate"] == pytest.approx(np.sqrt(np.mean(e * e)))
    # two replicates: the between-replicate variance rests on one difference, no interval
    assert rmse["models"]["anfis"]["low"] is None and "2 replicates" in rmse["models"]["anfis"]["note"]
    three = concat_unit_tables({0: a, 1: b, 2: _tables(rng)})
    out = headline_intervals(three, seed=1, min_attempts=5, n_resamples=300, replicated=True)
    iv = out["intervals"]["heldout.rssi_rmse_db"]["models"]["anfis"]
    assert iv["method"] == "two-stage percentile" and iv["low"] < iv["estimate"] < iv["high"]


def test_a_model_scored_on_fewer_units_is_compared_on_the_shared_ones():
    """A model with rows for 8 of the 16 tags: its interval is over its 8 tags, and its
    comparison with ANFIS uses those 8 tags for both models."""
    rng = np.random.default_rng(8)
    t = _tables(rng)
    part = t.rssi_links.query("model == 'anfis'").copy()
    part = part[part["unit"] < "T08"].assign(model="partial", error_db=lambda d: d["error_db"] + 1.0)
    t.rssi_links = pd.concat([t.rssi_links, part], ignore_index=True)
    out = headline_intervals(t, seed=1, min_attempts=5, n_resamples=300)
    iv = out["intervals"]["heldout.rssi_abs_bias_db"]
    assert iv["models"]["partial"]["n_units"] == 8 and iv["models"]["anfis"]["n_units"] == 16
    c = out["comparisons"]["metrics"]["heldout.rssi_abs_bias_db"]["partial"]
    ref = t.rssi_links.query("model == 'anfis' and unit < 'T08'")["error_db"]
    assert c["n_units"] == 8
    assert c["estimate"] == pytest.approx(abs(ref.mean() + 1.0) - abs(ref.mean()))


def test_the_abs_bias_interval_is_the_signed_one_folded_and_can_reach_zero():
    """Errors with no bias: a bootstrap of |mean| never reaches 0 (every resample's |mean|
    is > 0), so it could never say "no bias"; the folded interval of the signed mean does."""
    from pipeline.evaluation.intervals import Interval, fold_interval

    rng = np.random.default_rng(21)
    t = _tables(rng)
    e = t.rssi_links.query("model == 'anfis'")
    t.rssi_links = t.rssi_links.assign(error_db=t.rssi_links["error_db"] - e["error_db"].mean())
    out = headline_intervals(t, seed=1, min_attempts=5, n_resamples=500)
    iv = out["intervals"]["heldout.rssi_abs_bias_db"]["models"]["anfis"]
    assert iv["estimate"] == pytest.approx(0.0, abs=1e-9)
    assert iv["low"] == 0.0 and iv["high"] > 0 and iv["method"].endswith("(folded)")
    # the fold itself: an interval off 0 keeps its magnitudes, one across 0 starts at 0
    assert fold_interval(Interval(-2.0, -3.0, -1.0, 16, "tag", "BCa")).low == 1.0
    f = fold_interval(Interval(0.5, -1.0, 2.0, 16, "tag", "BCa"))
    assert (f.estimate, f.low, f.high) == (0.5, 0.0, 2.0)


def test_quantile_metrics_take_the_percentile_interval():
    """BCa's acceleration comes from the jackknife, which is inconsistent for a median
    (Efron & Tibshirani 1993, Sec. 11.6); with the expanded level its adjusted tail
    lands among the few largest order statistics of 16 tags, where the end jumps between
    them with the bootstrap seed (the review saw 1.89 and 2.49 m). The quantile metrics
    take the percentile interval, the others BCa."""
    rng = np.random.default_rng(4)
    t = _tables(rng)
    out = headline_intervals(t, seed=1, min_attempts=5, n_resamples=500)
    for key in ("tag_localisation.median_m", "tag_localisation.p90_m", "fig7.median_pct"):
        assert out["intervals"][key]["models"]["anfis"]["method"] == "percentile", key
    assert out["intervals"]["heldout.rssi_rmse_db"]["models"]["anfis"]["method"] == "BCa"
    cmp_ = out["comparisons"]["metrics"]["tag_localisation.median_m"]["twin"]
    assert cmp_["method"] in ("percentile", "degenerate")  # the twin equals ANFIS unit by unit
