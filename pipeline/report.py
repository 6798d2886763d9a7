"""A self-contained HTML report made from a run directory's files alone.

Reads ``config.toml``, ``manifest.json``, ``metrics.json`` and ``figures/*.png``
(images embedded as base64, so the HTML file can be mailed on its own) and writes
``report.html`` atomically. Metrics tables are laid out from the JSON's nesting:
a mapping of mappings of numbers becomes one table (rows = outer keys), so new
metrics show up without changes here.
"""

from __future__ import annotations

import base64
import datetime as _dt
import html
import json
import logging
import os
import tomllib
from pathlib import Path

from pipeline.evaluation.headline import METRICS
from pipeline.runstore import (
    UnsafePathError,
    atomic_write_text,
    read_run_json,
    regular_file,
    run_files,
)

__all__ = ["figure_captions", "headline_html", "intervals_html", "metrics_tables",
           "model_comparison_tables", "write_pooled_report", "write_report"]

log = logging.getLogger(__name__)

_CSS = """
body{font-family:system-ui,-apple-system,Segoe UI,Roboto,sans-serif;max-width:1100px;margin:2em auto;
padding:0 1em;color:#222}
h1{font-size:1.6em}h2{border-bottom:1px solid #ccc;padding-bottom:.2em;margin-top:1.6em}
table{border-collapse:collapse;margin:.6em 0 1.2em;font-size:.9em}
th,td{border:1px solid #ccc;padding:.25em .6em;text-align:right}th{background:#f3f3f3}
td:first-child,th:first-child{text-align:left}
figure{margin:1.2em 0;text-align:center}figure img{max-width:100%;border:1px solid #eee}
figcaption{font-size:.9em;color:#444;margin-top:.4em;text-align:left}
pre{background:#f7f7f7;padding:.8em;overflow:auto;font-size:.8em;max-height:30em}
.muted{color:#777;font-size:.85em}
"""


def _load_json(path: Path) -> dict | None:
    """A JSON object from a run directory (:func:`pipeline.runstore.read_run_json`: a
    regular file, no link followed, size-capped); anything else is a ValueError naming it."""
    if not os.path.lexists(path):
        return None
    data = read_run_json(path)
    if not isinstance(data, dict):
        raise ValueError(f"{path}: expected a JSON object, got {type(data).__name__}")
    return data


def _fmt(v) -> str:
    if isinstance(v, bool) or v is None:
        return html.escape(str(v))
    if isinstance(v, int):
        return f"{v:d}"
    if isinstance(v, float):
        if v != v:
            return "–"
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
            stats = _flatten(m.get(g, {})) if isinstance(m, dict) else {}
            cols += [c for c in stats if c not in cols]
            rows.append((name, stats))
        tables.append((f"models: {g}", ["model"] + cols,
                       [[name] + [st.get(c) for c in cols] for name, st in rows]))
    return tables


def _methods_html(run: Path, cfg: dict) -> list[str]:
    """Methods: materials (P.2040 fits extrapolated to the study frequency), radio geometry
    and the held-out design, from scene/scene.json and config.toml."""
    from scenes.materials import extrapolated_materials

    info = _load_json(run / "scene" / "scene.json") or {}
    f_hz = float(cfg.get("frequency_hz", 865e6))
    out = ["<h2>Methods</h2>",
           "<p>Walls, floor and ceiling are traced as one radio surface per physical layer "
           "carrying its thickness (a stud partition as two plasterboard leaves); Sionna RT "
           "applies the ITU-R P.2040 slab model once per surface crossed. Boxes and cabinets "
           "are closed shells. The evaluation tour reads a held-out tag layout "
           f"({_fmt(info.get('n_tags_eval'))} tags drawn on the scene's surfaces with their "
           f"own seed) that the training tour ({_fmt(info.get('n_tags_train'))} tags) never "
           "reads.</p>"]
    try:
        rows = extrapolated_materials(info.get("materials") or [], f_hz)
    except Exception:  # an unknown material in an old run directory: say nothing wrong
        rows = []
    if rows:
        out.append(f"<p>Material properties follow ITU-R P.2040-3 Table 3; these fits are valid "
                   f"from 1 GHz and are extrapolated to {f_hz / 1e9:.4g} GHz (smooth power "
                   "laws, the usual practice for UHF):</p>")
        out.append(_table_html("materials extrapolated below their P.2040 range",
                               ["material", "valid from [GHz]", "eps_r", "sigma [S/m]"],
                               [[r["material"], r["range_ghz"][0], r["relative_permittivity"],
                                 r["conductivity_s_per_m"]] for r in rows]))
    return out


_HEADLINE_COLS = (
    ("RSSI MAE [dB]", "rssi_dbm", "mae"), ("RSSI RMSE [dB]", "rssi_dbm", "rmse"),
    ("RSSI bias [dB]", "rssi_dbm", "bias"), ("RSSI links", "rssi_dbm", "n"),
    ("RMSE on the bound's links [dB]", "rssi_dbm_bound_links", "rmse"), ("fT cell MAE", "detection", "mae"),
    ("Brier", "detection", "brier"), ("Fig. 7 median [%]", "fig7", "median_pct"),
    ("Fig. 7 p90 [%]", "fig7", "p90_pct"), ("Fig. 7 share < 20 %", "fig7", "share_below_20pct"),
)


def headline_html(metrics: dict) -> list[str]:
    """The held-out headline, error budget, MCL bias and tag-site tables as HTML parts.

    Parameters
    ----------
    metrics : dict
        ``metrics.json`` with a ``heldout`` section (see ``pipeline.stages.evaluation``).
    """
    held = metrics["heldout"]
    fig7 = metrics.get("fig7") or {}
    data = held.get("data") or {}
    out = ["<h3>Held-out scores (the headline)</h3>",
           f"<p>Every number is on data no model saw: the evaluation tour (its own MCL run in "
           f"the same map) reading the held-out tag layout ({_fmt(data.get('n_tags'))} tags, "
           f"{_fmt(data.get('n_attempts'))} attempts), against the noise-free ray-traced truth; "
           f"RSSI within d &lt; {_fmt(data.get('d_max_m'))} m. Baselines are fitted on the "
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
    out.append(_table_html("held-out: model against the ray-traced truth",
                           ["model"] + [c[0] for c in _HEADLINE_COLS], rows))
    budget = metrics.get("error_budget")
    if isinstance(budget, dict):
        cols = ("rmse_db", "between_cells_db", "within_cells_db2", "step_db", "how")
        out.append(_table_html(
            "error budget of the held-out RSSI error",
            ["term", "RMSE [dB]", "between cells [dB]", "within cells [dB²]", "step [dB]", "how"],
            [[k, *[v.get(c) for c in cols]] for k, v in budget.items()
             if isinstance(v, dict) and k != "by_cell_size"]))
        by_size = budget.get("by_cell_size")
        if isinstance(by_size, dict) and by_size:
            cols = [c for v in by_size.values() for c in v]
            cols = list(dict.fromkeys(cols))
            out.append(_table_html("the bound against the cell size (smaller cells: a lower "
                                   "bound, down to 0 at one link per cell)", ["cells", *cols],
                                   [[k, *[v.get(c) for c in cols]] for k, v in by_size.items()]))
    loc = metrics.get("localisation")
    if isinstance(loc, dict) and loc:
        cols = []
        for v in loc.values():
            if isinstance(v, dict):
                cols += [c for c, x in v.items() if _is_scalar(x) and c not in cols]
        out.append(_table_html("MCL pose error and bias (biased map)", ["tour"] + cols,
                               [[k] + [v.get(c) for c in cols] for k, v in loc.items()
                                if isinstance(v, dict)]))
    for key, title, cols in (
            ("tag_localisation", "downstream: held-out tags localised from the evaluation tour's "
             "reads (MAP over candidate sites; 3-D error)",
             ("median_m", "p90_m", "rmse_m", "within_0_5m", "within_1m", "horizontal_median_m",
              "n_tags")),
            ("robot_localisation", "downstream: RFID-only robot localisation (unknown start, "
             "kidnapped halfway; medians over every step of every filter run, before and "
             "from the kidnapping; the range of the per-run medians; runs that converged "
             "and recovered)", ("median_m", "median_before_kidnap_m", "median_after_kidnap_m",
                                "median_m_min", "median_m_max", "p90_m", "converged_runs",
                                "recovered_runs", "converge_s", "recover_s", "n_runs"))):
        sec = metrics.get(key)
        if isinstance(sec, dict) and sec:
            out.append(_table_html(title, ["model", *cols],
                                   [[n, *[(v or {}).get(c) for c in cols]] for n, v in sec.items()]))
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
        out.append(_table_html("tag sites: model against the truth",
                               ["model", "pairs", "n", "rho MAE", "rho bias", "fT MAE",
                                "true read fraction", "predicted read fraction"], rows))
    return out


def _flatten(d: dict, prefix: str = "") -> dict:
    """Scalars of a nested mapping with dotted keys (one level deep; lists dropped)."""
    out = {}
    for k, v in d.items():
        if _is_scalar(v):
            out[f"{prefix}{k}"] = v
        elif isinstance(v, dict) and not prefix:
            out.update({kk: vv for kk, vv in _flatten(v, f"{k}.").items()})
    return out


def figure_captions(run_dir: Path) -> dict[str, str]:
    """Captions by figure stem: ``figures/captions.json`` if present, else pipeline.figures'."""
    p = run_dir / "figures" / "captions.json"
    caps = _load_json(p) if p.exists() else None
    if isinstance(caps, dict):
        return {str(k): str(v) for k, v in caps.items()}
    try:
        from pipeline import figures

        caps = getattr(figures, "CAPTIONS", None)
        return dict(caps) if isinstance(caps, dict) else {}
    except ImportError:
        return {}


def _interval_text(iv: dict | None, digits: int = 3) -> str:
    if not isinstance(iv, dict) or iv.get("estimate") is None:
        return "–"
    est = f"{iv['estimate']:.{digits}g}"
    if iv.get("low") is None or iv.get("high") is None:
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
    cmp_ = metrics.get("comparisons") or {}
    ref = cmp_.get("reference", "anfis")
    by_metric = cmp_.get("metrics") or {}
    out = ["<h3>Rankings with 95 % intervals</h3>",
           f"<p>Each number with its 95 % confidence interval from a bootstrap over the "
           f"independent units (held-out tags; filter runs; with replicates, both within each "
           f"replicate), and each model against <b>{html.escape(ref)}</b> on the same units: "
           "'better' or 'worse' only where the interval of the difference excludes 0, else "
           "'not distinguishable at 95 %'. The order of the rows is the estimates' and is not "
           "a ranking where the verdicts say 'not distinguishable'.</p>"]
    for key, sec in ivs.items():
        models = sec.get("models") or {}
        lower = next((m.lower_is_better for m in METRICS if m.key == key), True)
        order = sorted(models, key=lambda m: (models[m].get("estimate") is None,
                                              (1 if lower else -1) * (models[m].get("estimate") or 0)))
        rows = []
        for m in order:
            c = (by_metric.get(key) or {}).get(m)
            rows.append([m, _interval_text(models[m]),
                         "(reference)" if m == ref else _interval_text(c),
                         "" if m == ref else (c or {}).get("verdict", "–")])
        out.append(_table_html(f"{sec.get('label', key)}: {sec.get('n_units')} {sec.get('unit')}s",
                               ["model", "estimate [95 % interval]",
                                f"minus {ref} [95 % interval]", "verdict"], rows))
    return out


def write_pooled_report(metrics: dict, out: str | Path) -> Path:
    """``report.html`` of a replicated study (:mod:`pipeline.replicates`): which
    replicates it covers, the pooled rankings with intervals, each replicate's own
    estimates, and links to the replicates' reports."""
    rep = metrics.get("replicates") or {}
    parts = ["<!DOCTYPE html><html><head><meta charset='utf-8'>",
             "<title>rfidstudy report: replicated study</title>",
             f"<style>{_CSS}</style></head><body>",
             f"<h1>Replicated study: {html.escape(str(rep.get('covers', '?')))}</h1>",
             "<p>The same study run on independent seed streams (tour noise, MCL, reader "
             "noise, held-out tag layout, robot filter runs); every number below pools the "
             "complete replicates' held-out tags and filter runs.</p>"]
    failed = rep.get("failed") or []
    if failed:
        parts.append(_table_html("failed replicates (not pooled)", ["replicate", "seed", "error"],
                                 [[f.get("k"), f.get("seed"), f.get("error")] for f in failed]))
    parts.extend(intervals_html(metrics))
    per = metrics.get("per_replicate") or {}
    reps = per.get("replicates") or []
    parts.append("<h2>Each replicate's own estimates</h2>")
    for key, models in (per.get("metrics") or {}).items():
        label = ((metrics.get("intervals") or {}).get(key) or {}).get("label", key)
        parts.append(_table_html(label, ["model", *[f"replicate {k}" for k in reps]],
                                 [[m, *vals] for m, vals in models.items()]))
    parts.append("<h2>Replicates</h2><ul>")
    for k in reps:
        parts.append(f"<li><a href='replicates/{int(k)}/report.html'>replicate {int(k)}</a> "
                     f"(seed {html.escape(str((rep.get('seeds') or {}).get(str(k))))})</li>")
    parts.append("</ul></body></html>\n")
    out = Path(out)
    atomic_write_text(out, "\n".join(parts))
    return out


def _table_html(title: str, cols: list[str], rows: list[list]) -> str:
    head = "".join(f"<th>{html.escape(str(c))}</th>" for c in cols)
    body = "".join("<tr>" + "".join(f"<td>{_fmt(c)}</td>" for c in r) + "</tr>" for r in rows)
    return f"<h3>{html.escape(title)}</h3><table><tr>{head}</tr>{body}</table>"


def write_report(run_dir: str | Path, embed: bool = True, out: str | Path | None = None) -> Path:
    """Write ``<run_dir>/report.html`` from the run directory's files alone.

    Parameters
    ----------
    run_dir : path
        A run directory (``config.toml``, ``manifest.json``, ``metrics.json``,
        ``figures/*.png``; missing pieces are reported as missing, not fatal).
    embed : bool
        Embed the PNGs as base64 (self-contained file) or link them relatively.
    out : path, optional
        Where to write (default ``<run_dir>/report.html``).

    Returns
    -------
    pathlib.Path
        The report's path.

    Raises
    ------
    FileNotFoundError
        If ``run_dir`` is not a directory.
    ValueError
        If ``metrics.json`` or ``manifest.json`` is not valid JSON (names the file).
    """
    run = Path(run_dir)
    if not run.is_dir():
        raise FileNotFoundError(f"{run}: not a run directory")
    manifest = _load_json(run / "manifest.json") or {}
    metrics = _load_json(run / "metrics.json")
    cfg_path = run / "config.toml"
    if os.path.lexists(cfg_path) and not regular_file(cfg_path):
        raise ValueError(f"{cfg_path}: not a regular file (a link or a special file): not read")
    try:
        cfg_text = cfg_path.read_text(encoding="utf-8") if cfg_path.exists() else ""
        cfg = tomllib.loads(cfg_text) if cfg_text else {}
    except (UnicodeDecodeError, tomllib.TOMLDecodeError) as exc:
        raise ValueError(f"{cfg_path}: not a valid TOML file: {exc}") from None
    parts = [
        "<!DOCTYPE html><html><head><meta charset='utf-8'>",
        f"<title>rfidstudy report: {html.escape(str(cfg.get('scene', run.name)))}</title>",
        f"<style>{_CSS}</style></head><body>",
        f"<h1>RFID sensor-model study: {html.escape(str(cfg.get('scene', '?')))}</h1>",
        "<p>Ray-traced UHF RFID sensor model (Cicirelli, Milella &amp; Di Paola 2011): "
        "RSSI model f<sub>s</sub>(d, &alpha;) and detection model f<sub>T</sub>(d, &alpha;), "
        "FCM-initialised Takagi-Sugeno systems trained by ANFIS (Jang 1993), "
        "&rho; = f<sub>s</sub> f<sub>T</sub>.</p>",
        f"<p class='muted'>Run directory <code>{html.escape(str(run.resolve()))}</code>; "
        f"report written {_dt.datetime.now(_dt.timezone.utc).isoformat(timespec='seconds')}.</p>",
    ]
    # summary
    parts.append("<h2>Run summary</h2>")
    summary = [
        ["scene", cfg.get("scene")],
        ["seed", manifest.get("seed", cfg.get("seed"))],
        ["frequency_hz", cfg.get("frequency_hz")],
        # The report stage runs last, after every other stage succeeded, while the
        # manifest still says "running": only a recorded failure makes it incomplete.
        ["status", "failed" if manifest.get("failure") else "complete"],
        ["elapsed_s", manifest.get("elapsed_s")],
        ["peak_rss_mib", manifest.get("peak_rss_mib")],
    ]
    backend = manifest.get("backend") or {}
    if isinstance(backend, dict) and backend:
        summary.append(["Dr.Jit variant", backend.get("variant")])
    parts.append(_table_html("run", ["item", "value"], summary))
    stages = manifest.get("stages") or {}
    if stages:
        rows = [[n, s.get("status"), s.get("elapsed_s"), s.get("peak_rss_mib")] for n, s in stages.items()]
        parts.append(_table_html("stages", ["stage", "status", "elapsed_s", "peak_rss_mib"], rows))
    parts.extend(_methods_html(run, cfg))
    # metrics
    parts.append("<h2>Metrics</h2>")
    if metrics is None:
        parts.append("<p>metrics.json is missing (evaluation did not run).</p>")
    else:
        body = metrics.get("evaluation", metrics)
        rest = dict(body)
        if isinstance(body.get("heldout"), dict):
            parts.extend(headline_html(body))
            parts.extend(intervals_html(body))
            for key in ("heldout", "fig7", "error_budget", "localisation", "tag_sites",
                        "tag_localisation", "robot_localisation", "intervals", "comparisons"):
                rest.pop(key, None)
            if isinstance(rest.get("in_sample"), dict):
                parts.append("<h3>In-sample (training tour, training tags)</h3><p class='muted'>"
                             "Scored on the reads the models were fitted on: optimistic, kept for "
                             "comparison with the held-out table above.</p>")
        if isinstance(body.get("models"), dict):
            parts.append("<p>ANFIS (trained on MCL poses) against the baselines, and against the "
                         "same models trained on true poses (the localisation-error split).</p>")
            for title, cols, rows in model_comparison_tables(rest.pop("models")):
                parts.append(_table_html(title, cols, rows))
        split = rest.pop("localisation_split", None)
        if isinstance(split, dict) and isinstance(split.get("difference"), dict):
            # evaluate_all writes the differences flat: {"rssi_dbm.mae": x, ...}
            rows = [[k, v] for k, v in sorted(_flatten(split["difference"]).items())]
            parts.append("<p>Each value is the metric of the model trained on MCL poses minus "
                         "that of the model trained on true poses: the share of the error that "
                         "localisation adds.</p>")
            parts.append(_table_html("MCL-pose minus true-pose model", ["metric", "difference"],
                                     rows))
        for title, cols, rows in metrics_tables(rest):
            parts.append(_table_html(title, cols, rows))
    # figures
    parts.append("<h2>Figures</h2>")
    captions = figure_captions(run)
    try:  # regular files only: a link could embed any file of the reader's
        pngs = run_files(run, "figures", "*.png")
    except UnsafePathError as exc:
        log.warning("report: %s; no figure embedded", exc)
        pngs = []
    if not pngs:
        parts.append("<p>No figures in figures/.</p>")
    for png in pngs:
        if embed:
            src = "data:image/png;base64," + base64.b64encode(png.read_bytes()).decode("ascii")
        else:
            src = png.relative_to(run).as_posix()
        cap = captions.get(png.stem, png.stem.replace("_", " "))
        parts.append(f"<figure><img src='{src}' alt='{html.escape(png.stem)}'>"
                     f"<figcaption><b>{html.escape(png.stem)}</b>: {html.escape(cap)}</figcaption></figure>")
    # config & manifest
    parts.append("<h2>Configuration (resolved)</h2>")
    parts.append(f"<pre>{html.escape(cfg_text or '(config.toml missing)')}</pre>")
    parts.append("<h2>Manifest</h2>")
    parts.append(f"<pre>{html.escape(json.dumps(manifest, indent=2, sort_keys=True))}</pre>")
    parts.append("</body></html>\n")
    out = run / "report.html" if out is None else Path(out)
    atomic_write_text(out, "\n".join(parts))
    log.info("report written to %s", out)
    return out
