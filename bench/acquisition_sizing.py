"""How many RSSI-model (SSM) samples a guided tour of corridor_lab yields, and the tour
that reaches the chapter's 12,395 SSM training samples.

Measured, not guessed: one real tour (pipeline.robot.guided_tour) is driven, the reader
is simulated on real Sionna traces (pipeline.acquisition.simulate_reads), and the SSM
samples (reads with d < 3 m) are counted. The yield per second of touring scales with
the read rate, and each pass adds the same corridor length, so the number of passes
needed follows; a second tour with that many passes checks the prediction.

Usage: python bench/acquisition_sizing.py [--rays 10000] [--depth 3] [--passes 2]
"""

from __future__ import annotations

import argparse
import math
import time

import numpy as np

import scenes
from pipeline.acquisition import ReaderConfig, simulate_reads, ssm_samples, tdm_samples
from pipeline.robot import Robot
from pipeline.robot.trajectory import TourConfig, guided_tour
from propagation import TraceOptions

TARGET_SSM = 12_395  # Cicirelli, Milella & Di Paola (2011): SSM training samples


def measure(scene, passes, reader, rays, depth, cache_dir, seed=0, speed=0.3, out_dir=None):
    robot = Robot()
    tour = guided_tour(
        scene, robot, np.random.default_rng(seed), TourConfig(n_passes=passes, speed_m_per_s=speed)
    )
    t0 = time.perf_counter()
    log = simulate_reads(
        scene,
        robot,
        tour,
        reader,
        np.random.default_rng(seed),
        trace=TraceOptions(method="direct", max_depth=depth, samples_per_src=rays),
        cache_dir=cache_dir,
    )
    dt = time.perf_counter() - t0
    r = log.reads
    if out_dir is not None:
        log.write(out_dir)
    ssm = ssm_samples(r, d_max_m=3.0, pose="true")
    tdm = tdm_samples(r, d_max_m=3.0, pose="true", min_attempts=5)
    return {
        "passes": passes,
        "speed_m_per_s": speed,
        "tour_s": float(tour.t_s[-1] - tour.t_s[0]),
        "cycles": log.metadata["n_slots"],
        "rows": len(r),
        "reads": log.n_reads,
        "ssm": len(ssm),
        "tdm_cells": len(tdm),
        "pairs_traced": log.metadata["n_pairs_traced"],
        "seconds": dt,
    }


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--rays", type=int, default=10_000)
    ap.add_argument("--depth", type=int, default=3)
    ap.add_argument("--passes", type=int, default=2)
    ap.add_argument("--rate", type=float, default=10.0)
    ap.add_argument("--cache", default=".cache/acquisition_sizing")
    ap.add_argument("--out", default=None, help="write the first tour's read log here")
    args = ap.parse_args()
    scene = scenes.load("corridor_lab")
    reader = ReaderConfig(read_rate_hz=args.rate)
    m = measure(scene, args.passes, reader, args.rays, args.depth, args.cache, out_dir=args.out)
    per_pass = m["ssm"] / args.passes
    print(
        f"corridor_lab, {args.passes} passes at 0.3 m/s, {args.rate:g} Hz round robin, "
        f"{args.rays} rays depth {args.depth}: tour {m['tour_s']:.1f} s, {m['cycles']} "
        f"read cycles, {m['rows']} attempt rows, {m['reads']} reads, SSM samples (d < 3 m) {m['ssm']} "
        f"({per_pass:.0f}/pass, {m['ssm'] / m['tour_s']:.1f}/s), TDM cells {m['tdm_cells']}, "
        f"{m['pairs_traced']} pairs traced in {m['seconds']:.1f} s"
    )
    need = math.ceil(TARGET_SSM / per_pass)
    need += need % 2  # even: the tour ends where it started
    print(f"passes needed for {TARGET_SSM} SSM samples at {args.rate:g} Hz: {need}")
    check = measure(scene, need, reader, args.rays, args.depth, args.cache, seed=1)
    print(
        f"check: {need} passes -> tour {check['tour_s']:.1f} s, {check['cycles']} read cycles, "
        f"{check['rows']} rows, SSM samples {check['ssm']} (target {TARGET_SSM}: "
        f"{'met' if check['ssm'] >= TARGET_SSM else 'NOT met'}), TDM cells {check['tdm_cells']}, "
        f"{check['seconds']:.1f} s"
    )


if __name__ == "__main__":
    main()
