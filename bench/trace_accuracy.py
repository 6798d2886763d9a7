"""The study's tracer and bare Sionna at a few ray counts, against bare Sionna at many rays.

``bench/study_trace.py`` compares the study's time with bare Sionna tracing the same links
at the config's ``tracing.samples_per_src``. This bench says what each is worth: on a
sample of a finished run's training-tour antenna positions (``--groups`` runs of
``--consecutive`` positions, so the study's positions share rays as on the tour) and all
the run's tags, it traces

- a reference: bare Sionna (``tracing.method = "direct"``: the ``PathSolver`` alone, no
  completion) at ``--reference-rays``, twice (seeds 7 and 8): the reference's own noise;
- the study's tracer with the run's ``[tracing]`` options (seeds 1 and 2);
- bare Sionna at each of ``--rays`` (seeds 1 and 2),

each from an empty path cache, with the run's patterns and tag normals
(``propagation.trace_links``), and prints per tracer the seconds per antenna position and,
over the links readable in the reference (gain >= the reader's minimum readable gain),
p50 / p95 |gain - reference| and the read decisions flipped against it (readable in one,
not in the other). The reference is not the truth: rays miss what the study's image-method
completion enumerates (a tag a few mm in front of a metal face and its image, which
nearly cancel), and its own seed-to-seed flips are its floor.

Usage::

    .venv/bin/python bench/trace_accuracy.py RUN_DIR [--groups 3] [--consecutive 4]
        [--reference-rays 100000] [--rays 2000,8000,32000]
"""

from __future__ import annotations

import argparse
import tempfile
import time
import warnings
from pathlib import Path

import numpy as np
import pandas as pd


def sample_poses(run: Path, groups: int, consecutive: int) -> np.ndarray:
    """``groups`` runs of ``consecutive`` distinct training-tour antenna poses
    (x, y, z, yaw), spread evenly along the tour, (groups * consecutive, 4)."""
    r = pd.read_parquet(run / "reads.parquet")
    cols = ["true_ant_x_m", "true_ant_y_m", "true_ant_z_m", "true_ant_yaw_rad"]
    poses = r.drop_duplicates(cols[:3])[cols].to_numpy(float)
    if len(poses) < consecutive:
        raise SystemExit(f"{run}: {len(poses)} antenna positions, fewer than --consecutive {consecutive}")
    starts = np.linspace(0, len(poses) - consecutive, groups).round().astype(int)
    return np.concatenate([poses[s:s + consecutive] for s in starts])


def compare_row(gain_db: np.ndarray, ref_db: np.ndarray, threshold_db: float) -> str:
    """p50 / p95 |gain - reference| over the reference's readable links, and the read
    decisions flipped against the reference."""
    readable = ref_db >= threshold_db
    with np.errstate(invalid="ignore"):
        d = np.abs(gain_db - ref_db)[readable]
    flips = int(((gain_db >= threshold_db) != readable).sum())
    # "higher": an observed |delta|, inf where the tracer found no path for the link
    p50, p95 = (np.percentile(d, q, method="higher") for q in (50, 95))
    return (f"p50 {p50:.2f} dB, p95 {p95:.2f} dB; "
            f"flipped read decisions {flips}")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("run", type=Path, help="a finished run directory (its config, tags and tour)")
    ap.add_argument("--groups", type=int, default=3)
    ap.add_argument("--consecutive", type=int, default=4)
    ap.add_argument("--reference-rays", type=int, default=100_000)
    ap.add_argument("--rays", default="2000,8000,32000", help="bare Sionna's ray counts, comma-separated")
    args = ap.parse_args()
    warnings.simplefilter("ignore")
    import propagation as P
    import scenes
    from pipeline.config import load_config
    from pipeline.stages.common import trace_options

    cfg = load_config(args.run / "config.toml")
    P.select_variant(prefer="llvm" if cfg.tracing.deterministic else "auto")
    sc = scenes.load(cfg.scene)
    tags = pd.read_parquet(args.run / "scene" / "tags.parquet")
    tpos = tags[["x_m", "y_m", "z_m"]].to_numpy(float)
    tnrm = tags[["nx", "ny", "nz"]].to_numpy(float)
    poses = sample_poses(args.run, args.groups, args.consecutive)
    thr = cfg.reader.link_budget(cfg.frequency_hz).min_gain_db()
    base = trace_options(cfg)

    def gains(opts) -> tuple[np.ndarray, float]:
        with tempfile.TemporaryDirectory() as cd:
            t0 = time.perf_counter()
            links = P.trace_links(sc, poses, tpos, opts, tag_normals=tnrm, cache_dir=cd,
                                  frequency_hz=cfg.frequency_hz)
            return np.asarray(links.gain_db, float), (time.perf_counter() - t0) / len(poses)

    direct = base.replace(method="direct")
    # kernels compiled outside the timings (two poses, each tracer)
    for o in (base, direct):
        with tempfile.TemporaryDirectory() as cd:
            P.trace_links(sc, poses[:2], tpos, o, tag_normals=tnrm, cache_dir=cd, frequency_hz=cfg.frequency_hz)
    ref, t_ref = gains(direct.replace(samples_per_src=args.reference_rays, seed=7))
    ref2, _ = gains(direct.replace(samples_per_src=args.reference_rays, seed=8))
    print(f"{cfg.scene}: {len(poses)} antenna positions ({args.groups} runs of {args.consecutive}) x "
          f"{len(tpos)} tags; readable: gain >= {thr:.2f} dB, {int((ref >= thr).sum())} links in the reference "
          f"(bare Sionna, {args.reference_rays} rays, {t_ref:.2f} s per position)")
    print(f"  reference seed 8 vs seed 7: {compare_row(ref2, ref, thr)}", flush=True)
    rows = [(f"study tracer ({base.method}, {base.shared_samples_per_src} rays per position shared, "
             f"completion order {min(base.completion_order, base.max_depth)})", base)]
    rows += [(f"bare Sionna, {int(n)} rays", direct.replace(samples_per_src=int(n)))
             for n in args.rays.split(",")]
    for name, opts in rows:
        for seed in (1, 2):
            g, t = gains(opts.replace(seed=seed))
            print(f"  {name}, seed {seed}: {t:.2f} s per position; {compare_row(g, ref, thr)}", flush=True)


if __name__ == "__main__":
    main()
