"""Write the numbers of the README and of docs/results.md from run directories.

    python scripts/readme_tables.py runs/replicated            # print the full tables
    python scripts/readme_tables.py runs/replicated --write docs/results.md
    python scripts/readme_tables.py runs/replicated --compact --write README.md
    python scripts/readme_tables.py runs/default --single-run --write docs/results.md

With ``--write`` the text between ``<!-- headline-tables:begin -->`` and
``<!-- headline-tables:end -->`` (``--single-run``: ``<!-- single-run:begin -->`` and
``<!-- single-run:end -->``) in the file is replaced; nothing else is touched. Every
number is read from the run directory: the headline tables from ``metrics.json``
(sections ``intervals``, ``comparisons`` and, for a replicated study, ``replicates``):
estimate and 95 % interval, and the verdict of the paired comparison with ANFIS; the
single-run block (Fig. 7 beyond the training domain, in-sample scores, the tag
candidates, the error budget) from one run's ``metrics.json`` and
``downstream/scores.json``. Each block names its run directory and the git commit the
run's ``manifest.json`` records (``source``); a run whose manifest records none needs
``--commit``, and a run from uncommitted changes is marked so.
"""

from __future__ import annotations

import argparse
import json
import re
import sys
from pathlib import Path

from pipeline import runfiles
from pipeline.sensormodels.registry import model_info, table_order

BEGIN, END = "<!-- headline-tables:begin -->", "<!-- headline-tables:end -->"
SINGLE_BEGIN, SINGLE_END = "<!-- single-run:begin -->", "<!-- single-run:end -->"

MARK = {"better": " ▲", "worse": " ▼"}

HELDOUT = (("heldout.rssi_mae_db", "RSSI MAE [dB]", 2), ("heldout.rssi_rmse_db", "RSSI RMSE [dB]", 2),
           ("heldout.detection_mae", "f<sub>T</sub> cell MAE", 3),
           ("heldout.detection_brier", "Brier", 3), ("fig7.median_pct", "Fig. 7 median, d ≤ d<sub>max</sub> [%]", 1),
           ("fig7.share_below_20pct", "Fig. 7 share < 20 %, d ≤ d<sub>max</sub>", 2))
DOWNSTREAM = (("tag_localisation.median_m", "tag median [m]", 2),
              ("tag_localisation.within_0_5m", "tags within 0.5 m", 2),
              ("robot_localisation.median_m", "robot median, all steps [m]", 2),
              ("robot_localisation.median_before_kidnap_m", "before kidnapping [m]", 2),
              ("robot_localisation.median_after_kidnap_m", "after [m]", 2),
              ("robot_localisation.converged_share", "runs converged", 2))


def _cell(iv: dict | None, cmp_: dict | None, digits: int) -> str:
    if not iv or iv.get("estimate") is None:
        return "–"
    f = f"{{:.{digits}f}}"
    txt = f.format(iv["estimate"])
    if iv.get("low") is not None and iv.get("high") is not None:
        txt += f" [{f.format(iv['low'])}, {f.format(iv['high'])}]"
    return txt + MARK.get((cmp_ or {}).get("verdict"), "")


def table(metrics: dict, cols) -> str:
    ivs, cmps = metrics.get("intervals") or {}, (metrics.get("comparisons") or {}).get("metrics") or {}
    models = []
    for key, _, _ in cols:
        models += [m for m in (ivs.get(key) or {}).get("models", {}) if m not in models]
    models = table_order(models)  # the registry's order, unknown models last
    head = "| model | " + " | ".join(c[1] for c in cols) + " |"
    rows = [head, "|---" * (len(cols) + 1) + "|"]
    for m in models:
        cells = [_cell((ivs.get(k) or {}).get("models", {}).get(m), (cmps.get(k) or {}).get(m), d)
                 for k, _, d in cols]
        rows.append(f"| {row_label(m)} | " + " | ".join(cells) + " |")
    return "\n".join(rows)


def row_label(key: str) -> str:
    """A model's row label: its registry label and key, or the key the registry lacks."""
    try:
        return f"{model_info(key).label} (`{key}`)"
    except KeyError:
        return key


def units_line(metrics: dict, origin: str = "") -> str:
    """Where the intervals come from: the run(s), and the units of each metric family
    (their counts differ: a held-out tag without a closing link has no RSSI unit)."""
    ivs = metrics.get("intervals") or {}
    rep = metrics.get("replicates")
    what = f"{rep['covers']} (seeds {', '.join(str(s) for s in rep['seeds'].values())})" \
        if rep else "one run"
    parts = []
    for key, name in (("heldout.rssi_mae_db", "RSSI"), ("heldout.detection_brier", "detection"),
                      ("fig7.median_pct", "Fig. 7"), ("tag_localisation.median_m",
                                                      "tag localisation"),
                      ("robot_localisation.median_m", "robot")):
        iv = ivs.get(key) or {}
        if iv.get("n_units") is not None:
            parts.append(f"{iv['n_units']} {iv.get('unit', 'unit')} units ({name})")
    return (f"From {what}{', ' + origin if origin else ''}: intervals over "
            + (", ".join(parts) if parts else "no units") + ".")


def run_origin(run_dir: Path, commit: str | None = None) -> str:
    """``run `NAME` at commit abc1234`` from the run's manifest (or `commit`).

    Raises
    ------
    ValueError
        Neither the run's manifest (nor, for a replicated run, its first replicate's)
        records a commit and none is given.
    """
    src = {}
    for man in (run_dir / "manifest.json", run_dir / "replicates" / "0" / "manifest.json"):
        if man.is_file():
            src = json.loads(man.read_text()).get("source") or {}
            if src.get("commit"):
                break
    sha = commit or src.get("commit")
    if not sha:
        raise ValueError(f"{run_dir}: its manifest.json records no commit (a run before the "
                         "manifest did, or not from a git checkout): pass --commit")
    dirty = " with uncommitted changes" if (not commit and src.get("dirty")) else ""
    return f"run `{run_dir.name}` at commit {sha[:7]}{dirty}"


def _pct(part: float, whole: float) -> str:
    return f"{100.0 * part / whole:.0f} %"


def _signed(x: float, digits: int = 2) -> str:
    """``+1.23`` / ``−1.23`` (a minus sign, as the prose writes it)."""
    return f"{x:+.{digits}f}".replace("-", "−")


def single_run_text(metrics: dict, scores: dict, origin: str, min_count: int | None) -> str:
    """The prose of docs/results.md that quotes one run: Fig. 7 beyond the training domain,
    the in-sample scores, the tag candidates and the error budget, every number from
    `metrics` (``metrics.json``) and `scores` (``downstream/scores.json``)."""
    f7 = metrics["fig7"]["anfis"]
    beyond = f7.get("beyond_training_domain") or {}
    ins = metrics["in_sample"]["models"]
    held = metrics["heldout"]["models"]
    ins_rssi = ins["anfis"]["rssi_dbm"]["mae"]
    ins_ft = ins["baselines"]["detection"]["mae"]
    out_rssi = held["anfis"]["rssi_dbm"]["mae"]
    out_ft = (held.get("grid_count") or {}).get("detection", {}).get("mae")
    worse = out_rssi > ins_rssi and (out_ft is None or out_ft > ins_ft)
    fig7 = (f"Fig. 7 is the chapter's metric (Sec. 5): |f̄<sub>s</sub> − s| × 100 on RSSI "
            f"normalised to [0, 1], f̄<sub>s</sub> the model averaged within "
            f"{100 * f7['radius_m']:.0f} cm of the tag, over the evaluation groups inside the "
            f"training domain (d ≤ {f7['d_max_m']:g} m): ANFIS's median is "
            f"{f7['median_pct']:.1f} % over {f7['n_groups']} groups; the "
            f"{beyond.get('n_groups', 0)} groups beyond it are reported apart (median "
            f"{beyond.get('median_pct', float('nan')):.0f} %). **In-sample** (scored on the "
            f"training reads, as this project did before): ANFIS RSSI MAE {ins_rssi:.2f} dB "
            f"(held out: {out_rssi:.2f} dB), grid-count f<sub>T</sub> MAE {ins_ft:.3f}"
            + (f" (held out: {out_ft:.3f})" if out_ft is not None else "")
            + (": every number gets worse out of sample." if worse else "."))
    info = scores.get("info") or {}
    cand = (f"The downstream stage localises each held-out tag over "
            f"{info.get('n_candidates', '?'):,} candidate sites: every vertical surface facing "
            f"free space at every height it has, not only the held-out tags' height band.")
    eb = metrics["error_budget"]
    rb, mf, loc = eb["representation_bound"], eb["model_form"], eb["localisation"]
    b, m, btw, win = rb["rmse_db"], mf["rmse_db"], mf["between_cells_db"], mf["within_cells_db2"]
    mcl = ((metrics.get("localisation") or {}).get("eval") or {}).get("position_error_median_m")
    sizes = []
    beats = []
    for _key, row in sorted((eb.get("by_cell_size") or {}).items(),
                           key=lambda kv: float(kv[1]["d_bin_m"])):
        if row.get("rmse_db") is None:
            sizes.append(f"no cell holds enough links at {row['d_bin_m']:g} m × "
                         f"{row['alpha_bin_deg']:g}°")
            continue
        sizes.append(f"{row['rmse_db']:.2f} dB on the {row['n_links']} links at "
                     f"{row['d_bin_m']:g} m × {row['alpha_bin_deg']:g}° (ANFIS "
                     f"{row['anfis_rmse_db']:.2f} dB)")
        if row["anfis_rmse_db"] < row["rmse_db"]:
            beats.append(f"{row['d_bin_m']:g} m × {row['alpha_bin_deg']:g}°")
    held_rssi = held["anfis"]["rssi_dbm"]
    need = f"at least {min_count} of them" if min_count else "enough of them"
    budget = (
        f"**Error budget** of the held-out RSSI RMSE (`error_budget`, "
        f"`pipeline/evaluation/bound.py`). Its bound is an oracle, not a model: the held-out "
        f"truth's own mean per (d, α) cell ({rb['d_bin_m']:g} m × {rb['alpha_bin_deg']:g}°), "
        f"on the {eb['n_links']['value']} held-out links in the {rb['n_cells']} cells that "
        f"hold {need}, scores {b:.2f} dB; no function constant on those cells can do better "
        f"on those links. On the same links ANFIS trained on true poses scores {m:.2f} dB "
        f"and on MCL poses {loc['rmse_db']:.2f} dB ({_signed(loc['step_db'])} dB"
        + (f"; MCL errs by {100 * mcl:.1f} cm median on the evaluation tour" if mcl else "")
        + f"). The true-pose model's excess splits exactly into its cell means against the "
        f"truth's ({btw:.2f} dB, ≥ 0 by construction) and a within-cell term of "
        f"{_signed(win)} dB²: {m:.2f}² = {b:.2f}² + {btw:.2f}² {'+' if win >= 0 else '−'} "
        f"{abs(win):.2f}. So {_pct(b * b, m * m)} of the learned model's squared error on "
        f"these links is what the cells' (d, α) cannot tell apart (multipath fading with "
        f"position, the cells' own spread), {_pct(btw * btw, m * m)} is the model's cell "
        f"means being off, and {_pct(abs(win), m * m)} is "
        f"{'lost' if win >= 0 else 'gained'} inside the cells. The bound depends on the "
        f"cell size (`by_cell_size`): " + "; ".join(sizes) + "."
        + (f" At {', '.join(beats)} ANFIS beats it: a smooth model is not constant on large "
           f"cells, so the bound binds only at cells small enough for the model to be near "
           f"constant in them." if beats else "")
        + f" Reader noise adds {eb['reader_noise']['rmse_db']:.2f} dB to any comparison "
        f"with measured RSSI. On all {held_rssi['n']} held-out links ANFIS's RMSE is "
        f"{eb['total']['rmse_db']:.2f} dB.")
    return "\n\n".join([f"From {origin} (one run of the default study).", fig7, cand, budget])


COMPACT = (("heldout.rssi_mae_db", "RSSI MAE [dB]", 2), ("heldout.detection_brier", "Brier", 3),
           ("fig7.median_pct", "Fig. 7 median, d ≤ d<sub>max</sub> [%]", 1),
           ("tag_localisation.median_m", "tag median [m]", 2),
           ("robot_localisation.median_m", "robot median [m]", 2))


def render(metrics: dict, source: str, compact: bool = False, origin: str = "") -> str:
    tables = [table(metrics, COMPACT)] if compact else [table(metrics, HELDOUT), "",
                                                        table(metrics, DOWNSTREAM)]
    how = "--compact --write README.md" if compact else "--write docs/results.md"
    return "\n".join([
        BEGIN,
        f"<!-- written by scripts/readme_tables.py from a run of configs/replicated.toml "
        f"(`python scripts/readme_tables.py RUN {how}`); do not edit -->",
        units_line(metrics, origin), "",
        *tables, "",
        "Each cell: estimate [95 % interval]; ▲ / ▼: better / worse than the chapter's ANFIS "
        "on the same units (the 95 % interval of the difference excludes 0); no mark: not "
        "distinguishable at 95 %. '–': the model predicts no such quantity.",
        END])


def render_single(run_dir: Path, origin: str) -> str:
    """The ``single-run`` block of one run directory (:func:`single_run_text`)."""
    import tomllib

    metrics = json.loads((run_dir / runfiles.METRICS).read_text())
    scores = json.loads((run_dir / runfiles.DOWNSTREAM_SCORES).read_text())
    cfg = run_dir / "config.toml"
    min_count = None
    if cfg.is_file():
        min_count = (tomllib.loads(cfg.read_text()).get("training") or {}).get("min_attempts")
    return "\n".join([
        SINGLE_BEGIN,
        "<!-- written by scripts/readme_tables.py from one run of the default study "
        "(`python scripts/readme_tables.py RUN --single-run --write docs/results.md`); do not "
        "edit -->",
        single_run_text(metrics, scores, origin, min_count),
        SINGLE_END])


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("run_dir", type=Path)
    ap.add_argument("--write", type=Path, help="file to update between the markers")
    ap.add_argument("--compact", action="store_true",
                    help="one short table (the README's) instead of the two full ones")
    ap.add_argument("--single-run", action="store_true",
                    help="the single-run block (Fig. 7 beyond the domain, in-sample, tag "
                         "candidates, error budget) of one run, not the headline tables")
    ap.add_argument("--commit", help="the commit the run came from, where its manifest "
                                     "records none")
    args = ap.parse_args(argv)
    try:
        origin = run_origin(args.run_dir, args.commit)
    except ValueError as exc:
        print(exc, file=sys.stderr)
        return 2
    if args.single_run:
        try:
            text = render_single(args.run_dir, origin)
        except (OSError, KeyError, TypeError, ValueError) as exc:
            print(f"{args.run_dir}: cannot write the single-run block ({type(exc).__name__}: "
                  f"{exc}): a complete run of the default study is needed", file=sys.stderr)
            return 2
        begin, end = SINGLE_BEGIN, SINGLE_END
    else:
        metrics = json.loads((args.run_dir / runfiles.METRICS).read_text())
        if "intervals" not in metrics:
            print(f"{args.run_dir}/metrics.json has no intervals: rerun the study", file=sys.stderr)
            return 2
        text = render(metrics, args.run_dir.as_posix(), compact=args.compact, origin=origin)
        begin, end = BEGIN, END
    if not args.write:
        print(text)
        return 0
    readme = args.write.read_text()
    pat = re.compile(re.escape(begin) + ".*?" + re.escape(end), re.S)
    if not pat.search(readme):
        print(f"{args.write}: no {begin} ... {end} block", file=sys.stderr)
        return 2
    args.write.write_text(pat.sub(lambda _: text, readme, count=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
