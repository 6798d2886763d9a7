"""Acquisition-side throughput: laser ray casting, MCL updates, tour generation.

One measurement per function, each returning a dict row; main prints a table of the
numbers from this run (no timed assertions). Scene: bundled ``corridor_lab``.
The "acquisition" part (read attempts per second) is added by that stage's owner.

Usage: python bench/acquire.py [--scene corridor_lab] [--particles 1000] [--steps 300]
"""

from __future__ import annotations

import argparse
import os
import platform
import time

import numpy as np

import scenes
from pipeline.robot import (
    LaserScanner,
    MCLConfig,
    OdometryNoise,
    Robot,
    TourConfig,
    guided_tour,
    laser_map,
    run_mcl,
    simulate_odometry,
)
from propagation import TraceOptions
from scenes import floor_plan_segments


def _timed(fn, repeat=3):
    best = np.inf
    out = None
    for _ in range(repeat):
        t0 = time.perf_counter()
        out = fn()
        best = min(best, time.perf_counter() - t0)
    return best, out


def bench_tour(scene, robot, n_passes=2):
    """Tour generation (collision map, feasible band, sampling, footprint check)."""
    cfg = TourConfig(n_passes=n_passes)
    dt, tour = _timed(lambda: guided_tour(scene, robot, np.random.default_rng(0), cfg), 1)
    return {
        "measure": f"guided_tour ({n_passes} passes, {len(tour)} poses)",
        "value": len(tour) / dt,
        "unit": "poses/s",
        "seconds": dt,
    }, tour


def bench_laser(scene, poses, scanner):
    """Laser rays per second (exact 2-D ray/segment intersection)."""
    seg = floor_plan_segments(scene, scanner.height_m)
    dt, _ = _timed(lambda: scanner.scan(seg, poses, np.random.default_rng(0)))
    rays = len(poses) * scanner.n_beams
    return {
        "measure": f"laser ray cast ({len(seg)} segments, {rays} rays)",
        "value": rays / dt,
        "unit": "rays/s",
        "seconds": dt,
    }


def bench_map(scene, scanner):
    """Laser map + exact likelihood field construction."""
    dt, lm = _timed(lambda: laser_map(scene, scanner), 1)
    return {
        "measure": f"laser map + likelihood field {lm.shape}",
        "value": lm.occupied.size / dt,
        "unit": "cells/s",
        "seconds": dt,
    }, lm


def bench_mcl(lmap, scanner, segments, poses, n_particles):
    """MCL steps per second (predict + update + estimate) at n_particles."""
    rng = np.random.default_rng(1)
    odo = simulate_odometry(poses, OdometryNoise(), rng)
    scans = scanner.scan(segments, poses, rng)
    cfg = MCLConfig(n_particles=n_particles)
    dt, res = _timed(
        lambda: run_mcl(
            lmap,
            scanner,
            odo,
            scans,
            poses[0],
            np.random.default_rng(2),
            config=cfg,
            true_poses=poses,
        ),
        1,
    )
    return {
        "measure": f"MCL steps, {n_particles} particles, {cfg.n_beams_used} beams "
        f"({res.n_updates}/{len(poses)} with scan update)",
        "value": len(poses) / dt,
        "unit": "steps/s",
        "seconds": dt,
    }


def bench_reads(scene, robot, tour):
    """Read attempts per second without tracing: schedule, geometry, budget, noise, table.

    An attempt is one (read cycle, active antenna, tag) row of ``reads.parquet``; the gains
    are synthetic (uniform -70..-20 dB), so this times the reader simulation alone.
    """
    from pipeline.acquisition import ReaderConfig, as_pose_track, read_attempts, reads_from_gains

    reader = ReaderConfig(read_rate_hz=10.0)  # paper_scale's rate
    track = as_pose_track(tour)
    rng = np.random.default_rng(0)

    def run():
        att = read_attempts(track, robot.antennas, reader)
        gains = rng.uniform(-70.0, -20.0, size=(len(att.time_s), len(scene.tags)))
        return reads_from_gains(att, scene.tags, gains, np.ones(gains.shape, bool), reader, rng)

    dt, table = _timed(run)
    return {
        "measure": f"read attempts, no tracing ({len(table)} = slots x {len(scene.tags)} tags)",
        "value": len(table) / dt,
        "unit": "attempts/s",
        "seconds": dt,
    }


def bench_reads_traced(scene, robot, tour, seconds=4.0, rays=10_000, depth=3):
    """simulate_reads end to end on the first ``seconds`` of the tour: cold, then warm cache."""
    import tempfile

    from pipeline.acquisition import PoseTrack, ReaderConfig, as_pose_track, simulate_reads

    full = as_pose_track(tour)
    keep = full.t_s <= full.t_s[0] + seconds
    track = PoseTrack(
        full.t_s[keep], full.true_poses[keep], full.est_poses[keep], full.odom_poses[keep]
    )
    reader = ReaderConfig(read_rate_hz=10.0)  # paper_scale's rate
    trace = TraceOptions(method="direct", max_depth=depth, samples_per_src=rays)
    rows = []
    with tempfile.TemporaryDirectory() as cache:
        for label in ("cold trace cache", "warm trace cache"):
            dt, log = _timed(
                lambda: simulate_reads(
                    scene,
                    robot,
                    track,
                    reader,
                    np.random.default_rng(0),
                    trace=trace,
                    cache_dir=cache,
                ),
                1,
            )
            rows.append(
                {
                    "measure": f"read attempts, simulate_reads, {label} ({log.n_attempts} attempts, "
                    f"{log.metadata['n_pairs_traced']} pairs, {rays} rays, depth {depth})",
                    "value": log.n_attempts / dt,
                    "unit": "attempts/s",
                    "seconds": dt,
                }
            )
    return rows


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--scene", default="corridor_lab")
    ap.add_argument("--particles", type=int, default=1000)
    ap.add_argument("--steps", type=int, default=300)
    args = ap.parse_args()
    scene = scenes.load(args.scene)
    robot = Robot()
    scanner = LaserScanner()
    segments = floor_plan_segments(scene, scanner.height_m)
    rows = []
    row, tour = bench_tour(scene, robot)
    rows.append(row)
    poses = tour.poses[: args.steps]
    rows.append(bench_laser(scene, poses, scanner))
    row, lmap = bench_map(scene, scanner)
    rows.append(row)
    rows.append(bench_mcl(lmap, scanner, segments, poses, args.particles))
    rows.append(bench_mcl(lmap, scanner, segments, poses, 5 * args.particles))
    mcl1, mcl5 = rows[-2]["value"], rows[-1]["value"]
    read_rows = [bench_reads(scene, robot, tour), *bench_reads_traced(scene, robot, tour)]
    rows.extend(read_rows)
    print(
        f"# bench/acquire.py  scene={args.scene}  {platform.processor() or platform.machine()}"
        f"  cpus={os.cpu_count()}  numpy={np.__version__}"
    )
    print(f"{'measure':<72} {'value':>12} {'unit':<8} {'time_s':>8}")
    for r in rows:
        print(f"{r['measure']:<72} {r['value']:>12.4g} {r['unit']:<8} {r['seconds']:>8.3f}")
    print(
        f"ratio: MCL steps/s at {args.particles} vs {5 * args.particles} particles = "
        f"{mcl1 / mcl5:.2f} (5.00 if cost were linear in particles)"
    )
    pure, cold, warm = (r["value"] for r in read_rows)
    print(
        f"ratio: read attempts/s no tracing vs warm cache vs cold cache = "
        f"{pure / warm:.1f} : 1 : {cold / warm:.3f}"
    )
    real_time = 1.0 / TourConfig().dt_s
    print(
        f"ratio: MCL at {args.particles} particles vs real time ({real_time:.0f} Hz scans) = "
        f"{mcl1 / real_time:.1f}x"
    )


if __name__ == "__main__":
    main()
