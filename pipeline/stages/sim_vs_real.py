"""Stage ``sim_vs_real``: the recorded tour traced in the scene and scored against the log.

The recorded poses (``tour/train_track.npz``) and tag layout are run through the
simulated reader (:func:`pipeline.acquisition.simulate_reads`, the study's ``[reader]``
and ``[tracing]``), each attempt on the channel the reader reported in its slot for a
training tag (a slot without such a read: its nearest reported slot's within half the
hop dwell, else the simulated hop; ``summary.json`` ``channels`` counts them): its
attempt schedule is the one the recording's attempts were
rebuilt on (:mod:`pipeline.recording.attempts`), so every recorded attempt has its
traced twin, joined on (cycle, antenna, tag). The comparison and the baseline are
:mod:`pipeline.evaluation.simreal`'s. Writes ``sim_vs_real/attempts.parquet`` (per
attempt in range: split, read, measured and predicted RSSI, predicted probabilities, the
antenna's traced pose and channel),
``sim_vs_real/links.parquet`` (:func:`~pipeline.evaluation.simreal.link_rates`, per
tag and antenna, with ``split``) and ``sim_vs_real/summary.json``.
"""

from __future__ import annotations

import numpy as np
import pandas as pd

from pipeline import runfiles
from pipeline.acquisition import simulate_reads
from pipeline.engine.runstore import atomic_write_json
from pipeline.engine.study import Stage
from pipeline.engine.tracetasks import trace_tasks
from pipeline.evaluation.simreal import fit_log_distance_baseline, link_rates, sim_vs_real
from pipeline.evaluation.truth import true_detected, true_rssi_dbm
from pipeline.runfiles import STAGE_OUTPUTS
from pipeline.stages.common import TRACING_KEYS, load_scene, read_reads, read_track
from pipeline.stages.truth import attempt_miss_probability
from pipeline.studyscene import (
    build_robot,
    link_budget,
    resolve_cache_dir,
    select_backend,
    stage_rng,
    trace_options,
)

__all__ = ["STAGE", "stage_sim_vs_real"]

_KEY = ["cycle", "antenna", "tag_id"]


def _recorded(ctx) -> pd.DataFrame:
    parts = []
    for prefix, split in (("", "train"), ("eval_", "eval")):
        df, _ = read_reads(ctx, prefix)
        parts.append(df[[*_KEY, "read", "rssi_dbm", "d_est_m", "frequency_hz"]].assign(
            tag_id=df["tag_id"].astype(str), split=split))
    return pd.concat(parts, ignore_index=True)


def _slot_channels(rec: pd.DataFrame) -> dict:
    """(cycle, antenna) -> the channel [Hz] the reader reported in that slot (its most
    frequent one where reads of one slot disagree), from the training tags' reads only: a
    held-out read's own channel would tell its attempt's prediction that it was read."""
    r = rec[rec["read"].to_numpy(bool) & np.isfinite(rec["frequency_hz"].to_numpy(np.float64))
            & (rec["split"] == "train").to_numpy()]
    if r.empty:
        return {}
    mode = r.groupby(["cycle", "antenna"])["frequency_hz"].agg(lambda f: f.mode().iloc[0])
    return {(int(c), int(a)): float(f) for (c, a), f in mode.items()}


def stage_sim_vs_real(ctx) -> dict:
    """Trace the recorded tour, predict every recorded attempt, compare (module doc)."""
    cfg = ctx.config
    variant = select_backend(cfg)
    sc = load_scene(ctx)
    robot = build_robot(cfg)
    cache = resolve_cache_dir(cfg)
    cache.mkdir(parents=True, exist_ok=True)
    budget = link_budget(cfg)
    rec = _recorded(ctx)
    with trace_tasks(cfg) as tasks:
        sim = simulate_reads(sc, robot, read_track(ctx, "train"), cfg.reader,
                             stage_rng(cfg, "sim_vs_real"), trace=trace_options(cfg),
                             cache_dir=cache, progress=ctx.progress("tracing the recorded tour"),
                             tags=sc.tags, frequency_hz=cfg.frequency_hz,
                             slot_channels_hz=_slot_channels(rec))
    s = sim.reads
    gain = s["gain_db"].to_numpy(np.float64)
    closed = true_detected(gain, budget)
    q = np.broadcast_to(np.asarray(attempt_miss_probability(cfg, s, budget), np.float64), closed.shape)
    pred = pd.DataFrame({
        "cycle": s["cycle"].to_numpy(), "antenna": s["antenna"].to_numpy(),
        "tag_id": s["tag_id"].astype(str).to_numpy(), "in_range": s["in_range"].to_numpy(bool),
        # where the traced antenna stood (the calibration re-fields these links)
        **{f"ant_{c}": s[f"true_ant_{c}"].to_numpy(np.float64) for c in ("x_m", "y_m", "z_m", "yaw_rad")},
        "frequency_hz": s["frequency_hz"].to_numpy(np.float64),
        "gain_db": gain, "miss_probability": q, "p_sim": np.where(closed, 1.0 - q, 0.0),
        "rssi_sim_dbm": np.where(closed, true_rssi_dbm(gain, budget), np.nan)})
    att = rec.drop(columns="frequency_hz").merge(pred, on=_KEY, how="left", validate="one_to_one")
    if att["in_range"].isna().any():
        n = int(att["in_range"].isna().sum())
        raise ValueError(f"{n} recorded attempts have no traced twin: the recording stage and "
                         "this one disagree on the attempt schedule (re-run both)")
    att = att[att["in_range"].to_numpy(bool)].reset_index(drop=True)
    train = att[att["split"] == "train"]
    base = fit_log_distance_baseline(train["d_est_m"], train["antenna"], train["read"],
                                     train["rssi_dbm"], len(cfg.robot.antennas))
    att["p_base"] = base.p_read(att["d_est_m"], att["antenna"])
    att["rssi_base_dbm"] = base.rssi_dbm(att["d_est_m"], att["antenna"])
    held = att[att["split"] == "eval"].reset_index(drop=True)
    if held["tag_id"].nunique() == 0:
        raise ValueError("no held-out tag is within the traced range of the recorded tour")
    summary = {
        "heldout": sim_vs_real(held, seed=cfg.seed),
        "baseline": base.to_dict(),
        "n_attempts_in_range": int(len(att)),
        "n_attempts_not_traced": int(len(rec) - len(att)),
        "channels": sim.metadata["channels"].get("recorded"),
        "how": "per held-out attempt within the traced range: predicted read probability "
               "(traced link closes x (1 - miss probability)) and noise-free RSSI against the "
               "recorded read and RSSI; intervals over held-out tags; the baseline fitted on "
               "the training tags (pipeline.evaluation.simreal)",
    }
    att.to_parquet(ctx.out(runfiles.SIM_VS_REAL.format(name="attempts.parquet")), index=False)
    links = pd.concat([link_rates(att[att["split"] == sp]).assign(split=sp)
                       for sp in ("train", "eval")], ignore_index=True)
    links.to_parquet(ctx.out(runfiles.SIM_VS_REAL.format(name="links.parquet")), index=False)
    atomic_write_json(ctx.out(runfiles.SIM_VS_REAL.format(name="summary.json")), summary)
    info = {"variant": variant, "n_attempts_in_range": summary["n_attempts_in_range"],
            "brier": summary["heldout"]["brier"]["ray_tracer"]["estimate"],
            "rssi_mae_db": summary["heldout"]["rssi_mae_db"]["ray_tracer"]["estimate"]}
    if tasks is not None:
        info["trace_tasks"] = tasks.as_dict()
    return info


STAGE = Stage("sim_vs_real", stage_sim_vs_real, ("seed", "robot", "reader") + TRACING_KEYS,
              ("scene", "recording"), version=4,  # each version's change: CHANGELOG.md
              description="simulation against the recording",
              outputs=STAGE_OUTPUTS["sim_vs_real"])
