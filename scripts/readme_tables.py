"""Write the headline tables of the README and of docs/results.md from a run's metrics.json.

    python scripts/readme_tables.py runs/replicated            # print the full tables
    python scripts/readme_tables.py runs/replicated --write docs/results.md
    python scripts/readme_tables.py runs/replicated --compact --write README.md

With ``--write`` the text between ``<!-- headline-tables:begin -->`` and
``<!-- headline-tables:end -->`` in the file is replaced; nothing else is touched.
Every number is read from ``metrics.json`` (sections ``intervals``, ``comparisons``
and, for a replicated study, ``replicates``): estimate and 95 % interval, and the
verdict of the paired comparison with ANFIS.
"""

from __future__ import annotations

import argparse
import json
import re
import sys
from pathlib import Path

BEGIN, END = "<!-- headline-tables:begin -->", "<!-- headline-tables:end -->"

NAMES = {
    "anfis": "FCM + ANFIS, MCL poses (`anfis`, the chapter's)",
    "anfis_truepose": "FCM + ANFIS, true poses (`anfis_truepose`)",
    "fcm_only": "FIS from FCM, no ANFIS (`fcm_only`)",
    "anfis_gridinit": "ANFIS from a grid partition (`anfis_gridinit`)",
    "joho2009": "Joho et al. 2009 (`joho2009`)",
    "log_distance": "log-distance + pattern (`log_distance`)",
    "grid_count": "Hähnel et al. 2004 grid count (`grid_count`)",
    "liu2006": "sector read region, project's own (`liu2006`)",
    "vorst2008": "Vorst & Zell 2008 (`vorst2008`)",
    "phase": "reader phase alone (`phase`)",
    "phase_anfis": "reader phase x ANFIS (`phase_anfis`)",
    "oracle": "ray-traced oracle (`oracle`)",
}
MARK = {"better": " ▲", "worse": " ▼"}

HELDOUT = (("heldout.rssi_mae_db", "RSSI MAE [dB]", 2), ("heldout.rssi_rmse_db", "RSSI RMSE [dB]", 2),
           ("heldout.detection_mae", "f<sub>T</sub> cell MAE", 3),
           ("heldout.detection_brier", "Brier", 3), ("fig7.median_pct", "Fig. 7 median [%]", 1),
           ("fig7.share_below_20pct", "Fig. 7 share < 20 %", 2))
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
    models.sort(key=lambda m: list(NAMES).index(m) if m in NAMES else len(NAMES))
    head = "| model | " + " | ".join(c[1] for c in cols) + " |"
    rows = [head, "|---" * (len(cols) + 1) + "|"]
    for m in models:
        cells = [_cell((ivs.get(k) or {}).get("models", {}).get(m), (cmps.get(k) or {}).get(m), d)
                 for k, _, d in cols]
        rows.append(f"| {NAMES.get(m, m)} | " + " | ".join(cells) + " |")
    return "\n".join(rows)


def units_line(metrics: dict) -> str:
    ivs = metrics.get("intervals") or {}
    rep = metrics.get("replicates")
    tag = (ivs.get("tag_localisation.median_m") or ivs.get("heldout.rssi_mae_db") or {})
    robot = ivs.get("robot_localisation.median_m") or {}
    what = f"{rep['covers']} (seeds {', '.join(str(s) for s in rep['seeds'].values())})" \
        if rep else "one run"
    return (f"From {what}: intervals over {tag.get('n_units', '?')} {tag.get('unit', 'tag')} units "
            f"and {robot.get('n_units', '?')} {robot.get('unit', 'filter run')} units.")


COMPACT = (("heldout.rssi_mae_db", "RSSI MAE [dB]", 2), ("heldout.detection_brier", "Brier", 3),
           ("fig7.median_pct", "Fig. 7 median [%]", 1),
           ("tag_localisation.median_m", "tag median [m]", 2),
           ("robot_localisation.median_m", "robot median [m]", 2))


def render(metrics: dict, source: str, compact: bool = False) -> str:
    tables = [table(metrics, COMPACT)] if compact else [table(metrics, HELDOUT), "",
                                                        table(metrics, DOWNSTREAM)]
    how = "--compact --write README.md" if compact else "--write docs/results.md"
    return "\n".join([
        BEGIN,
        f"<!-- written by scripts/readme_tables.py from a run of configs/replicated.toml "
        f"(`python scripts/readme_tables.py RUN {how}`); do not edit -->",
        units_line(metrics), "",
        *tables, "",
        "Each cell: estimate [95 % interval]; ▲ / ▼: better / worse than the chapter's ANFIS "
        "on the same units (the 95 % interval of the difference excludes 0); no mark: not "
        "distinguishable at 95 %. '–': the model predicts no such quantity.",
        END])


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("run_dir", type=Path)
    ap.add_argument("--write", type=Path, help="file to update between the markers")
    ap.add_argument("--compact", action="store_true",
                    help="one short table (the README's) instead of the two full ones")
    args = ap.parse_args(argv)
    metrics = json.loads((args.run_dir / "metrics.json").read_text())
    if "intervals" not in metrics:
        print(f"{args.run_dir}/metrics.json has no intervals: rerun the study", file=sys.stderr)
        return 2
    text = render(metrics, args.run_dir.as_posix(), compact=args.compact)
    if not args.write:
        print(text)
        return 0
    readme = args.write.read_text()
    pat = re.compile(re.escape(BEGIN) + ".*?" + re.escape(END), re.S)
    if not pat.search(readme):
        print(f"{args.write}: no {BEGIN} ... {END} block", file=sys.stderr)
        return 2
    args.write.write_text(pat.sub(lambda _: text, readme, count=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
