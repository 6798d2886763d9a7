"""The placement study's answer: per-candidate table, ranking, recommendation, Pareto front.

``placement/summary.parquet`` has one row per candidate:

- ``candidate``, ``origin`` (grid / preset / optimiser), the mount values it sets
  (``z_m``, ``tilt_deg``, ...; NaN where it sets none), ``antennas`` (readable mounts);
- per objective (:data:`~.objectives.OBJECTIVES`): ``<key>`` the estimate and
  ``<key>_low`` / ``<key>_high`` its 95 % interval over (replicate, unit) units;
- ``completeness_<lo>_<hi>m`` (and ``_low`` / ``_high``): completeness of the tags
  whose height is in that band;
- ``feasibility``: "met" / "uncertain" / "missed", every ``[[constraint]]`` judged on
  the objective's 95 % interval (:func:`feasibility`); ``feasible``: it is "met";
  ``rank`` (1 = the best by the primary objective among the most feasible);
- ``diff_vs_best``, ``diff_vs_best_low/high``, ``verdict_vs_best``: the primary
  objective minus the recommended candidate's on the same units;
- ``n_replicates`` complete, ``n_sources_traced`` (antenna positions traced afresh by
  its studies), ``n_links`` (links its studies used), ``compute_s`` (its studies'
  stage times summed).

- ``n_tags`` and ``never_read_n``: tags of a tour, and those it never read (means
  over the replicates), beside ``never_read``'s share;

``placement/answer.json`` holds the recommendation, its margin to the runner-up on
the primary objective with the margin's interval and whether it exceeds it ("better"
verdict), and the Pareto front of the two ``pareto`` objectives.
"""

from __future__ import annotations

import io
import math
from pathlib import Path

import numpy as np
import pandas as pd

from pipeline.apps.placement.candidates import MOUNT_FIELDS
from pipeline.apps.placement.figures import draw_figures
from pipeline.apps.placement.objectives import (
    OBJECTIVES,
    compare_objective,
    load_candidate_data,
    needed_stage,
    objective_interval,
    traced_counts,
)
from pipeline.apps.placement.report import write_report
from pipeline.apps.placement.results import (
    PlacementResult,
    band_key,
    complete_dirs,
    height_bands,
    ranking_table,
)
from pipeline.config import ConfigError
from pipeline.engine.runstore import (
    atomic_write_bytes,
    atomic_write_json,
    inside,
    read_run_json,
    run_files,
)
from pipeline.studyscene import link_budget

__all__ = ["FEASIBILITY", "SELECTION_RULE", "evidence", "feasibility", "pareto_front",
           "rank_candidates", "summarise", "write_outputs"]


def _compute_s(run_dir: Path) -> float:
    total = 0.0
    for p in run_files(run_dir, "stages", "*.json"):  # regular files only, never a link
        try:
            total += float(read_run_json(p).get("elapsed_s") or 0.0)
        except (OSError, ValueError, AttributeError, TypeError):
            continue
    return total


def _antennas_text(c) -> str:
    return "; ".join(f"{a.name} ({a.x_m:g}, {a.y_m:g}, {a.z_m:g}) m yaw {a.yaw_deg:g} "
                     f"tilt {a.tilt_deg:g} deg" for a in c.antennas)


def summarise(spec, out: Path, cands: list) -> tuple[pd.DataFrame, dict]:
    """The summary table and each candidate's data (``{name: CandidateData}``)."""
    s = spec.settings
    budget = link_budget(spec.base)
    seed = int(spec.base.seed)
    required = _required(spec)
    rows, datas = [], {}
    for c in cands:
        dirs = complete_dirs(out, c.name, s.replicates, required)
        row = {"candidate": c.name, "origin": c.origin, "antennas": _antennas_text(c),
               "n_antennas": len(c.antennas), "n_replicates": len(dirs)}
        for k in MOUNT_FIELDS:
            row[k] = float(c.values[k]) if k in c.values else float("nan")
        counts = [traced_counts(d) for d in dirs.values()]
        row["n_sources_traced"] = int(sum(x["n_sources_traced"] for x in counts))
        row["n_links"] = int(sum(x["n_links"] for x in counts))
        row["compute_s"] = float(sum(_compute_s(d) for d in dirs.values()))
        if dirs:
            data = load_candidate_data(dirs, budget)
            datas[c.name] = data
            row.update(never_read_counts(data.inventory))
            for key in OBJECTIVES:
                iv = objective_interval(data, key, seed=seed, candidate=c.name,
                                        min_reads=s.min_reads)
                row[key], row[f"{key}_low"], row[f"{key}_high"] = iv.estimate, iv.low, iv.high
            bands = height_bands(s.height_bands_m)
            for j, band in enumerate(bands):
                # the last band holds its upper edge too (a tag at the top edge counts)
                sel = (band[0], float(np.nextafter(band[1], np.inf))) if j == len(bands) - 1 else band
                iv = objective_interval(data, "completeness", seed=seed, candidate=c.name,
                                        min_reads=s.min_reads, band=sel)
                bk = band_key(band)
                row[bk], row[f"{bk}_low"], row[f"{bk}_high"] = iv.estimate, iv.low, iv.high
        rows.append(row)
    df = pd.DataFrame(rows)
    for col in df.columns:  # None (no interval) -> NaN: numeric columns stay numeric
        if col.endswith(("_low", "_high")):
            df[col] = pd.to_numeric(df[col], errors="coerce")
    return df, datas


def never_read_counts(inventory: pd.DataFrame) -> dict:
    """``n_tags`` (tags a tour attempted, mean over replicates) and ``never_read_n``
    (those it never read, mean over replicates) of :class:`~.objectives.CandidateData`
    inventory rows (units ``r<k>/<tag>``): the count beside ``never_read``'s share."""
    if inventory is None or inventory.empty:
        return {"n_tags": float("nan"), "never_read_n": float("nan")}
    per_tag = inventory.groupby("unit")["n_reads"].sum()
    rep = per_tag.index.to_series().str.split("/").str[0].to_numpy()
    return {"n_tags": float(per_tag.groupby(rep).size().mean()),
            "never_read_n": float((per_tag == 0).groupby(rep).sum().mean())}


#: Order of the feasibility states (the ranking's first key).
FEASIBILITY = ("met", "uncertain", "missed")


def feasibility(row, constraints) -> str:
    """Whether a candidate meets every constraint, judged on its 95 % intervals:
    ``"met"`` (every interval inside its constraint), ``"missed"`` (some interval wholly
    outside), else ``"uncertain"`` (an interval straddles a limit, or an objective has
    no interval; not evaluated at all: ``"missed"``)."""
    state = 0
    for c in constraints:
        v = row.get(c.objective)
        if v is None or not math.isfinite(float(v)):
            return "missed"
        lo, hi = row.get(f"{c.objective}_low"), row.get(f"{c.objective}_high")
        if lo is None or hi is None or not (math.isfinite(float(lo)) and math.isfinite(float(hi))):
            state = max(state, 1)
            continue
        met = (c.min is None or lo >= c.min) and (c.max is None or hi <= c.max)
        missed = (c.min is not None and hi < c.min) or (c.max is not None and lo > c.max)
        state = max(state, 0 if met else 2 if missed else 1)
    return FEASIBILITY[state]


def rank_candidates(df: pd.DataFrame, primary: str, constraints=()) -> pd.DataFrame:
    """``df`` with ``feasibility`` (:func:`feasibility`), ``feasible`` (it is "met") and
    ``rank``, sorted: by feasibility (met, uncertain, missed), then by the primary
    objective's estimate (best first; those without one last)."""
    out = df.copy()
    if primary not in out.columns:
        out[primary] = np.nan
    out["feasibility"] = [feasibility(r, constraints) for _, r in out.iterrows()]
    out["feasible"] = out["feasibility"] == "met"
    sign = 1.0 if OBJECTIVES[primary].lower_is_better else -1.0
    key = pd.to_numeric(out[primary], errors="coerce") * sign
    out["_order"] = list(zip(out["feasibility"].map(FEASIBILITY.index), key.isna(),
                             key.fillna(0.0), strict=True))
    out = out.sort_values("_order", kind="stable").drop(columns="_order").reset_index(drop=True)
    out["rank"] = np.arange(1, len(out) + 1)
    return out


def evidence(df: pd.DataFrame, best: str | None) -> dict:
    """What the comparisons with the best support (``df`` ranked, with
    ``verdict_vs_best``): ``single_best`` when every other candidate of the best's
    feasibility or better is worse than it at 95 %; else ``tied_with_best`` lists those
    not distinguishable from it (or ahead of it on the units both share)."""
    if best is None:
        return {"single_best": False, "tied_with_best": [], "rule": SELECTION_RULE}
    fb = df.loc[df["candidate"] == best, "feasibility"].iloc[0]
    peers = df[(df["candidate"] != best)
               & (df["feasibility"].map(FEASIBILITY.index) <= FEASIBILITY.index(fb))
               & df["verdict_vs_best"].astype(bool)]
    tied = [str(n) for n, v in zip(peers["candidate"], peers["verdict_vs_best"], strict=True)
            if v != "worse"]
    return {"single_best": not tied, "tied_with_best": tied, "rule": SELECTION_RULE}


#: The selection rule, as the report and ``answer.json`` state it.
SELECTION_RULE = (
    "Candidates are ranked by constraint feasibility judged on the 95 % intervals (met, "
    "uncertain, missed), then by the primary objective's estimate. The best is compared with "
    "every other candidate on the units both share (paired bootstrap of the difference); it is "
    "a single best only if every candidate of its feasibility or better is worse than it at "
    "95 %. These comparisons are made on the replicates that selected the best, so they "
    "favour it (the winner's curse of a maximum over noisy estimates); the confirmation runs "
    "the top candidates again on fresh replicate seeds that took no part in the selection.")


def pareto_front(df: pd.DataFrame, a: str, b: str) -> list[str]:
    """Candidates no other candidate beats on both objectives ``a`` and ``b`` (their
    estimates; each objective's own direction)."""
    sa = 1.0 if OBJECTIVES[a].lower_is_better else -1.0
    sb = 1.0 if OBJECTIVES[b].lower_is_better else -1.0
    pts = [(r["candidate"], sa * r[a], sb * r[b]) for _, r in df.iterrows()
           if np.isfinite(r.get(a, np.nan)) and np.isfinite(r.get(b, np.nan))]
    front = []
    for n, x, y in pts:
        dominated = any((x2 <= x and y2 <= y) and (x2 < x or y2 < y) for _, x2, y2 in pts)
        if not dominated:
            front.append(n)
    return front


def _required(spec) -> str:
    s = spec.settings
    return needed_stage([s.primary, *(c.objective for c in s.constraint)])


def top_candidates(spec, cands: list, k: int, summary: tuple) -> list:
    """The ``k`` best-ranked candidates with results (:func:`rank_candidates` on the
    selection replicates' ``summary``, :func:`summarise`'s pair): whom the confirmation
    runs again."""
    df, datas = summary
    df = rank_candidates(df, spec.settings.primary, spec.settings.constraint)
    by_name = {c.name: c for c in cands}
    names = [n for n in df["candidate"] if n in datas and np.isfinite(
        df.loc[df["candidate"] == n, spec.settings.primary].iloc[0])]
    return [by_name[n] for n in names[:k]]


def confirmation(spec, out: Path, names: list[str]) -> dict | None:
    """The confirmed candidates on the fresh replicates ``R .. 2R - 1`` only: each one's
    primary objective with its interval, and the first (the selected best) against each
    other one on the units both share; ``holds`` when the first is still ahead of every
    other at 95 %. None without two confirmed candidates with results."""
    s = spec.settings
    if len(names) < 2:
        return None
    fresh = range(s.replicates, 2 * s.replicates)
    budget = link_budget(spec.base)
    seed = int(spec.base.seed)
    datas = {}
    for n in names:
        dirs = complete_dirs(out, n, s.replicates, _required(spec), ks=fresh)
        if dirs:
            datas[n] = load_candidate_data(dirs, budget)
    if len(datas) < 2 or names[0] not in datas:
        return None
    best = names[0]
    est = {n: objective_interval(d, s.primary, seed=seed + 1, candidate=n,
                                 min_reads=s.min_reads).to_dict() for n, d in datas.items()}
    cmp_ = {n: compare_objective(datas[n], datas[best], s.primary, seed=seed + 1,
                                 names=(n, best), min_reads=s.min_reads).to_dict()
            for n in datas if n != best}
    return {"candidates": list(datas), "replicates": [int(fresh[0]), int(fresh[-1])],
            "estimates": est, "vs_selected": cmp_,
            "holds": all(c.get("verdict") == "worse" for c in cmp_.values())}


def write_outputs(spec, out: Path, cands: list, done: dict, *, upto: str = "evaluation",
                  dropped: list | None = None, confirmed: list | None = None,
                  summary: tuple | None = None):
    """Summarise, rank, compare, draw and report; return a :class:`~.results.PlacementResult`.

    ``upto`` is the last stage the candidates' studies ran, ``dropped`` why they stopped
    earlier than the objectives asked, ``confirmed`` the candidates run again on fresh
    replicates (all go into ``answer.json``); ``summary``, :func:`summarise` already
    computed (the confirmation's replicates do not enter it)."""
    s = spec.settings
    df, datas = summary if summary is not None else summarise(spec, out, cands)
    if not datas:
        errors = sorted({e for d in done.values() for e in d.get("errors", [])})
        raise ConfigError(f"{out}: no candidate finished a single replicate"
                          + (f"; first error: {errors[0]}" if errors else ""))
    df = rank_candidates(df, s.primary, s.constraint)
    seed = int(spec.base.seed)
    best = df.iloc[0]["candidate"] if df.iloc[0]["candidate"] in datas else None
    comparisons = {}
    for col in ("diff_vs_best", "diff_vs_best_low", "diff_vs_best_high"):
        df[col] = np.nan
    df["verdict_vs_best"] = ""
    if best is not None:
        for i, r in df.iterrows():
            name = r["candidate"]
            if name == best or name not in datas:
                continue
            cmp_ = compare_objective(datas[name], datas[best], s.primary, seed=seed,
                                     names=(name, best), min_reads=s.min_reads)
            d = cmp_.difference
            df.loc[i, ["diff_vs_best", "diff_vs_best_low", "diff_vs_best_high"]] = [
                d.estimate, np.nan if d.low is None else d.low, np.nan if d.high is None else d.high]
            df.loc[i, "verdict_vs_best"] = cmp_.verdict
            comparisons[name] = cmp_.to_dict()
    runner_up = next((n for n in df["candidate"] if n != best and n in comparisons), None)
    answer = {
        "primary": s.primary,
        "primary_label": OBJECTIVES[s.primary].label,
        "constraints": [{"objective": c.objective, "min": c.min, "max": c.max} for c in s.constraint],
        "recommended": best,
        "recommended_feasible": bool(df.iloc[0]["feasible"]) if best is not None else False,
        "recommended_feasibility": str(df.iloc[0]["feasibility"]) if best is not None else None,
        "runner_up": runner_up,
        "margin": None if runner_up is None else comparisons.get(runner_up),
        "margin_exceeds_interval": (runner_up is not None
                                    and comparisons[runner_up].get("verdict") == "worse"),
        **evidence(df, best),
        "pareto_objectives": list(s.pareto),
        "pareto_front": pareto_front(df, *s.pareto),
        "replicates": s.replicates,
        "studies_ran_upto": upto,
        "confirmation": confirmation(spec, out, list(confirmed or [])),
        "dropped": list(dropped or []),
        "n_candidates": int(len(df)),
        "comparisons_vs_recommended": comparisons,
    }
    pdir = inside(out, "placement")
    pdir.mkdir(exist_ok=True)
    buf = io.BytesIO()
    df.to_parquet(buf, index=False)
    files = [atomic_write_bytes(pdir / "summary.parquet", buf.getvalue())]
    files.append(atomic_write_bytes(pdir / "ranking.csv", ranking_table(df, s).to_csv(
        index=False).encode()))
    files.append(atomic_write_json(pdir / "answer.json", answer))
    figs = draw_figures(spec, out, df, datas, answer)
    files.extend(figs)
    files.append(write_report(spec, out, df, answer, figs))
    return PlacementResult(out_dir=out, summary=df, answer=answer, files=files)
