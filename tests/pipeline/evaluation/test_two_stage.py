"""Two-stage intervals for pooled replicates: the replicate is the top-level unit.

Simulated two-stage data with known truth: R replicates, each with its own random
effect (its tour, its reads, its fitted model shift every tag of it alike) and 16 tags
with their own noise. A statistic of the pooled (replicate, tag) units varies with the
replicate effect; resampling the (replicate, tag) units as independent leaves that
variance out. The coverage of the 95 % intervals is counted over simulated data sets for
each statistic kind the tool reports on such units: a mean, an RMSE, a median, a p90, a
share and a Brier score (a mean of squared probability errors)."""

from __future__ import annotations

import numpy as np
import pytest

from pipeline.evaluation.intervals import (
    clusters_of,
    two_stage_multiplicity,
    unit_interval,
    weighted_mean,
    weighted_quantile,
)

N_REP, N_TAG = 5, 16
TAU, SIGMA = 1.0, 1.0  # replicate effect and tag noise sd: half the variance between replicates


def _stat(kind: str, x: np.ndarray):
    if kind == "mean":
        return lambda w: weighted_mean(x, w)
    if kind == "rmse":
        return lambda w: np.sqrt(weighted_mean(x ** 2, w))
    if kind == "median":
        return lambda w: weighted_quantile(x, w, 0.5)
    if kind == "p90":
        return lambda w: weighted_quantile(x, w, 0.9)
    if kind == "share":
        return lambda w: weighted_mean((x < 0.5).astype(float), w)
    if kind == "brier":  # squared error of a probability 0.7 against 0/1 outcomes
        p = 1.0 / (1.0 + np.exp(-x))  # each unit's probability of a read
        return lambda w: weighted_mean((0.7 - p) ** 2, w)
    raise KeyError(kind)


def _truth(kind: str, rng) -> float:
    """The statistic's population value (a very large two-stage sample)."""
    big = rng.normal(0, TAU, 20_000)[:, None] + rng.normal(0, SIGMA, (20_000, 50))
    return float(_stat(kind, big.ravel())(np.ones(big.size)))


def test_clusters_are_read_from_pooled_unit_names():
    assert clusters_of(["r0/T1", "r0/T2", "r3/T1"]).tolist() == [0, 0, 3]
    assert clusters_of(["T1", "T2"]) is None  # one run: independent units
    assert clusters_of(["r0/T1", "T2"]) is None


def test_two_stage_multiplicities_keep_each_resample_s_size_and_draw_replicates_whole():
    rng = np.random.default_rng(0)
    clusters = np.repeat(np.arange(3), 4)
    w = two_stage_multiplicity(clusters, rng, 2000)
    assert w.shape == (2000, 12)
    assert np.all(w.sum(axis=1) == 12)  # 3 replicates x 4 units in every resample
    # a replicate drawn m times contributes 4 m units: per replicate, multiples of 4
    per_rep = w.reshape(2000, 3, 4).sum(axis=2)
    assert np.all(per_rep % 4 == 0)
    # how often a replicate is left out: (2/3)^3 = 0.296
    assert np.mean(per_rep[:, 0] == 0) == pytest.approx((2 / 3) ** 3, abs=0.03)


@pytest.mark.parametrize("kind", ["mean", "rmse", "median", "p90", "share", "brier"])
def test_two_stage_intervals_cover_and_one_stage_intervals_do_not(kind):
    """Coverage over 60 simulated data sets (each 5 replicates x 16 tags). The two-stage
    interval must cover at least 85 % (95 % nominal; with 60 data sets a true 95 %
    falls below 85 % with probability 0.001); the one-stage interval, resampling
    (replicate, tag) as independent, covers far less with half the variance between
    replicates (it is shown to fail so that the test can)."""
    rng = np.random.default_rng(11)
    truth = _truth(kind, rng)
    clusters = np.repeat(np.arange(N_REP), N_TAG)
    hit2 = hit1 = 0
    n_sets = 60
    for _ in range(n_sets):
        x = (rng.normal(0, TAU, N_REP)[:, None] + rng.normal(0, SIGMA, (N_REP, N_TAG))).ravel()
        f = _stat(kind, x)
        two = unit_interval(f, x.size, rng, clusters=clusters, n_resamples=2000)
        one = unit_interval(f, x.size, rng, n_resamples=2000)
        hit2 += two.low <= truth <= two.high
        hit1 += one.low <= truth <= one.high
        assert two.method == "two-stage percentile"
    assert hit2 / n_sets >= 0.85, (kind, hit2, hit1)
    assert hit1 / n_sets < hit2 / n_sets, (kind, hit2, hit1)
