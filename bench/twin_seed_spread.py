"""The calibration twin's truth against itself: how far is a calibrated residual from the floor?

``bench/calibration_twin.py`` plants differences in a simulated building and calibrates
the unchanged one to its recording. This script scores, on the held-out tags of the
planted twin's calibration (the same tags, the same metric,
:func:`pipeline.evaluation.simreal.sim_vs_real`, with its tag-bootstrap interval), two
predictions of the recorded RSSI by the planted building itself:

- the planted simulation's own trace (the rays that made the recording): the residual is
  the reader's noise alone. The twin's calibrated model shares those rays (the twin traces
  the recorded tour with the same seed and cache), so this is its floor;
- a trace with another tracer seed and a fresh propagation cache (new rays): the reader's
  noise and the truth's seed-to-seed spread. For a real recording, whose rays nobody
  traced, this is the floor.

It prints how far the new trace's gains are from the simulation's, both residuals, and
the calibrated model's from ``calibration.json`` (not paired with them).

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
    from pipeline.evaluation.truth import true_detected, true_rssi_dbm
    from pipeline.studyscene import link_budget

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
    pairs = tags_rec.assign(**{c: tags_rec[c].round(3) for c in where}).merge(
        tags_sim.assign(**{c: tags_sim[c].round(3) for c in where})[[*where, "tag_id"]],
        on=where, how="inner", validate="one_to_one")
    if len(pairs) != len(tags_rec):
        raise SystemExit(f"{len(tags_rec) - len(pairs)} recorded tags have no simulated tag at their position")
    name_of = dict(zip(pairs["epc"], pairs["tag_id"].astype(str), strict=True))
    g = m.assign(tag_id=m["tag_id"].map(name_of)).merge(
        sim.assign(tag_id=sim["tag_id"].astype(str))[[*key, "gain_db"]], on=key, how="left",
        suffixes=("", "_sim"), validate="one_to_one")
    both = np.isfinite(g["gain_db"]) & np.isfinite(g["gain_db_sim"])
    dg = np.abs(g["gain_db"] - g["gain_db_sim"])[both]
    print(f"planted twin ({args.twin.name}) traced again with seed {cfg.seed} and a fresh cache: {elapsed:.0f} s")
    print(f"one-way gain against the planted simulation's own trace, {int(both.sum())} of {len(g)} "
          f"recorded attempts: median |diff| {np.median(dg):.3f} dB, p90 {np.percentile(dg, 90):.2f} dB, "
          f"p99 {np.percentile(dg, 99):.2f} dB, identical {np.mean(dg < 1e-6):.1%}")
    budget = link_budget(cfg)
    gs = g["gain_db_sim"].to_numpy(np.float64)
    closes = np.isfinite(gs) & true_detected(np.nan_to_num(gs, nan=-400.0), budget)
    g["rssi_same_dbm"] = np.where(closes, true_rssi_dbm(np.nan_to_num(gs, nan=-400.0), budget), np.nan)
    held = g[g["split"] == "eval"].reset_index(drop=True)
    for label, col in (("the simulation's own rays (the reader's noise alone)", "rssi_same_dbm"),
                       ("another seed, new rays (and the truth's seed-to-seed spread)", "rssi_sim_dbm")):
        h = held.assign(rssi_sim_dbm=held[col], p_base=held["p_sim"], rssi_base_dbm=held[col])
        score = sim_vs_real(h, seed=cfg.seed)["rssi_mae_db"]
        e = score["ray_tracer"]
        print(f"held-out RSSI MAE of the planted truth, {label}: {e['estimate']:.2f} dB "
              f"[{e['low']:.2f}, {e['high']:.2f}] over {score['n_tags']} tags")
    cal = json.loads((planted / "recorded" / runfiles.CALIBRATION).read_text())["heldout"]["rssi_mae_db"]
    a = cal["after"]
    print(f"held-out RSSI MAE after calibration (calibration.json): {a['estimate']:.2f} dB "
          f"[{a['low']:.2f}, {a['high']:.2f}] over {cal['n_tags']} tags (not paired with the lines above)")


if __name__ == "__main__":
    main()
