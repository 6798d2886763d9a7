"""Real maps as given: `scenes show` and the default `rfidstudy run MAP.yaml` on each map of
data/real_maps, timed, with peak memory and what the study then measures.

    python bench/real_maps.py                       # scenes show on every map (seconds)
    python bench/real_maps.py --run --out runs/real # and the default study on each (minutes)
    python bench/real_maps.py nav2_warehouse --run  # one map

For each map it prints: the wall time and peak memory of ``rfidstudy scenes show MAP``
(a fresh process, so imports included), racks, radio surfaces, tags and tags skipped by
the route; with ``--run``, the wall time and peak memory of ``rfidstudy run MAP --out``
(a cold run directory; the propagation cache is the user's, ``--cache DIR`` names a fresh
one), whether it completed, the training tour's read rate, and how many held-out tags
sit on a hand-labelled rack face (within 0.1 m of a labelled rectangle's outline).

Memory is the process tree's summed proportional set size (psutil, sampled every 0.5 s):
shared pages counted once across the study's processes.
"""

from __future__ import annotations

import argparse
import json
import re
import subprocess
import sys
import time
import tomllib
from pathlib import Path

import psutil

from pipeline import runfiles

ROOT = Path(__file__).resolve().parents[1]
MAPS = ROOT / "data" / "real_maps"


def _tree_pss(proc: psutil.Process) -> int:
    total = 0
    for p in [proc, *proc.children(recursive=True)]:
        try:
            total += p.memory_full_info().pss
        except (psutil.NoSuchProcess, psutil.AccessDenied):
            pass
    return total


def timed(cmd: list[str], env=None) -> tuple[int, float, int, str]:
    """(return code, wall seconds, peak summed PSS bytes, stdout+stderr) of a command."""
    t0 = time.perf_counter()
    proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True,
                            cwd=ROOT, env=env)
    ps = psutil.Process(proc.pid)
    peak = 0
    out: list[str] = []
    import threading

    reader = threading.Thread(target=lambda: out.append(proc.stdout.read()), daemon=True)
    reader.start()
    while proc.poll() is None:
        peak = max(peak, _tree_pss(ps))
        time.sleep(0.5)
    reader.join()
    return proc.returncode, time.perf_counter() - t0, peak, "".join(out)


def held_out_on_racks(run: Path, labels: Path) -> tuple[int, int]:
    """(held-out tags within 0.1 m of a labelled rack's outline, held-out tags)."""
    import pandas as pd
    import shapely

    tags = pd.read_parquet(run / runfiles.SCENE_TAGS)
    held = tags[tags["split"] == "eval"]
    boxes = tomllib.loads(labels.read_text())["racks"]
    if not boxes:
        return 0, len(held)
    racks = shapely.union_all([shapely.box(*b) for b in boxes])
    d = shapely.distance(racks.boundary, shapely.points(held[["x_m", "y_m"]].to_numpy()))
    return int((d <= 0.1).sum()), len(held)


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("maps", nargs="*", help="folders of data/real_maps (default: all)")
    ap.add_argument("--run", action="store_true", help="also run the default study on each map")
    ap.add_argument("--out", type=Path, default=ROOT / "runs" / "real_maps",
                    help="parent of the run directories (each must not exist yet)")
    ap.add_argument("--cache", type=Path, default=None,
                    help="propagation cache for the runs (default: the user's)")
    args = ap.parse_args(argv)
    exe = str(Path(sys.executable).with_name("rfidstudy"))
    names = args.maps or sorted(p.name for p in MAPS.iterdir() if p.is_dir())
    for name in names:
        folder = MAPS / name
        yaml = next(folder.glob("*.yaml"))
        rc, wall, peak, text = timed([exe, "scenes", "show", str(yaml)])
        field = {k: re.search(rf"^  {k}: ([^\n]*)", text, re.MULTILINE)
                 for k in ("tags", "radio surfaces", "map", "planned route")}
        skipped = sum(int(m) for m in re.findall(r"skipped (\d+) tags", text))
        print(f"{name}: scenes show rc {rc}, {wall:.1f} s, peak {peak / 2**20:,.0f} MiB")
        for k, m in field.items():
            print(f"  {k}: {m.group(1) if m else '-'}")
        print(f"  tags skipped by the route: {skipped}")
        if not args.run:
            continue
        run = args.out / name
        cmd = [exe, "run", str(yaml), "--out", str(run)]
        if args.cache is not None:
            cmd += ["--set", f"tracing.cache_dir={json.dumps(str(args.cache))}"]
        rc, wall, peak, text = timed(cmd)
        print(f"  rfidstudy run: rc {rc}, {wall / 60:.1f} min, peak {peak / 2**30:.2f} GiB")
        if rc != 0:
            print("  " + "\n  ".join(text.strip().splitlines()[-3:]))
            continue
        from pipeline.stages.summary import run_summary

        row = run_summary(run)
        on, n = held_out_on_racks(run, folder / "labels.toml")
        print(f"  read rate {row['read_rate']:.4f} ({row['n_reads']:,} reads / "
              f"{row['n_attempts_in_range']:,} in-range attempts); held-out tags on a labelled "
              f"rack face: {on} of {n}")


if __name__ == "__main__":
    main()
