"""Coverage of the 95 % intervals: pooled replicates (two-stage against one-stage), and
one run's independent units (BCa or percentile at Hesterberg's expanded level).

    python bench/two_stage_coverage.py [--sets 200] [--replicates 5] [--tags 16]

Simulated two-stage data with a known population value (tests/pipeline/evaluation/
test_two_stage.py: a replicate effect and a tag noise of equal variance) for each
statistic kind the tool reports; prints, per kind, the share of data sets whose interval
covers the truth, for the two-stage resampling (replicate, then unit) and for the
(replicate, unit) pairs resampled as independent. Then one run: ``--tags`` independent
units (each a tag effect plus noise, no replicate), the interval the tool gives there
(BCa; the percentile interval for the quantiles).
"""

from __future__ import annotations

import argparse

import numpy as np

from pipeline.evaluation.intervals import unit_interval
from tests.pipeline.evaluation.test_two_stage import SIGMA, TAU, _stat, _truth


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--sets", type=int, default=200)
    ap.add_argument("--replicates", type=int, default=5)
    ap.add_argument("--tags", type=int, default=16)
    a = ap.parse_args()
    rng = np.random.default_rng(2026)
    clusters = np.repeat(np.arange(a.replicates), a.tags)
    print(f"{a.sets} data sets of {a.replicates} replicates x {a.tags} units; 95 % nominal")
    print(f"{'statistic':>9} {'two-stage':>10} {'one-stage':>10} {'two-stage width':>16}")
    for kind in ("mean", "rmse", "median", "p90", "share", "brier"):
        truth = _truth(kind, rng)
        h2 = h1 = 0
        widths = []
        for _ in range(a.sets):
            x = (rng.normal(0, TAU, a.replicates)[:, None]
                 + rng.normal(0, SIGMA, (a.replicates, a.tags))).ravel()
            f = _stat(kind, x)
            two = unit_interval(f, x.size, rng, clusters=clusters, n_resamples=2000)
            one = unit_interval(f, x.size, rng, n_resamples=2000)
            h2 += two.low <= truth <= two.high
            h1 += one.low <= truth <= one.high
            widths.append(two.high - two.low)
        print(f"{kind:>9} {h2 / a.sets:>10.3f} {h1 / a.sets:>10.3f} {np.median(widths):>16.3f}")
    print(f"\none run: {a.sets} data sets of {a.tags} independent units; 95 % nominal")
    print(f"{'statistic':>9} {'coverage':>10} {'method':>11}")
    for kind in ("mean", "rmse", "median", "p90", "share", "brier"):
        big = rng.normal(0, np.hypot(TAU, SIGMA), 2_000_000)  # one level, the same variance
        truth = float(_stat(kind, big)(np.ones(big.size)))
        how = "percentile" if kind in ("median", "p90") else "BCa"
        hit = 0
        for _ in range(a.sets):
            x = rng.normal(0, np.hypot(TAU, SIGMA), a.tags)
            iv = unit_interval(_stat(kind, x), x.size, rng, n_resamples=2000, method=how)
            hit += iv.low <= truth <= iv.high
        print(f"{kind:>9} {hit / a.sets:>10.3f} {how:>11}")


if __name__ == "__main__":
    main()
