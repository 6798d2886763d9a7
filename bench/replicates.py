"""Time, memory and shared traces of a replicated study (pipeline.apps.replicates).

Runs a study config with ``replicates.n`` replicates one after the other (``workers =
1``, so that the propagation cache can be counted between them) into a fresh run
directory with its own propagation cache (empty unless ``--cache`` names a filled
one), and prints per replicate: its wall time and peak memory (its manifest), the
links (antenna position x tag) it added to the cache, and how many it found there
(the links replicate 0 traced into the empty cache, less those replicate k added: the
replicates' tours differ, so only the shared scene's traces are shared).

    python -m bench.replicates --config configs/replicated.toml --out /tmp/rep --cache /tmp/rep-cache
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path


def cache_links(cache_dir: Path) -> tuple[int, int]:
    """(antenna positions, links) held by a propagation cache (every settings folder)."""
    best: dict[tuple[str, str], int] = {}
    for js in Path(cache_dir).glob("*/pack-*.json"):
        meta = json.loads(js.read_text())
        for key, n in zip(meta["keys"], meta["n_tags"], strict=True):
            k = (js.parent.name, key)
            best[k] = max(best.get(k, 0), int(n))
    return len(best), sum(best.values())


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--config", default="configs/replicated.toml")
    ap.add_argument("--out", required=True, help="run directory (new)")
    ap.add_argument("--cache", required=True, help="propagation cache directory")
    ap.add_argument("-n", type=int, default=None, help="replicates (default: the config's)")
    args = ap.parse_args(argv)

    from pipeline.apps.replicates import replicate_configs
    from pipeline.apps.studypool import run_point
    from pipeline.apps.studyrun import run_full_study
    from pipeline.config import config_to_dict, load_config, replace_path

    cfg = load_config(args.config)
    if args.n:
        cfg = replace_path(cfg, "replicates.n", args.n)
    cfg = replace_path(cfg, "tracing.cache_dir", str(Path(args.cache).resolve()))
    out = Path(args.out)
    rows = []
    t_all = time.perf_counter()
    _, links0 = cache_links(cfg.tracing.cache_dir) if Path(args.cache).is_dir() else (0, 0)
    # the replicates one by one into the run directory's replicates/<k>/, counting the cache
    for k, c in enumerate(replicate_configs(cfg)):
        t0 = time.perf_counter()
        row = run_point(config_to_dict(c), str(out / "replicates" / str(k)), "bench")
        _, links = cache_links(cfg.tracing.cache_dir)
        man = json.loads((out / "replicates" / str(k) / "manifest.json").read_text())
        rows.append({"k": k, "seed": c.seed, "status": row["status"],
                     "wall_s": round(time.perf_counter() - t0, 1),
                     "peak_rss_mib": man.get("peak_rss_mib"), "links_added": links - links0})
        links0 = links
        print(json.dumps(rows[-1]), flush=True)
    # then the study itself: every replicate cached, the pooled numbers and the report
    t0 = time.perf_counter()
    # (force_dir: the folder holds only the replicates run above, not yet a run directory)
    res = run_full_study(cfg, out, progress=False, command_line=["bench.replicates"],
                         force_dir=True)
    pooled_s = time.perf_counter() - t0
    first = rows[0]["links_added"]
    print(json.dumps({
        "replicates": len(rows), "total_wall_s": round(time.perf_counter() - t_all, 1),
        "pooling_s": round(pooled_s, 1), "stages_run": res.ran,
        "peak_rss_mib_max": max(r["peak_rss_mib"] or 0 for r in rows),
        "links_replicate_0": first,
        "links_found_in_cache": {r["k"]: first - r["links_added"] for r in rows[1:]},
    }, indent=1))


if __name__ == "__main__":
    main()
