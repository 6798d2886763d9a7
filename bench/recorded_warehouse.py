"""A recorded study of the bundled warehouse: import, sim-vs-real and calibration, timed.

The warehouse study (``configs/warehouse.toml``: the ROS map as given, MCL poses) is
simulated up to its reads, exported as a recording (:func:`pipeline.apps.export.export_csv`)
and run as a recorded study with the same config. Prints each recorded stage's wall time
and the run's peak resident memory (the manifest's), and what the calibration found.

    python bench/recorded_warehouse.py [--out /tmp/recorded_warehouse]
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

from pipeline import runfiles


def main() -> None:
    from pipeline.apps.export import export_csv
    from pipeline.apps.studyrun import run_full_study
    from pipeline.config import load_config, replace_path

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", type=Path, default=Path("/tmp/recorded_warehouse"))
    args = ap.parse_args()
    root = Path(__file__).resolve().parents[1]
    cfg = load_config(root / "configs" / "warehouse.toml")
    cfg = replace_path(cfg, "tracing.cache_dir", str(args.out / "cache"))
    t0 = time.perf_counter()
    run_full_study(cfg, args.out / "sim", command_line=["bench"], upto="reads")
    export_csv(args.out / "sim", args.out / "rec")
    t_sim = time.perf_counter() - t0
    rec = cfg
    for key, name in (("recording.tags", "tags.csv"), ("recording.poses", "poses.csv"),
                      ("recording.reads", "reads.csv")):
        rec = replace_path(rec, key, str(args.out / "rec" / name))
    t0 = time.perf_counter()
    run_full_study(rec, args.out / "recorded", command_line=["bench"])
    t_rec = time.perf_counter() - t0
    man = json.loads((args.out / "recorded" / "manifest.json").read_text())
    print(f"warehouse (configs/warehouse.toml): simulated to its reads and exported in {t_sim:.0f} s; "
          f"recorded study {t_rec:.0f} s, peak RSS {man.get('peak_rss_mib', float('nan')):.0f} MiB")
    for name, st in man["stages"].items():
        print(f"  {name:14s} {st.get('elapsed_s', float('nan')):7.1f} s")
    cal = json.loads((args.out / "recorded" / runfiles.CALIBRATION).read_text())
    imp = json.loads((args.out / "recorded" / runfiles.METRICS).read_text())["recording"]
    print(f"import: {imp.get('n_reads')} reads of {imp.get('n_tags', '?')} tags")
    cons = cal.get("constructions", {})
    print(f"constructions: power share {cons.get('power_share')}; converged {cons.get('converged')}; "
          f"in calibrated.toml: {cons.get('in_calibrated_toml')}")
    for k, v in cal["parameters"].items():
        lo, hi = v.get("low"), v.get("high")
        iv = f"[{lo:.3g}, {hi:.3g}]" if lo is not None and hi is not None else ""
        print(f"  {k:44s} {v['value']:9.4g} {iv}")
    h = cal["heldout"]["rssi_mae_db"]
    print(f"held-out RSSI MAE before {h['before']['estimate']:.2f} dB, after {h['after']['estimate']:.2f} dB "
          f"({h['difference']['verdict']}; {h['n_tags']} tags)")


if __name__ == "__main__":
    main()
