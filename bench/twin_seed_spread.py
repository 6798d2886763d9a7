"""The calibration twin's truth against itself: how well can any calibration do?

``bench/calibration_twin.py`` plants differences in a simulated building and calibrates
the unchanged one to its recording. Its held-out RSSI MAE after calibration is worth what
the truth's own seed-to-seed spread allows: the planted building itself, traced again
with another tracer seed (a fresh propagation cache: independent ray samples), predicts the
recorded reads no better than that. This script traces the planted twin's recording so
(the recorded study up to ``sim_vs_real`` with the planted config, seed + 1), prints how far
its gains are from the planted simulation's own trace, and scores its RSSI prediction on
the held-out tags of the twin's calibration (the same tags, the same metric,
:func:`pipeline.evaluation.simreal.sim_vs_real`, with its tag-bootstrap interval), beside
the calibrated model's held-out MAE from ``calibration.json``.

    python bench/twin_seed_spread.py [--twin /tmp/calibration_twin/true_poses] [--out DIR]
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import time
from pathlib import Path

from pipeline import runfiles


def main() -> None:
    import numpy as np
    import pandas as pd

    from pipeline.apps.studyrun import run_full_study
    from pipeline.config import load_config, replace_path
    from pipeline.evaluation.simreal import sim_vs_real

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--twin", type=Path, default=Path("/tmp/calibration_twin/true_poses"),
                    help="a variant folder of bench/calibration_twin.py's --out")
    ap.add_argument("--out", type=Path, default=Path("/tmp/twin_seed_spread"))
    args = ap.parse_args()
    planted = args.twin / "planted"
    cfg = load_config(planted / "sim" / "config.toml")  # runfiles: the engine's; the planted building
    for key, name in (("recording.tags", "tags.csv"), ("recording.poses", "poses.csv"),
                      ("recording.reads", "reads.csv")):  # reads last: it needs the tags
        cfg = replace_path(cfg, key, str(planted / "rec" / name))
    cfg = replace_path(cfg, "tracing.cache_dir", str(args.out / "cache"))  # fresh: new rays
    cfg = dataclasses.replace(cfg, seed=cfg.seed + 1)
    t0 = time.perf_counter()
    run = args.out / "retraced"
    run_full_study(cfg, run, command_line=["bench"], upto="sim_vs_real")
    elapsed = time.perf_counter() - t0
    attempts = runfiles.SIM_VS_REAL.format(name="attempts.parquet")
    new = pd.read_parquet(run / attempts)
    twin = pd.read_parquet(planted / "recorded" / attempts)  # its split: the calibration's
    key = ["cycle", "antenna", "tag_id"]
    m = twin[[*key, "split", "read", "rssi_dbm"]].merge(
        new[[*key, "gain_db", "p_sim", "rssi_sim_dbm"]], on=key, how="inner", validate="one_to_one")
    # the planted simulation's own trace of the same attempts (its tag names by position)
    sim = pd.read_parquet(planted / "sim" / runfiles.READS.format(prefix=""))
    tags_sim = pd.read_parquet(planted / "sim" / runfiles.SCENE_TAGS)
    tags_rec = pd.read_csv(planted / "rec" / "tags.csv", dtype={"epc": str})  # runfiles: a recording's
    where = ["x_m", "y_m", "z_m"]
    name_of = dict(zip(tags_rec.merge(tags_sim.round(4), on=where)["epc"],
                       tags_rec.merge(tags_sim.round(4), on=where)["tag_id"].astype(str), strict=True))
    g = m.assign(tag_id=m["tag_id"].map(name_of)).merge(
        sim.assign(tag_id=sim["tag_id"].astype(str))[[*key, "gain_db"]], on=key, suffixes=("", "_sim"))
    both = np.isfinite(g["gain_db"]) & np.isfinite(g["gain_db_sim"])
    dg = np.abs(g["gain_db"] - g["gain_db_sim"])[both]
    print(f"planted twin ({args.twin.name}) traced again with seed {cfg.seed} and a fresh cache: {elapsed:.0f} s")
    print(f"one-way gain against the planted simulation's own trace, {int(both.sum())} attempts: "
          f"median |diff| {np.median(dg):.3f} dB, p90 {np.percentile(dg, 90):.2f} dB, "
          f"p99 {np.percentile(dg, 99):.2f} dB, identical {np.mean(dg < 1e-6):.1%}")
    held = m[m["split"] == "eval"].reset_index(drop=True)
    score = sim_vs_real(held.assign(p_base=held["p_sim"], rssi_base_dbm=held["rssi_sim_dbm"]),
                        seed=cfg.seed)["rssi_mae_db"]
    e = score["ray_tracer"]
    print(f"held-out RSSI MAE of the planted truth, another seed: {e['estimate']:.2f} dB "
          f"[{e['low']:.2f}, {e['high']:.2f}] over {score['n_tags']} tags")
    cal = json.loads((planted / "recorded" / runfiles.CALIBRATION).read_text())["heldout"]["rssi_mae_db"]
    a = cal["after"]
    print(f"held-out RSSI MAE after calibration (calibration.json): {a['estimate']:.2f} dB "
          f"[{a['low']:.2f}, {a['high']:.2f}] over {cal['n_tags']} tags (not paired with the line above)")


if __name__ == "__main__":
    main()
