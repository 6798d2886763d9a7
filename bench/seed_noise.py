"""Seed-to-seed noise of the study's truth on sparse antenna poses and on the dense
evaluation path, per ``tracing.min_samples_per_position`` setting, in one run.

Prints, per setting (default: the guarantee off, ``0``, and the study's default), for
two sets of antenna poses of ``corridor_lab`` traced with the study's tracing options
(patterns, depth, rays, sharing, completion) and seeds 1 and 2 (no path cache):

1. *sparse*: 96 poses, stations 2 m apart along the corridor (x = 1, 3, ..., 23 m), at
   each a pair 0.6 m apart across it (y = 0.9 and 1.5 m), at two heights 1.1 m apart
   (0.5 and 1.6 m) and two yaws (+-45 deg): 48 positions, each with exactly one
   neighbour within the 1 m sharing radius;
2. *dense*: the evaluation path of a finished default run (``--run``: its
   ``eval_reads.parquet``, every antenna position once, the held-out tags), ~0.3 m
   between antenna slots (skipped without ``--run``).

For each: the number of readable links (either seed's gain >= the study's read
threshold, ``reader.link_budget().min_gain_db()``, as ``bench/study_trace.py`` defines
it), p50 / p95 of |gain seed 1 - gain seed 2| over them, the flipped read decisions,
the positions that shot extra rays and the seconds per trace.

With ``--study N``, then: the whole default study from an empty propagation cache
(``rfidstudy run``, ``bench/study_trace.py``'s ``run_study``; this machine's Dr.Jit
kernel cache) N times per setting, the settings alternating, its wall time and the
ratio of each setting's median to the first's.

Usage::

    .venv/bin/python bench/seed_noise.py [--run RUN_DIR] [--min 0 --min default --min 60000]
        [--config CONFIG.toml] [--skip-dense] [--skip-sparse] [--pairs 3] [--study 2]
"""

from __future__ import annotations

import argparse
import logging
import time
import warnings
from pathlib import Path

import numpy as np
import pandas as pd

from pipeline import runfiles


def sparse_poses() -> np.ndarray:
    """(96, 4) [x, y, z, yaw] poses: 12 stations 2 m apart x 2 across (0.6 m) x 2 heights
    (1.1 m apart) x 2 yaws; each of the 48 positions has one neighbour within 1 m."""
    rows = [[x, y, z, yaw] for x in np.arange(1.0, 24.0, 2.0) for y in (0.9, 1.5)
            for z in (0.5, 1.6) for yaw in (np.pi / 4, -np.pi / 4)]
    return np.asarray(rows, float)


def dense_links(run: Path):
    """Poses (n, 4), tag positions and normals of a run's evaluation path (as
    ``bench/study_trace.py`` takes them)."""
    tags = pd.read_parquet(run / runfiles.SCENE_TAGS).set_index("tag_id")
    r = pd.read_parquet(run / runfiles.EVAL_READS)
    ids = sorted(r["tag_id"].unique())
    cols = ["true_ant_x_m", "true_ant_y_m", "true_ant_z_m", "true_ant_yaw_rad"]
    poses = r.drop_duplicates(cols[:3])[cols].to_numpy(float)
    return (poses, tags.loc[ids, ["x_m", "y_m", "z_m"]].to_numpy(float),
            tags.loc[ids, ["nx", "ny", "nz"]].to_numpy(float))


def noise(a: np.ndarray, b: np.ndarray, threshold_db: float) -> dict:
    """p50 / p95 |a - b| [dB] over readable links (either >= ``threshold_db``), their
    count and the flipped read decisions."""
    readable = np.maximum(a, b) >= threshold_db
    with np.errstate(invalid="ignore"):
        d = np.abs(a - b)[readable]
    return {"n": int(readable.sum()), "p50": float(np.percentile(d, 50)) if len(d) else np.nan,
            "p95": float(np.percentile(d, 95)) if len(d) else np.nan,
            "flips": int(((a >= threshold_db) != (b >= threshold_db)).sum())}


class _ShortCount(logging.Handler):
    """Counts the positions the tracer reports short of the minimum (its INFO line)."""

    def __init__(self):
        super().__init__(logging.INFO)
        self.n = 0

    def emit(self, record):
        if "sharing positions short of" in record.getMessage():
            self.n += int(record.args[0])


def seed_pair(scene, poses, tags, normals, opts, frequency_hz, seeds=(1, 2)) -> tuple[dict, float, int]:
    """Gains [dB] per seed of ``seeds``, the mean seconds per trace and the positions
    the tracer reported short of the minimum (per trace)."""
    import propagation as P

    gains, secs = {}, []
    log = logging.getLogger("propagation.pathsolve")
    h = _ShortCount()
    log.addHandler(h)
    old = log.level
    log.setLevel(logging.INFO)
    try:
        for seed in seeds:
            t0 = time.perf_counter()
            links = P.trace_links(scene, poses, tags, opts.replace(seed=seed), tag_normals=normals,
                                  frequency_hz=frequency_hz)
            secs.append(time.perf_counter() - t0)
            gains[seed] = links.gain_db
    finally:
        log.removeHandler(h)
        log.setLevel(old)
    return gains, float(np.mean(secs)), h.n // len(seeds)


def setting_overrides(s: str) -> dict:
    """A setting's ``[tracing]`` config keys: 'default' none, a count the
    min_samples_per_position, 'key=value[,key=value]' those TraceOptions fields."""
    if s == "default":
        return {}
    if "=" not in s:
        return {"min_samples_per_position": s}
    return dict(kv.split("=", 1) for kv in s.split(","))


def setting_options(base, s: str):
    """The TraceOptions of a setting (``--min``): 'direct' is Sionna's PathSolver alone,
    samples_per_src rays, no completion."""
    if s == "direct":
        return base.replace(method="direct")
    over = {}
    for k, v in setting_overrides(s).items():
        cur = getattr(base, k)
        over[k] = int(v) if isinstance(cur, int) or cur is None else float(v)
    return base.replace(**over)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--run", type=Path, default=None, help="a finished default run (dense evaluation path)")
    ap.add_argument("--config", type=Path, default=None, help="a study config instead of the default")
    ap.add_argument("--min", action="append", default=None,
                    help="tracing.min_samples_per_position to measure ('default' or a count; repeat); "
                         "'direct': method 'direct' (every position samples_per_src rays alone); "
                         "'key=value[,key=value]': those tracing options (e.g. completion_min_area_m2=1.0)")
    ap.add_argument("--skip-dense", action="store_true")
    ap.add_argument("--skip-sparse", action="store_true")
    ap.add_argument("--pairs", type=int, default=1,
                    help="seed pairs (1, 2), (3, 4), ...: the p95 of one pair moves by ~0.1-0.15 dB "
                         "from pair to pair, so several give it an error bar")
    ap.add_argument("--study", type=int, default=0, metavar="N",
                    help="also time the cold default study N times per setting, alternating")
    args = ap.parse_args()
    warnings.simplefilter("ignore")
    import propagation as P
    import scenes
    from pipeline.apps.cli import resolve_target
    from pipeline.studyscene import trace_options

    P.select_variant("llvm")
    cfg = resolve_target(None if args.config is None else str(args.config))
    scene = scenes.load(cfg.scene)
    base = trace_options(cfg)
    thr = cfg.reader.link_budget(cfg.frequency_hz).min_gain_db()
    settings = args.min or ["0", "default"]
    sets = [] if args.skip_sparse else [("sparse", sparse_poses(), scene.tags.positions_m, scene.tags.normals)]
    if args.run is not None and not args.skip_dense:
        sets.append(("dense", *dense_links(args.run)))
    print(f"{cfg.scene}; readable: gain >= {thr:.2f} dB; tracing: {base.method}, depth {base.max_depth}, "
          f"{base.shared_samples_per_src} shared / {base.samples_per_src} lone rays, "
          f"radius {base.share_radius_m} m, completion {base.completion_order}", flush=True)
    for name, poses, tags, normals in sets:
        n_pos = len(np.unique(poses[:, :3], axis=0))
        for s in settings:
            opts = setting_options(base, s)
            p95 = []
            for k in range(args.pairs):
                seeds = (2 * k + 1, 2 * k + 2)
                g, secs, n_short = seed_pair(scene, poses, tags, normals, opts, cfg.frequency_hz, seeds)
                r = noise(g[seeds[0]], g[seeds[1]], thr)
                p95.append(r["p95"])
                print(f"{name} ({len(poses)} poses, {n_pos} positions), setting {s} (min_samples_per_position "
                      f"{opts.min_samples}, completion_min_area_m2 {opts.completion_min_area_m2}), seeds {seeds[0]} vs {seeds[1]}: readable n={r['n']}: "
                      f"p50 {r['p50']:.2f} dB, p95 {r['p95']:.2f} dB; flipped read decisions {r['flips']}; "
                      f"{n_short} positions shot extra rays; {secs:.1f} s per trace", flush=True)
            if args.pairs > 1:
                print(f"  {name}, setting {s}: p95 over {args.pairs} seed pairs: mean {np.mean(p95):.2f} dB, "
                      f"range {min(p95):.2f}-{max(p95):.2f} dB", flush=True)

    if args.study:
        study_times(settings, args.study, args.config)


def study_times(settings: list[str], repeats: int, config: Path | None) -> None:
    """The cold study's wall time per setting (``--set tracing.min_samples_per_position``),
    the settings alternating ``repeats`` times; each run with an empty propagation cache."""
    import tempfile

    from study_trace import run_study  # bench/ is the script's own folder

    walls: dict[str, list[float]] = {s: [] for s in settings if s != "direct"}
    with tempfile.TemporaryDirectory(prefix="seed_noise_study_") as tmp:
        for k in range(repeats):
            for s in walls:
                over = {f"tracing.{k}": v for k, v in setting_overrides(s).items()}
                out = Path(tmp) / f"run_{s}_{k}"
                r = run_study(out, Path(tmp) / f"cache_{s}_{k}", over, config=config)
                walls[s].append(r["wall_s"])
                st = ", ".join(f"{n} {v:.0f}" for n, v in r["stages_s"].items() if v >= 1.0)
                print(f"cold study, setting {s}, run {k + 1}: {r['wall_s']:.0f} s "
                      f"(stages [s]: {st})", flush=True)
    first = next(iter(walls))
    for s, w in walls.items():
        print(f"RATIO cold study {s} / {first}: {np.median(w) / np.median(walls[first]):.3f} "
              f"(medians {np.median(w):.0f} s / {np.median(walls[first]):.0f} s)", flush=True)


if __name__ == "__main__":
    main()
