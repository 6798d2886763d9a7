"""``placement/report.html``: the answer first, then the table, then the figures (Jinja2)."""

from __future__ import annotations

import base64
import html
from pathlib import Path

import numpy as np

from pipeline.apps.placement.objectives import OBJECTIVES
from pipeline.apps.placement.results import ranking_table
from pipeline.engine.runstore import atomic_write_bytes

__all__ = ["answer_lines", "confirmation_sentence", "engineering_sentence", "margin_sentence", "write_report"]

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
{% if single_best %}<p><b>Recommended: {{ recommended }}</b> ({{ antennas }}){% if feasibility != "met" %}, although {{ "it may miss a constraint (its interval straddles a limit)" if feasibility == "uncertain" else "it misses a constraint: no candidate meets them all" }}{% endif %}.</p>
{% else %}<p><b>No single best.</b> {{ recommended }} ({{ antennas }}) leads on the estimate, but
{{ tied }} {{ "is" if n_tied == 1 else "are" }} not distinguishable from it at 95 %: choose among them on cost or
mounting, or run more replicates.{% if feasibility != "met" %} Its constraints are {{ feasibility }} on their intervals.{% endif %}</p>{% endif %}
<p>{{ sentence }}</p>
{% if units %}<p>In the engineer's units: {{ units }}.</p>{% endif %}
{% if confirmation %}<p>{{ confirmation }}</p>{% endif %}
{% else %}<p>No candidate finished.</p>{% endif %}
<p>Ranked by <b>{{ primary_label }}</b>{% if constraints %}, among candidates with {{ constraints }}{% endif %};
{{ n_candidates }} candidates, {{ replicates }} replicate(s) each on paired seeds. Every number is an
estimate with its 95 % interval from a bootstrap over (replicate, tag) or (replicate, filter run) units;
a difference is called only where its interval excludes 0.
Each study ran up to its <code>{{ upto }}</code> stage{% if upto == "reads" %} (the objectives asked need
no fitted model){% endif %}.</p>
{% for d in dropped %}<p><b>Not computed:</b> {{ d }}</p>
{% endfor %}
<p><small>Selection rule: {{ rule }}</small></p>
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
        return (f"{name[8:]}: reads per metre of route against the distance driven on the "
                "training tour (replicate 0), one row per tag, ordered by where the route passes "
                "it closest (black tick); red crosses: tags never read.")
    if name.startswith("never_read_"):
        return (f"{name[11:]}: top view of the tags the training tour never read (replicate 0), "
                "with the walls at the lower tag height and the driven tour.")
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


def confirmation_sentence(answer: dict) -> str:
    """The confirmation on fresh replicates (``answer.json``'s ``confirmation``) as a
    sentence: each candidate's estimate and interval there, and whether the lead holds."""
    c = answer.get("confirmation")
    if not c:
        return ""

    def iv(d):
        txt = f"{d['estimate']:.3g}" if d.get("estimate") is not None else "–"
        if d.get("low") is not None and d.get("high") is not None:
            txt += f" [{d['low']:.3g}, {d['high']:.3g}]"
        return txt

    lo, hi = c["replicates"]
    parts = ", ".join(f"{n} {iv(d)}" for n, d in c["estimates"].items())
    first = c["candidates"][0]
    verdict = ("it is ahead of each at 95 % there" if c.get("holds") else
               "its lead is not confirmed at 95 % there")
    return (f"Confirmation on fresh replicates {lo}-{hi}, which took no part in the selection: "
            f"{answer.get('primary')} {parts}; {first} was selected, and {verdict}.")


def answer_lines(df, answer: dict) -> list[str]:
    """The answer as the console prints it: the recommendation with its lead's verdict,
    its inventory in the engineer's units, and what was not computed."""
    out = []
    best = answer.get("recommended")
    if best and not answer.get("runner_up"):
        out.append(f"recommended: {best} (the only candidate with results: nothing to compare)")
    elif best:
        verdict = (answer.get("margin") or {}).get("verdict")
        lead = ("its lead over the runner-up exceeds the 95 % interval" if verdict == "worse" else
                "the runner-up is ahead on the units both share: run more replicates"
                if verdict == "better" else "not distinguishable from the runner-up at 95 %")
        if answer.get("single_best", True):
            out.append(f"recommended: {best} ({lead})")
        else:
            out.append(f"no single best: {best} leads on the estimate; not distinguishable from "
                       f"it at 95 %: {', '.join(answer.get('tied_with_best') or [])}")
    if best and (units := engineering_sentence(df[df["candidate"] == best].iloc[0])):
        out.append(f"  {units}")
    if (conf := confirmation_sentence(answer)):
        out.append(conf)
    out.extend(f"not computed: {d}" for d in answer.get("dropped") or [])
    return out


def engineering_sentence(row) -> str:
    """A candidate's inventory in the units a mount is chosen by: reads per tag per
    pass, link margin, tags never read (each with its 95 % interval)."""
    def iv(key, fmt):
        v, lo, hi = row.get(key), row.get(f"{key}_low"), row.get(f"{key}_high")
        if v is None or not np.isfinite(v):
            return None
        out = format(v, fmt)
        if lo is not None and hi is not None and np.isfinite(lo) and np.isfinite(hi):
            out += f" [{format(lo, fmt)}, {format(hi, fmt)}]"
        return out

    parts = []
    if (t := iv("reads_per_pass", ".3g")) is not None:
        parts.append(f"{t} reads per tag per pass")
    if (t := iv("link_margin_db", ".1f")) is not None:
        parts.append(f"a median best link margin of {t} dB per pass")
    n, tot = row.get("never_read_n"), row.get("n_tags")
    if n is not None and tot is not None and np.isfinite(n) and np.isfinite(tot):
        share = iv("never_read", ".3g")
        parts.append(f"{n:.3g} of {tot:.3g} tags never read in the tour"
                     + (f" (share {share})" if share else ""))
    return "; ".join(parts)


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
    units = ""
    if best:
        units = engineering_sentence(df[df["candidate"] == best].iloc[0])
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
        feasibility=answer.get("recommended_feasibility") or "met", sentence=Markup(sentence),
        single_best=answer.get("single_best", True),
        tied=", ".join(answer.get("tied_with_best") or []),
        n_tied=len(answer.get("tied_with_best") or []), rule=answer.get("rule", ""),
        confirmation=confirmation_sentence(answer),
        primary_label=OBJECTIVES[s.primary].label, constraints=cons,
        n_candidates=answer.get("n_candidates"), replicates=answer.get("replicates"),
        table=Markup(table), figures=figs, objectives=list(OBJECTIVES.values()), units=units,
        upto=answer.get("studies_ran_upto", "evaluation"), dropped=answer.get("dropped") or [])
    return atomic_write_bytes(out / "placement" / "report.html", text.encode("utf-8"))  # runfiles: placement's own
