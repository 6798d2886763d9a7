"""What trace reuse saves a placement study: the grid as it runs against the same
candidates run as independent cold studies, measured in one run.

1. The placement file's candidates (grid and presets; the optimiser is left out, its
   trials depend on the values) run as ``rfidstudy placement`` runs them, one study at a
   time, into ``OUT/shared`` with a fresh propagation cache of their own that all the
   studies share (``OUT/shared-cache``, empty at the start).
2. The same (candidate, replicate) studies, with the same configs and seeds, run one by
   one as independent studies into ``OUT/cold/<name>/<k>``, each with its own empty
   propagation cache: what a user running them as separate studies would pay.

Both halves run one study at a time (``workers = 1``), so the ratio compares the work,
not the parallelism. One untimed warm-up study (the first candidate's replicate 0, its
own cache) runs first, so that neither half pays the process's first imports and the
Dr.Jit kernels' compilation. Run it on an otherwise idle machine: a second job on the
cores makes the two halves' times incomparable. Prints per candidate the time and the antenna
positions traced afresh in each half, and the ratio of the totals.

    python bench/placement_reuse.py --placement configs/placement_example.toml --out /tmp/reuse
"""

from __future__ import annotations

import argparse
import dataclasses
import time
from pathlib import Path


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--placement", default="configs/placement_example.toml")
    ap.add_argument("--out", required=True, help="new directory for both halves")
    args = ap.parse_args(argv)

    from pipeline.apps.placement import load_placement, run_placement
    from pipeline.apps.placement.candidates import candidates_of
    from pipeline.apps.placement.objectives import traced_counts
    from pipeline.apps.placement.runner import _replicate_config
    from pipeline.apps.studypool import run_point
    from pipeline.config import config_to_dict, replace_path

    out = Path(args.out).resolve()
    if out.exists() and any(out.iterdir()):
        raise SystemExit(f"--out {out}: must be new or empty (both halves start cold)")
    spec = load_placement(args.placement)
    shared_cache = out / "shared-cache"
    base = replace_path(spec.base, "tracing.cache_dir", str(shared_cache))
    settings = dataclasses.replace(spec.settings, workers=1,
                                   optimise=dataclasses.replace(spec.settings.optimise,
                                                                n_trials=0))
    spec = dataclasses.replace(spec, base=base, settings=settings)
    cands = candidates_of(spec)
    n = spec.settings.replicates
    print(f"{len(cands)} candidates x {n} replicates = {len(cands) * n} studies, one at a time")

    warm = time.perf_counter()
    row = run_point(config_to_dict(_replicate_config(spec, cands[0], 0, str(out / "warmup-cache"))),
                    str(out / "warmup"), "bench")
    if row.get("status") != "complete":
        raise SystemExit(f"warm-up study failed: {row.get('error')}")
    print(f"warm-up study (untimed in the ratio): {time.perf_counter() - warm:.1f} s")

    shared_s: dict[str, float] = {}

    def on_progress(ev):
        shared_s[ev.candidate] = ev.elapsed_s
        print(f"  shared  {ev.candidate:<22} {ev.elapsed_s:7.1f} s  "
              f"{ev.n_sources_traced:6d} positions traced", flush=True)

    t0 = time.perf_counter()
    run_placement(spec, out / "shared", workers=1, progress=on_progress)
    shared_wall = time.perf_counter() - t0
    shared_traced = {c.name: sum(traced_counts(out / "shared" / "candidates" / c.name / str(k))
                                 ["n_sources_traced"] for k in range(n)) for c in cands}

    cold_s: dict[str, float] = {}
    cold_traced: dict[str, int] = {}
    t1 = time.perf_counter()
    for c in cands:
        t = time.perf_counter()
        traced = 0
        for k in range(n):
            run_dir = out / "cold" / c.name / str(k)
            cfg = _replicate_config(spec, c, k, str(out / "cold-cache" / c.name / str(k)))
            row = run_point(config_to_dict(cfg), str(run_dir), "bench")
            if row.get("status") != "complete":
                raise SystemExit(f"cold study {c.name}/{k} failed: {row.get('error')}")
            traced += traced_counts(run_dir)["n_sources_traced"]
        cold_s[c.name] = time.perf_counter() - t
        cold_traced[c.name] = traced
        print(f"  cold    {c.name:<22} {cold_s[c.name]:7.1f} s  {traced:6d} positions traced",
              flush=True)
    cold_wall = time.perf_counter() - t1

    print()
    print(f"{'candidate':<22} {'shared s':>9} {'traced':>7} {'cold s':>8} {'traced':>7}")
    for c in cands:
        print(f"{c.name:<22} {shared_s.get(c.name, float('nan')):9.1f} "
              f"{shared_traced[c.name]:7d} {cold_s[c.name]:8.1f} {cold_traced[c.name]:7d}")
    print(f"whole placement study (grid, summary, figures, report): {shared_wall:.1f} s; "
          f"its studies: {sum(shared_s.values()):.1f} s")
    print(f"the same studies as independent cold studies: {cold_wall:.1f} s")
    print(f"placement study vs independent cold studies = {shared_wall / cold_wall:.2f}x "
          f"(antenna positions traced {sum(shared_traced.values())} vs "
          f"{sum(cold_traced.values())})")


if __name__ == "__main__":
    main()
