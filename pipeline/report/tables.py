"""The report's tables: run-directory numbers laid out as HTML tables.

Every value may come from a stranger's run directory: each is escaped (:func:`fmt_cell`),
malformed entries are skipped, missing values show as '–' and shares as percentages
(:func:`fmt_cell`).
:func:`metrics_tables` lays out any nested metrics by their JSON shape, so new metrics
show up without changes here; the named tables (held-out scores, error budget, MCL,
downstream, tag sites, rankings with intervals) are the report's sections
(:mod:`pipeline.report.html`).
"""

from __future__ import annotations

import html
import re

from pipeline.evaluation.headline import METRICS

__all__ = ["REPORT_CSS", "budget_html", "downstream_html", "flatten_scalars", "fmt_cell",
           "heldout_html", "intervals_html", "mcl_html", "metrics_tables",
           "model_comparison_tables", "sites_html", "table_html"]

#: The style sheet of every report (:mod:`pipeline.report.html`, :mod:`pipeline.report.recorded`).
REPORT_CSS = """
body{font-family:system-ui,-apple-system,Segoe UI,Roboto,sans-serif;max-width:1100px;margin:2em auto;
padding:0 1em;color:#222;line-height:1.45}
h1{font-size:1.6em}.smoke{border:2px solid #b00020;color:#b00020;padding:.6em;margin:1em 0}h2{border-bottom:1px solid #ccc;padding-bottom:.2em;margin-top:1.8em}
h3{font-size:1.05em;margin-bottom:.3em}
.tw{max-width:100%;overflow-x:auto}
table{border-collapse:collapse;margin:.4em 0 1.2em;font-size:.85em;max-width:100%}
th,td{border:1px solid #ccc;padding:.2em .5em;text-align:right;overflow-wrap:anywhere}
th{background:#f3f3f3;font-weight:600}td:first-child,th:first-child{text-align:left}
table.headline td{white-space:nowrap}table.headline td:first-child{white-space:normal}
.ci{color:#666;font-size:.9em}.up{color:#1a7f37}.down{color:#c62828}
figure{margin:1.4em 0;text-align:center}figure img{max-width:100%;height:auto;border:1px solid #eee}
figcaption{font-size:.9em;color:#333;margin-top:.4em;text-align:left}
details{margin:.8em 0}summary{cursor:pointer;font-weight:600}
pre{background:#f7f7f7;padding:.8em;overflow:auto;font-size:.8em;max-height:30em}
.muted{color:#666;font-size:.9em}
"""


_SHARE = re.compile(r"(share|fraction|within_\d|within \d|converged_share|recovered_share)",
                    re.IGNORECASE)


def _is_share(col: str) -> bool:
    """A column of shares in [0, 1] (shown as percentages): named so, and without a unit."""
    return bool(_SHARE.search(col)) and "[" not in col


def fmt_cell(v, col: str = "") -> str:
    """A table cell: '–' for a missing value, shares as percentages, 4 significant digits."""
    if v is None:
        return "–"
    if isinstance(v, bool):
        return "yes" if v else "no"
    if isinstance(v, int):
        return f"{v:d}"
    if isinstance(v, float):
        if v != v:
            return "–"
        if _is_share(col) and 0.0 <= v <= 1.0:
            return f"{100 * v:.1f} %"
        return f"{v:.4g}"
    return html.escape(str(v))


def _is_scalar(v) -> bool:
    return v is None or isinstance(v, (int, float, str, bool))


def metrics_tables(metrics: dict, prefix: str = "") -> list[tuple[str, list[str], list[list]]]:
    """Lay out nested metrics as tables.

    Parameters
    ----------
    metrics : dict
        Parsed ``metrics.json``.
    prefix : str
        Dotted name of ``metrics`` inside the whole document.

    Returns
    -------
    list of (title, column names, rows)
        A mapping whose values are all mappings of scalars becomes one table (rows =
        outer keys); a mapping's scalar entries become a two-column table; deeper
        nesting recurses with dotted titles.
    """
    tables = []
    scalars = [(k, v) for k, v in metrics.items() if _is_scalar(v)]
    subs = [(k, v) for k, v in metrics.items() if isinstance(v, dict)]
    if scalars:
        tables.append((prefix or "summary", ["quantity", "value"], [[k, v] for k, v in scalars]))
    for k, v in subs:
        name = f"{prefix}.{k}" if prefix else k
        rows_are_tables = v and all(
            isinstance(x, dict) and x and all(_is_scalar(y) for y in x.values()) for x in v.values()
        )
        if rows_are_tables:
            cols: list[str] = []
            for x in v.values():
                cols += [c for c in x if c not in cols]
            rows = [[rk] + [x.get(c) for c in cols] for rk, x in v.items()]
            tables.append((name, [""] + cols, rows))
        else:
            tables.extend(metrics_tables(v, name))
    return tables


def model_comparison_tables(models: dict) -> list[tuple[str, list[str], list[list]]]:
    """One table per metric group (rssi_dbm, detection, rho, fig7...): rows = models.

    Parameters
    ----------
    models : dict
        ``metrics.json``'s ``models`` mapping: model name -> group -> statistics.
    """
    groups: list[str] = []
    for m in models.values():
        if isinstance(m, dict):
            groups += [g for g, v in m.items() if isinstance(v, dict) and g not in groups]
    tables = []
    for g in groups:
        cols: list[str] = []
        rows = []
        for name, m in models.items():
            stats = flatten_scalars(m.get(g, {})) if isinstance(m, dict) else {}
            cols += [c for c in stats if c not in cols]
            rows.append((name, stats))
        tables.append((f"models: {g}", ["model"] + cols,
                       [[name] + [st.get(c) for c in cols] for name, st in rows]))
    return tables


_HEADLINE_COLS = (
    ("RSSI MAE [dB]", "rssi_dbm", "mae"), ("RSSI RMSE [dB]", "rssi_dbm", "rmse"),
    ("RSSI bias [dB]", "rssi_dbm", "bias"), ("RSSI links", "rssi_dbm", "n"),
    ("RMSE on the bound's links [dB]", "rssi_dbm_bound_links", "rmse"), ("fT cell MAE", "detection", "mae"),
    ("Brier", "detection", "brier"), ("Fig. 7 median, in-domain [%]", "fig7", "median_pct"),
    ("Fig. 7 p90 [%]", "fig7", "p90_pct"), ("Fig. 7 share < 20 %", "fig7", "share_below_20pct"),
)




def heldout_html(metrics: dict) -> list[str]:
    """The held-out table: every model's point scores against the truth, and the bound."""
    held = metrics["heldout"]
    fig7 = metrics.get("fig7") or {}
    data = held.get("data") or {}
    out = ["<h3>Held-out scores in detail</h3>",
           f"<p>Every number is on data no model saw: the evaluation tour (its own MCL run in "
           f"the same map) reading the held-out tag layout ({fmt_cell(data.get('n_tags'))} tags, "
           f"{fmt_cell(data.get('n_attempts'))} attempts), against the noise-free ray-traced truth; "
           f"RSSI within d &lt; {fmt_cell(data.get('d_max_m'))} m. Baselines are fitted on the "
           "training tour only. Fig. 7 is chapter Sec. 5: |f&#772;s - s| x 100 on "
           "normalised RSSI, within the training domain. '–': the model predicts no such "
           "quantity. The row 'bound' is an oracle, not a model: the held-out truth's own "
           "(d, &alpha;) cell means on its own links (cells holding enough of them), which no "
           "function constant on those cells can beat there; 'RMSE on the bound's links' "
           "puts every model on those same links, and the error budget uses them.</p>"]
    rows = []
    models = dict(held.get("models") or {})
    models["bound"] = held.get("bound") or {}
    for name, m in models.items():
        row = [name]
        for _, sec, key in _HEADLINE_COLS:
            if sec == "fig7":
                src = fig7.get(name)
            elif name == "bound" and sec == "rssi_dbm_bound_links":
                src = (m or {}).get("rssi_dbm")  # the bound is on its own links
            else:
                src = (m or {}).get(sec)
            row.append(None if not isinstance(src, dict) else src.get(key))
        rows.append(row)
    out.append(table_html("held-out: model against the ray-traced truth",
                           ["model"] + [c[0] for c in _HEADLINE_COLS], rows))
    return out


_BUDGET_ORDER = ("representation_bound", "model_form", "localisation", "reader_noise", "total",
                 "n_links")


def budget_html(metrics: dict) -> list[str]:
    """The error budget of the held-out RSSI error (terms in the budget's order; a term
    with no number at all is left out) and the bound against the cell size."""
    out = []
    budget = metrics.get("error_budget")
    if isinstance(budget, dict):
        cols = ("rmse_db", "between_cells_db", "within_cells_db2", "step_db", "how")
        terms = [k for k, v in budget.items() if isinstance(v, dict) and k != "by_cell_size"]
        terms = sorted(terms, key=lambda k: _BUDGET_ORDER.index(k) if k in _BUDGET_ORDER
                       else len(_BUDGET_ORDER))  # stable: unknown terms keep their order
        rows = [[k, *[budget[k].get(c) for c in cols]] for k in terms
                if any(budget[k].get(c) is not None for c in cols[:-1])]
        n = (budget.get("n_links") or {}).get("value") if isinstance(budget.get("n_links"),
                                                                     dict) else None
        out.append(table_html(
            "error budget of the held-out RSSI error"
            + (f" (matched terms on {n} links)" if n is not None else ""),
            ["term", "RMSE [dB]", "between cells [dB]", "within cells [dB²]", "step [dB]", "how"],
            rows))
        by_size = budget.get("by_cell_size")
        if isinstance(by_size, dict) and by_size:
            cols = [c for v in by_size.values() for c in v]
            cols = list(dict.fromkeys(cols))
            out.append(table_html("the bound against the cell size (smaller cells: a lower "
                                   "bound, down to 0 at one link per cell)", ["cells", *cols],
                                   [[k, *[v.get(c) for c in cols]] for k, v in by_size.items()]))
    return out


def mcl_html(metrics: dict) -> list[str]:
    """MCL pose error and bias per tour, one row per tour (transposed: a column per tour,
    so the many statistics fit the page)."""
    loc = metrics.get("localisation")
    if not isinstance(loc, dict) or not loc:
        return []
    tours = [k for k, v in loc.items() if isinstance(v, dict)]
    stats: list[str] = []
    for k in tours:
        stats += [c for c, x in loc[k].items() if _is_scalar(x) and c not in stats]
    return [table_html("MCL pose error and bias (biased map)", ["statistic", *tours],
                        [[c, *[loc[k].get(c) for k in tours]] for c in stats])]


def downstream_html(metrics: dict) -> list[str]:
    """The downstream tables: held-out tags and the RFID-only robot filter per model."""
    out = []
    for key, title, cols in (
            ("tag_localisation", "held-out tags localised from the evaluation tour's "
             "reads (MAP over candidate sites; 3-D error)",
             ("median_m", "p90_m", "rmse_m", "within_0_5m", "within_1m", "horizontal_median_m",
              "n_tags")),
            ("robot_localisation", "RFID-only robot localisation (unknown start, "
             "kidnapped halfway; medians over every step of every filter run, before and "
             "from the kidnapping; runs that converged and recovered)",
             ("median_m", "median_before_kidnap_m", "median_after_kidnap_m", "p90_m",
              "converged_runs", "recovered_runs", "n_runs"))):
        sec = metrics.get(key)
        if isinstance(sec, dict) and sec:
            out.append(table_html(title, ["model", *cols],
                                   [[n, *[(v or {}).get(c) for c in cols]] for n, v in sec.items()]))
    return out


def sites_html(metrics: dict) -> list[str]:
    """Truth where tags are: the model's rho against the truth at clear and obstructed sites."""
    out = []
    sites = metrics.get("tag_sites")
    if isinstance(sites, dict) and sites:
        rows = []
        for name, s in sites.items():
            for part in ("clear", "obstructed"):
                p = s.get(part) or {}
                rho = p.get("rho") or {}
                rows.append([name, part, p.get("n_pairs"), rho.get("mae"), rho.get("bias"),
                             p.get("fT_mae"), p.get("true_read_fraction"),
                             p.get("predicted_read_fraction")])
        out.append("<p>Truth where tags are: every tag site (a grid on every surface facing "
                   "free space, tag dipole in the surface) within the training domain of "
                   "evaluation-tour antenna poses; 'obstructed': the straight line crosses a "
                   "wall, cabinet or box.</p>")
        out.append(table_html("tag sites: model against the truth",
                               ["model", "pairs", "n", "rho MAE", "rho bias", "fT MAE",
                                "true read fraction", "predicted read fraction"], rows))
    return out


def flatten_scalars(d: dict, prefix: str = "") -> dict:
    """Scalars of a nested mapping with dotted keys (one level deep; lists dropped)."""
    out = {}
    for k, v in d.items():
        if _is_scalar(v):
            out[f"{prefix}{k}"] = v
        elif isinstance(v, dict) and not prefix:
            out.update({kk: vv for kk, vv in flatten_scalars(v, f"{k}.").items()})
    return out


def _is_number(v) -> bool:
    return isinstance(v, (int, float)) and not isinstance(v, bool)


def _interval_text(iv: dict | None, digits: int = 3) -> str:
    if not isinstance(iv, dict) or not _is_number(iv.get("estimate")):
        return "–"
    est = f"{iv['estimate']:.{digits}g}"
    if not (_is_number(iv.get("low")) and _is_number(iv.get("high"))):
        return f"{est} (no interval: {iv.get('note') or 'undefined'})"
    return f"{est} [{iv['low']:.{digits}g}, {iv['high']:.{digits}g}]"


def intervals_html(metrics: dict) -> list[str]:
    """The ranking tables: per headline metric, every model's estimate with its 95 %
    interval, its difference to the reference model on the same units and the verdict
    (``metrics.json`` sections ``intervals`` and ``comparisons``,
    :mod:`pipeline.evaluation.headline`). Models are listed best first by estimate; a
    difference is stated only where its interval excludes 0."""
    ivs = metrics.get("intervals")
    if not isinstance(ivs, dict) or not ivs:
        return []
    cmp_ = metrics.get("comparisons") if isinstance(metrics.get("comparisons"), dict) else {}
    ref = str(cmp_.get("reference", "anfis"))
    by_metric = cmp_.get("metrics") if isinstance(cmp_.get("metrics"), dict) else {}
    out = ["<h3>Rankings with 95 % intervals</h3>",
           f"<p>Each number with its 95 % confidence interval from a bootstrap over the "
           f"independent units (held-out tags; filter runs; with replicates, both within each "
           f"replicate), and each model against <b>{html.escape(ref)}</b> on the same units: "
           "'better' or 'worse' only where the interval of the difference excludes 0, else "
           "'not distinguishable at 95 %'. The order of the rows is the estimates' and is not "
           "a ranking where the verdicts say 'not distinguishable'.</p>"]
    for key, sec in ivs.items():
        if not isinstance(sec, dict) or not isinstance(sec.get("models"), dict):
            continue  # a malformed entry of a stranger's metrics.json: not shown
        models = {m: e for m, e in sec["models"].items()
                  if isinstance(e, dict) and _is_number(e.get("estimate"))}
        lower = next((m.lower_is_better for m in METRICS if m.key == key), True)
        order = sorted(models, key=lambda m: (models[m].get("estimate") is None,
                                              (1 if lower else -1) * (models[m].get("estimate") or 0)))
        rows = []
        for m in order:
            per = by_metric.get(key) if isinstance(by_metric.get(key), dict) else {}
            c = per.get(m) if isinstance(per.get(m), dict) else None
            rows.append([m, _interval_text(models[m]),
                         "(reference)" if m == ref else _interval_text(c),
                         "" if m == ref else str((c or {}).get("verdict", "–"))])
        out.append(table_html(f"{sec.get('label', key)}: {sec.get('n_units')} {sec.get('unit')}s",
                               ["model", "estimate [95 % interval]",
                                f"minus {ref} [95 % interval]", "verdict"], rows))
    return out


def table_html(title: str, cols: list[str], rows: list[list]) -> str:
    # headers break at underscores (long keys would otherwise widen the table off the page)
    head = "".join(f"<th>{html.escape(str(c)).replace('_', '_<wbr>')}</th>" for c in cols)
    body = "".join("<tr>" + "".join(f"<td>{fmt_cell(c, str(col))}</td>"
                                    for c, col in zip(r, cols, strict=False)) + "</tr>"
                   for r in rows)
    return (f"<h3>{html.escape(title)}</h3><div class='tw'><table><tr>{head}</tr>{body}"
            "</table></div>")

