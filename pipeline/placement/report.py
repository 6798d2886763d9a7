"""``placement/report.html``: the answer first, then the table, then the figures (Jinja2)."""

from __future__ import annotations

import base64
import html
from pathlib import Path

import numpy as np

from pipeline.runstore import atomic_write_bytes

from .objectives import OBJECTIVES
from .summary import ranking_table

__all__ = ["margin_sentence", "write_report"]

_TEMPLATE = """<!DOCTYPE html>
<html lang="en"><head><meta charset="utf-8"><title>Antenna placement: {{ title }}</title>
<style>
body { font-family: sans-serif; max-width: 1100px; margin: 1em auto; padding: 0 1em; }
table { border-collapse: collapse; font-size: 0.8em; display: block; overflow-x: auto; }
th, td { border: 1px solid #ccc; padding: 2px 6px; text-align: left; white-space: nowrap; }
figure { margin: 1em 0; } img { max-width: 100%; }
.answer { background: #eef5ee; padding: 0.6em 1em; border-left: 4px solid #393; }
</style></head><body>
<h1>Antenna placement: {{ title }}</h1>
<div class="answer">
{% if recommended %}
<p><b>Recommended: {{ recommended }}</b> ({{ antennas }}){% if not feasible %}, although it misses a constraint: no candidate meets them all{% endif %}.</p>
<p>{{ sentence }}</p>
{% else %}<p>No candidate finished.</p>{% endif %}
<p>Ranked by <b>{{ primary_label }}</b>{% if constraints %}, among candidates with {{ constraints }}{% endif %};
{{ n_candidates }} candidates, {{ replicates }} replicate(s) each on paired seeds. Every number is an
estimate with its 95 % interval from a bootstrap over (replicate, tag) or (replicate, filter run) units;
a difference is called only where its interval excludes 0.</p>
</div>
<h2>Ranking</h2>
{{ table }}
<h2>Figures</h2>
{% for f in figures %}<figure><img alt="{{ f.name }}" src="{{ f.src }}"><figcaption>{{ f.caption }}</figcaption></figure>
{% endfor %}
<h2>Objectives</h2><ul>
{% for o in objectives %}<li><b>{{ o.key }}</b>: {{ o.label }} ({{ "lower" if o.lower_is_better else "higher" }} is better; unit: {{ o.unit }})</li>
{% endfor %}</ul>
</body></html>
"""

_CAPTIONS = {
    "ranking": "The primary objective of every candidate with its 95 % interval, best first; grey "
               "candidates miss a constraint.",
    "heatmap": "The primary objective over the two-parameter grid; each cell's ± is half its 95 % "
               "interval. Cells whose intervals overlap are not distinguishable.",
    "pareto": "The two Pareto objectives of each candidate with intervals; red: the candidates no "
              "other beats on both.",
    "completeness_by_height": "Share of tags read at least k times per pass, per tag-height band: "
                              "where a mount loses the low or the high shelves.",
}


def _caption(name: str) -> str:
    if name.startswith("marginal_"):
        return (f"The primary objective against {name[9:]}, one line per value of the other grid "
                "fields (nothing averaged), with 95 % intervals.")
    if name.startswith("readmap_"):
        return (f"{name[8:]}: where along the route each training tag was read (replicate 0), by "
                "antenna; the tick marks the tag's own position.")
    return _CAPTIONS.get(name, name)


def margin_sentence(answer: dict, lower_is_better: bool) -> str:
    """The recommended candidate against the runner-up, from ``answer.json``'s margin
    (runner-up minus recommended on the same units), as a sentence with its verdict."""
    m, ru = answer.get("margin"), answer.get("runner_up")
    if not m or not ru or m.get("estimate") is None:
        return ""
    sgn = 1.0 if lower_is_better else -1.0  # the lead, positive when the recommended is ahead
    lead = sgn * m["estimate"]
    iv = ""
    if m.get("low") is not None and m.get("high") is not None:
        lo, hi = sorted((sgn * m["low"], sgn * m["high"]))
        iv = f" [{lo:.3g}, {hi:.3g}]"
    if m.get("verdict") == "worse":  # the runner-up is worse: a real lead
        return (f"It leads the runner-up {ru} by {lead:.3g}{iv} (95 % interval): a margin larger "
                "than its interval.")
    if m.get("verdict") == "better":  # the runner-up wins on the units both share
        return (f"On the units both were scored on, the runner-up {ru} is ahead by {-lead:.3g}"
                f"{iv}: the recommendation rests on units only it has; run more replicates.")
    return (f"Its lead over the runner-up {ru}, {lead:.3g}{iv}, is <b>not distinguishable at "
            "95 %</b>: choose between them on cost or mounting, or run more replicates.")


def write_report(spec, out: Path, df, answer: dict, figures: list) -> Path:
    """Write ``out/placement/report.html`` (figures embedded) and return its path."""
    from jinja2 import Environment, select_autoescape

    s = spec.settings
    best = answer.get("recommended")
    sentence = ""
    if best:
        r = df[df["candidate"] == best].iloc[0]
        lo, hi = r.get(f"{s.primary}_low"), r.get(f"{s.primary}_high")
        iv = (f" [{lo:.3g}, {hi:.3g}]" if lo is not None and np.isfinite(lo) and np.isfinite(hi)
              else "")
        sentence = f"{OBJECTIVES[s.primary].label}: {r[s.primary]:.3g}{iv}."
        sentence += " " + margin_sentence(answer, OBJECTIVES[s.primary].lower_is_better)
    cons = ", ".join(f"{c['objective']} {'>= ' + format(c['min'], 'g') if c['min'] is not None else ''}"
                     f"{' and ' if c['min'] is not None and c['max'] is not None else ''}"
                     f"{'<= ' + format(c['max'], 'g') if c['max'] is not None else ''}"
                     for c in answer.get("constraints") or [])
    figs = []
    for p in figures:
        p = Path(p)
        figs.append({"name": p.stem, "caption": _caption(p.stem),
                     "src": "data:image/png;base64," + base64.b64encode(p.read_bytes()).decode()})
    table = ranking_table(df, s).to_html(index=False, escape=True, border=0)
    env = Environment(autoescape=select_autoescape(default=True))
    from markupsafe import Markup

    text = env.from_string(_TEMPLATE).render(
        title=html.escape(str(spec.base.scene)), recommended=best,
        antennas=(df[df["candidate"] == best].iloc[0]["antennas"] if best else ""),
        feasible=answer.get("recommended_feasible", False), sentence=Markup(sentence),
        primary_label=OBJECTIVES[s.primary].label, constraints=cons,
        n_candidates=answer.get("n_candidates"), replicates=answer.get("replicates"),
        table=Markup(table), figures=figs, objectives=list(OBJECTIVES.values()))
    return atomic_write_bytes(out / "placement" / "report.html", text.encode("utf-8"))
