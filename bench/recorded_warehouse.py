"""A recorded study of the bundled warehouse: import, sim-vs-real and calibration, timed.

The warehouse study (``configs/warehouse.toml``: the ROS map as given, MCL poses) is
simulated up to its reads, exported as a recording (:func:`pipeline.apps.export.export_csv`)
and run as a recorded study with the same config. Prints each recorded stage's wall time
and the run's peak resident memory (the manifest's), and what the calibration found.

    python bench/recorded_warehouse.py [--out /tmp/recorded_warehouse]

``--recalibrate`` reruns, in an earlier ``--out`` (its ``rec/``, ``cache/``, ``recorded/``),
only the stages up to the calibration whose inputs changed (a new calibration: that
stage alone; nothing cached is traced again), and ``--previous`` names an earlier
``calibration.json`` to compare the held-out scores with.

    python bench/recorded_warehouse.py --out /tmp/rwh53 --recalibrate \
        --previous /tmp/rwh/recorded/calibration.json
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
    ap.add_argument("--recalibrate", action="store_true",
                    help="rerun only up to the calibration in an earlier --out (no simulation)")
    ap.add_argument("--previous", type=Path, help="an earlier calibration.json to compare with")
    args = ap.parse_args()
    root = Path(__file__).resolve().parents[1]
    # recalibrating: the earlier run's own config (its paths moved to --out below), so
    # that only what changed since is run again
    cfg = load_config(args.out / "recorded" / "config.toml" if args.recalibrate
                      else root / "configs" / "warehouse.toml")
    cfg = replace_path(cfg, "tracing.cache_dir", str(args.out / "cache"))
    t0 = time.perf_counter()
    if not args.recalibrate:
        run_full_study(cfg, args.out / "sim", command_line=["bench"], upto="reads")
        export_csv(args.out / "sim", args.out / "rec")
    t_sim = time.perf_counter() - t0
    rec = cfg
    for key, name in (("recording.tags", "tags.csv"), ("recording.poses", "poses.csv"),
                      ("recording.reads", "reads.csv")):
        rec = replace_path(rec, key, str(args.out / "rec" / name))
    t0 = time.perf_counter()
    res = run_full_study(rec, args.out / "recorded", command_line=["bench"],
                         upto="calibration" if args.recalibrate else None)
    t_rec = time.perf_counter() - t0
    man = json.loads((args.out / "recorded" / "manifest.json").read_text())
    print("warehouse (configs/warehouse.toml): " + (
        "recalibrated" if args.recalibrate else f"simulated to its reads and exported in {t_sim:.0f} s;")
        + f" recorded study {t_rec:.0f} s, peak RSS {man.get('peak_rss_mib', float('nan')):.0f} MiB")
    for name, st in man["stages"].items():
        cached = " (cached)" if name in res.cached else ""
        print(f"  {name:14s} {st.get('elapsed_s', float('nan')):7.1f} s{cached}")
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
    runs = [("this run", cal)]
    if args.previous is not None:
        runs.append((f"previous ({args.previous})", json.loads(args.previous.read_text())))
    print("held-out scores (before -> after calibration, the paired verdict):")
    for name, c in runs:
        print(f"  {name}:")
        for key in ("rssi_mae_db", "rssi_bias_db", "rssi_rmse_db", "brier", "read_rate_mae"):
            v = c["heldout"].get(key)
            if isinstance(v, dict):
                print(f"    {v.get('label', key):28s} {v['before']['estimate']:8.4g} -> "
                      f"{v['after']['estimate']:8.4g}  ({v['difference']['verdict']})")
        for where in ("crossvalidated", "heldout"):  # the choice, then its check
            vs = c.get("constructions", {}).get(f"{where}_against_reader_only", {})
            for key, v in vs.items():
                if isinstance(v, dict):
                    print(f"    constructions vs reader alone, {where}, {key}: "
                          f"{v['with_constructions']['estimate']:.4g} vs "
                          f"{v['reader_only']['estimate']:.4g} ({v['difference']['verdict']})")
        print(f"    constructions in calibrated.toml: {c.get('constructions', {}).get('in_calibrated_toml')}")


if __name__ == "__main__":
    main()
