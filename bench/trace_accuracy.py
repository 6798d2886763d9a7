"""The study's tracer and bare Sionna at a few ray counts, against bare Sionna at many rays.

``bench/study_trace.py`` compares the study's time with bare Sionna tracing the same links
at the config's ``tracing.samples_per_src``. This bench says what each is worth: on a
sample of a finished run's training-tour antenna positions (``--groups`` runs of
``--consecutive`` positions, spread along the tour) and all the run's tags, it traces

- a reference: bare Sionna (``tracing.method = "direct"``: the ``PathSolver`` alone, no
  completion) at ``--reference-rays``, twice (seeds 7 and 8): the reference's own noise;
  ``REFERENCE_TAGS`` tags per call, as ``PathSolver`` keeps at most ``rays * (depth + 1)``
  candidates per source, one for every chain and target it sees (hundreds of tags overflow
  it and lose paths without a word; the study's tracer shoots such a call again);
- the study's tracer with the run's ``[tracing]`` options (seeds 1 and 2), at the sampled
  positions and every tour position within ``tracing.share_radius_m`` of them (the
  neighbours whose rays it shares on the tour; its time is per position traced);
- bare Sionna at each of ``--rays`` (seeds 1 and 2), ``REFERENCE_TAGS`` tags per call as
  the reference, within its cap (``bench/study_trace.py --naive-cap sionna`` traces all
  tags in one call with Sionna's default cap instead: the same rays, another batching of
  the chain hashes); ``--bare-tags-per-call 0``: all tags at once within a cap of rays x
  (depth + 1), as that bench's naive side calls it by default, which drops paths with
  hundreds of tags,

each from an empty path cache, after one untimed trace of two positions with the same
settings (Dr.Jit bakes the ray count into its kernels), with the run's patterns and tag
normals (``propagation.trace_links``). It prints per tracer the seconds per antenna
position and, over the sampled positions' links: p50 / p95 |gain - reference| over the
links readable in the reference (gain >= the reader's minimum readable gain), how many of
those it finds more than 6 dB weaker / stronger, and the read decisions flipped against
the reference over all links (readable in one and not in the other). The reference is not
the truth: its own seed-to-seed flips are its floor, and rays miss what the study's
image-method completion enumerates.

The independent units are the runs of positions (``--groups``: tags of one position, and
positions a few centimetres apart, are not independent). Per bare-Sionna ray count it
prints the flipped read decisions per position, mean over both seeds, of the study's
tracer and of bare Sionna, and their paired difference (bare - study) with a 95 % BCa
bootstrap interval over the runs (``scipy.stats.bootstrap``, 9,999 resamples): bare
Sionna flips more than the study's tracer only where the interval lies above 0.

Usage::

    .venv/bin/python bench/trace_accuracy.py RUN_DIR [--groups 3] [--consecutive 4]
        [--reference-rays 100000] [--rays 2000,8000,32000] [--bare-tags-per-call 0]
        [--study-option completion_min_area_m2=0.1]
"""

from __future__ import annotations

import argparse
import tempfile
import time
import warnings
from pathlib import Path

import numpy as np
import pandas as pd

from pipeline import runfiles

#: Tags per reference call (bare Sionna's candidate cap is per source, for all its targets).
REFERENCE_TAGS = 32


def tour_poses(run: Path) -> np.ndarray:
    """The run's distinct training-tour antenna poses in tour order, (k, 4): x, y, z [m],
    yaw [rad]."""
    r = pd.read_parquet(run / runfiles.TRAIN_READS)
    cols = ["true_ant_x_m", "true_ant_y_m", "true_ant_z_m", "true_ant_yaw_rad"]
    return r.drop_duplicates(cols[:3])[cols].to_numpy(float)


def sample_rows(n_poses: int, groups: int, consecutive: int) -> np.ndarray:
    """Rows of ``groups`` runs of ``consecutive`` poses spread evenly along a tour of
    ``n_poses``, (groups * consecutive,) int."""
    if n_poses < consecutive:
        raise SystemExit(f"{n_poses} antenna positions, fewer than --consecutive {consecutive}")
    starts = np.linspace(0, n_poses - consecutive, groups).round().astype(int)
    return np.unique(np.concatenate([np.arange(s, s + consecutive) for s in starts]))


def flips_per_group(gain_db: np.ndarray, ref_db: np.ndarray, threshold_db: float,
                    groups: int) -> np.ndarray:
    """Read decisions flipped against the reference per position, mean over each run of
    positions, (groups,) float; rows of ``gain_db`` in run order, runs of equal length."""
    flips = ((gain_db >= threshold_db) != (ref_db >= threshold_db)).sum(axis=1)
    return flips.reshape(groups, -1).mean(axis=1)


def paired_interval(diff: np.ndarray, seed: int = 0) -> tuple[float, float]:
    """95 % BCa bootstrap interval of the mean of per-run differences (``scipy.stats``);
    (nan, nan) where every difference is equal (no spread to resample)."""
    from scipy.stats import bootstrap

    if np.ptp(diff) == 0:
        return float("nan"), float("nan")
    res = bootstrap((diff,), np.mean, n_resamples=9999, confidence_level=0.95,
                    method="BCa", random_state=np.random.default_rng(seed))
    return float(res.confidence_interval.low), float(res.confidence_interval.high)


def compare_row(gain_db: np.ndarray, ref_db: np.ndarray, threshold_db: float) -> str:
    """|gain - reference| [dB] over the reference's readable links (p50, p95, how many more
    than 6 dB weaker / stronger) and the read decisions flipped against the reference over
    all links."""
    readable = ref_db >= threshold_db
    flips = int(((gain_db >= threshold_db) != readable).sum())
    if not readable.any():
        return f"no link readable in the reference; flipped read decisions {flips}"
    with np.errstate(invalid="ignore"):
        delta = (gain_db - ref_db)[readable]  # -inf where the tracer found no path
    d = np.abs(delta)
    # "higher": an observed |delta| (inf where no path), never an interpolation with inf
    p50, p95 = (np.percentile(d, q, method="higher") for q in (50, 95))
    return (f"p50 {p50:.2f} dB, p95 {p95:.2f} dB, {int((delta < -6).sum())} weaker / "
            f"{int((delta > 6).sum())} stronger by > 6 dB; flipped read decisions {flips}")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("run", type=Path, help="a finished run directory (its config, tags and tour)")
    ap.add_argument("--groups", type=int, default=3)
    ap.add_argument("--consecutive", type=int, default=4)
    ap.add_argument("--reference-rays", type=int, default=100_000)
    ap.add_argument("--rays", default="2000,8000,32000", help="bare Sionna's ray counts, comma-separated")
    ap.add_argument("--study-option", action="append", default=[], metavar="NAME=VALUE",
                    help="a TraceOptions field of the study's tracer set to VALUE (its type), e.g. "
                         "completion_min_area_m2=0.1; repeatable")
    ap.add_argument("--bare-tags-per-call", type=int, default=REFERENCE_TAGS,
                    help=f"tags per bare-Sionna call: {REFERENCE_TAGS} (default) within its cap, as the "
                         "reference; 0: all at once, as bench/study_trace.py's naive side by default "
                         "(drops paths with hundreds of tags)")
    args = ap.parse_args()
    warnings.simplefilter("ignore")
    import propagation as P
    import scenes
    from pipeline.config import load_config
    from pipeline.studyscene import preferred_backend, trace_options

    cfg = load_config(args.run / "config.toml")
    P.select_variant(prefer=preferred_backend(cfg.tracing))
    sc = scenes.load(cfg.scene)
    tags = pd.read_parquet(args.run / runfiles.SCENE_TAGS)
    tpos = tags[["x_m", "y_m", "z_m"]].to_numpy(float)
    tnrm = tags[["nx", "ny", "nz"]].to_numpy(float)
    tour = tour_poses(args.run)
    rows = sample_rows(len(tour), args.groups, args.consecutive)
    starts = rows[::args.consecutive]
    if len(rows) != args.groups * args.consecutive or np.any(np.diff(starts) <= args.consecutive):
        raise SystemExit(f"runs of {args.consecutive} positions touch or overlap on a tour of "
                         f"{len(tour)}: fewer --groups (the runs are the independent units)")
    if args.groups < 8:
        print(f"note: {args.groups} runs of positions are too few for a bootstrap interval worth "
              "its name (--groups 8 or more)")
    if args.bare_tags_per_call < 0:
        raise SystemExit(f"--bare-tags-per-call must be >= 0, got {args.bare_tags_per_call}")
    poses = tour[rows]
    # the study's tracer shares rays with the tour's positions within its radius
    near = np.linalg.norm(tour[:, None, :3] - poses[None, :, :3], axis=2).min(axis=1)
    context = np.union1d(rows, np.flatnonzero(near <= cfg.tracing.share_radius_m))
    at = np.searchsorted(context, rows)
    thr = cfg.reader.link_budget(cfg.frequency_hz).min_gain_db()
    base = trace_options(cfg)
    for item in args.study_option:
        name, _, value = item.partition("=")
        if not hasattr(base, name) or not value:
            raise SystemExit(f"--study-option {item!r}: expected NAME=VALUE with a TraceOptions field")
        base = base.replace(**{name: type(getattr(base, name))(value)})
    direct = trace_options(cfg).replace(method="direct")

    def gains(opts, traced: np.ndarray, warm: bool = False,
              tags_per_call: int | None = None) -> tuple[np.ndarray, float]:
        if warm:  # kernels of these settings built outside the timing
            gains(opts, traced[:2], tags_per_call=tags_per_call)
        step = tags_per_call or len(tpos)
        out = []
        t0 = time.perf_counter()
        for c0 in range(0, len(tpos), step):
            with tempfile.TemporaryDirectory() as cd:
                links = P.trace_links(sc, traced, tpos[c0:c0 + step], opts, tag_normals=tnrm[c0:c0 + step],
                                      cache_dir=cd, frequency_hz=cfg.frequency_hz)
            out.append(np.asarray(links.gain_db, float))
        return np.concatenate(out, axis=1), (time.perf_counter() - t0) / len(traced)

    # the reference in calls of REFERENCE_TAGS tags: PathSolver keeps at most rays x
    # (depth + 1) candidates per source, one per chain and target it sees
    ref_opts = direct.replace(samples_per_src=args.reference_rays)
    ref, t_ref = gains(ref_opts.replace(seed=7), poses, warm=True, tags_per_call=REFERENCE_TAGS)
    ref2, _ = gains(ref_opts.replace(seed=8), poses, tags_per_call=REFERENCE_TAGS)
    print(f"{cfg.scene}: {len(poses)} antenna positions ({args.groups} runs of {args.consecutive}) x "
          f"{len(tpos)} tags; readable: gain >= {thr:.2f} dB, {int((ref >= thr).sum())} links in the "
          f"reference (bare Sionna, {args.reference_rays} rays, {t_ref:.2f} s per position)")
    print(f"  reference seed 8 vs seed 7: {compare_row(ref2, ref, thr)}", flush=True)
    tracers = [(f"study tracer ({base.method}, {base.shared_samples_per_src} rays per position shared "
                f"over {len(context)} positions, completion order "
                f"{min(base.completion_order, base.max_depth)}, planes >= "
                f"{base.completion_min_area_m2:g} m^2)", base, tour[context], at, None)]
    bare = args.bare_tags_per_call or None
    tracers += [(f"bare Sionna, {int(n)} rays{f', {bare} tags per call' if bare else ''}",
                 direct.replace(samples_per_src=int(n)), poses, np.arange(len(poses)), bare)
                for n in args.rays.split(",")]
    per_group = {}
    for name, opts, traced, pick, per_call in tracers:
        per_group[name] = []
        for seed in (1, 2):
            g, t = gains(opts.replace(seed=seed), traced, warm=seed == 1, tags_per_call=per_call)
            per_group[name].append(flips_per_group(g[pick], ref, thr, args.groups))
            print(f"  {name}, seed {seed}: {t:.2f} s per position; {compare_row(g[pick], ref, thr)}",
                  flush=True)
    study = np.mean(per_group[tracers[0][0]], axis=0)
    print(f"flipped read decisions per position, mean of seeds 1 and 2; paired over the {args.groups} "
          "runs of positions, 95 % BCa bootstrap interval of bare - study:")
    for name, *_ in tracers[1:]:
        other = np.mean(per_group[name], axis=0)
        lo, hi = paired_interval(other - study)
        print(f"  {name}: {other.mean():.2f} against the study tracer's {study.mean():.2f}; "
              f"difference {np.mean(other - study):+.2f} [{lo:+.2f}, {hi:+.2f}]", flush=True)


if __name__ == "__main__":
    main()
