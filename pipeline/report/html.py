"""A self-contained HTML report made from a run directory's files alone.

Reads ``config.toml``, ``manifest.json``, ``metrics.json`` and ``figures/*.png``
(images embedded as base64, so the HTML file can be mailed on its own) and writes
``report.html`` atomically. The answer comes first: the headline figure, the held-out
table with 95 % intervals and verdicts, findings generated from the numbers
(:mod:`pipeline.report.findings`) and their caveats; then sections in pipeline order, each with
its tables and captioned figures (:mod:`pipeline.figures.captions`); the rankings, every
other number of ``metrics.json`` (laid out from the JSON's nesting, so new metrics show
up without changes here), the config and the manifest are collapsed (``<details>``).
Missing values show as '–', shares as percentages; the tables are
:mod:`pipeline.report.tables`'.
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

from pipeline import runfiles
from pipeline.config import ConfigError, config_from_mapping
from pipeline.engine.runstore import (
    UnsafePathError,
    atomic_write_text,
    read_run_json,
    read_run_text,
    run_files,
)
from pipeline.figures.captions import CAPTIONS, SECTIONS
from pipeline.figures.headline import HEADLINE_METRICS, MODEL_LABELS, headline_table, model_label
from pipeline.report.findings import findings
from pipeline.report.recorded import write_recorded_report
from pipeline.report.smokescale import smoke_scale_reasons
from pipeline.report.tables import (
    REPORT_CSS,
    budget_html,
    downstream_html,
    flatten_scalars,
    fmt_cell,
    heldout_html,
    intervals_html,
    mcl_html,
    metrics_tables,
    model_comparison_tables,
    sites_html,
    table_html,
)
from scenes.materials import extrapolated_materials

__all__ = ["figure_captions", "write_pooled_report", "write_report"]

log = logging.getLogger(__name__)


def _load_json(path: Path) -> dict | None:
    """A JSON object from a run directory (:func:`pipeline.engine.runstore.read_run_json`: a
    regular file, no link followed, size-capped); anything else is a ValueError naming it."""
    if not os.path.lexists(path):
        return None
    data = read_run_json(path)
    if not isinstance(data, dict):
        raise ValueError(f"{path}: expected a JSON object, got {type(data).__name__}")
    return data


#: Keys of a run's config.toml the report computes with, checked as ``load_config``
#: checks them (the rest it only shows, escaped).
_COMPUTED_KEYS = ("frequency_hz",)


def _checked_config(cfg: dict, path: Path) -> dict:
    """``cfg`` (a run's config.toml) with the keys of :data:`_COMPUTED_KEYS` checked as
    :func:`pipeline.config.load_config` checks them (an absent key stays absent).

    The whole file is not validated: a run directory of an older version may hold keys
    since renamed, and the report must still read it.

    Raises
    ------
    ValueError
        One line naming ``path`` and the key: ``frequency_hz = 0`` (``nan``, a string,
        ``1e30``) is refused, not extrapolated to.
    """
    given = {k: cfg[k] for k in _COMPUTED_KEYS if k in cfg}
    try:
        checked = config_from_mapping(given, source=str(path))
    except ConfigError as exc:
        raise ValueError(str(exc)) from None
    return {**cfg, **{k: getattr(checked, k) for k in given}}


def _methods_html(run: Path, cfg: dict) -> list[str]:
    """Methods: materials (P.2040 fits extrapolated to the study frequency), radio geometry
    and the held-out design, from scene/scene.json and config.toml."""
    info = _load_json(run / runfiles.SCENE_SUMMARY) or {}
    f_hz = float(cfg.get("frequency_hz", 865e6))  # checked by _checked_config
    out = ["<h2>Methods</h2>",
           "<p>Walls, floor and ceiling are traced as one radio surface per physical layer "
           "carrying its thickness (a stud partition as two plasterboard leaves); Sionna RT "
           "applies the ITU-R P.2040 slab model once per surface crossed. Boxes and cabinets "
           "are closed shells. The evaluation tour reads a held-out tag layout "
           f"({fmt_cell(info.get('n_tags_eval'))} tags drawn on the scene's surfaces with their "
           f"own seed) that the training tour ({fmt_cell(info.get('n_tags_train'))} tags) never "
           "reads.</p>"]
    try:
        rows = extrapolated_materials(info.get("materials") or [], f_hz)
    except Exception:  # an unknown material in an old run directory: say nothing wrong
        rows = []
    if rows:
        out.append(f"<p>Material properties follow ITU-R P.2040-3 Table 3; these fits are valid "
                   f"from 1 GHz and are extrapolated to {f_hz / 1e9:.4g} GHz (smooth power "
                   "laws, the usual practice for UHF):</p>")
        out.append(table_html("materials extrapolated below their P.2040 range",
                               ["material", "valid from [GHz]", "eps_r", "sigma [S/m]"],
                               [[r["material"], r["range_ghz"][0], r["relative_permittivity"],
                                 r["conductivity_s_per_m"]] for r in rows]))
    return out


def figure_captions(run_dir: Path) -> dict[str, str]:
    """Captions by figure stem: ``figures/captions.json`` if present, else
    :data:`pipeline.figures.captions.CAPTIONS`."""
    p = run_dir / runfiles.FIGURE.format(name="captions.json")
    caps = _load_json(p) if p.exists() else None
    if isinstance(caps, dict):
        return {str(k): str(v) for k, v in caps.items()}
    return dict(CAPTIONS)


def write_pooled_report(metrics: dict, out: str | Path) -> Path:
    """``report.html`` of a replicated study (:mod:`pipeline.apps.replicates`): which
    replicates it covers, the pooled rankings with intervals, each replicate's own
    estimates, and links to the replicates' reports."""
    rep = metrics.get("replicates") or {}
    parts = ["<!DOCTYPE html><html><head><meta charset='utf-8'>",
             "<title>rfidstudy report: replicated study</title>",
             f"<style>{REPORT_CSS}</style></head><body>",
             f"<h1>Replicated study: {html.escape(str(rep.get('covers', '?')))}</h1>",
             "<p>The same study run on independent seed streams (tour noise, MCL, reader "
             "noise, held-out tag layout, robot filter runs); every number below pools the "
             "complete replicates' held-out tags and filter runs.</p>"]
    failed = rep.get("failed") or []
    if failed:
        parts.append(table_html("failed replicates (not pooled)", ["replicate", "seed", "error"],
                                 [[f.get("k"), f.get("seed"), f.get("error")] for f in failed]))
    parts.extend(intervals_html(metrics))
    per = metrics.get("per_replicate") or {}
    reps = per.get("replicates") or []
    parts.append("<h2>Each replicate's own estimates</h2>")
    for key, models in (per.get("metrics") or {}).items():
        label = ((metrics.get("intervals") or {}).get(key) or {}).get("label", key)
        parts.append(table_html(label, ["model", *[f"replicate {k}" for k in reps]],
                                 [[m, *vals] for m, vals in models.items()]))
    parts.append("<h2>Replicates</h2><ul>")
    for k in reps:
        parts.append(f"<li><a href='replicates/{int(k)}/report.html'>replicate {int(k)}</a> "
                     f"(seed {html.escape(str((rep.get('seeds') or {}).get(str(k))))})</li>")
    parts.append("</ul></body></html>\n")
    out = Path(out)
    atomic_write_text(out, "\n".join(parts))
    return out


def _figure_files(run: Path) -> dict[str, Path]:
    """The run's PNG figures by name (regular files only: a link could embed any file of
    the reader's)."""
    try:
        return {p.stem: p for p in run_files(run, "figures", "*.png")}
    except UnsafePathError as exc:
        log.warning("report: %s; no figure embedded", exc)
        return {}


def _figure_html(png: Path, run: Path, embed: bool, captions: dict[str, str]) -> str:
    if embed:
        src = "data:image/png;base64," + base64.b64encode(png.read_bytes()).decode("ascii")
    else:
        src = png.relative_to(run).as_posix()
    cap = captions.get(png.stem, png.stem.replace("_", " "))
    return (f"<figure id='fig-{html.escape(png.stem)}'><img src='{html.escape(src)}' "
            f"alt='{html.escape(png.stem)}'><figcaption>{html.escape(cap)} "
            f"<span class='muted'>(figures/{html.escape(png.stem)}.png)</span></figcaption>"
            "</figure>")


def _summary_html(run: Path, body: dict) -> list[str]:
    """The held-out headline table with intervals and verdicts, the findings, the caveats."""
    out = []
    try:
        table = headline_table(run)
    except (FileNotFoundError, ValueError):
        table = None
    if table is not None and len(table):
        specs = [m for m in HEADLINE_METRICS if (table["metric"] == m.key).any()]
        seen = list(dict.fromkeys(table["model"]))
        order = [n for n in MODEL_LABELS if n in seen] + [n for n in seen if n not in MODEL_LABELS]
        cells = {(r.metric, r.model): r for r in table.itertuples()}
        rows = []
        for name in order:
            row = [model_label(name)]
            for m in specs:
                r = cells.get((m.key, name))
                row.append(_interval_cell(r, m.digits))
            rows.append(row)
        head = "".join(f"<th>{html.escape(m.label)}</th>" for m in specs)
        body_rows = "".join("<tr><td>" + html.escape(r[0]) + "</td>" + "".join(
            f"<td>{c}</td>" for c in r[1:]) + "</tr>" for r in rows)
        out.append("<h3>Held-out scores with 95 % intervals</h3>"
                   "<div class='tw'><table class='headline'><tr><th>model</th>" + head + "</tr>"
                   + body_rows + "</table></div><p class='muted'>Each cell: estimate [95 % "
                   "interval]; ▲ / ▼: better / worse than the chapter's ANFIS on the same units "
                   "(the paired interval of the difference excludes 0); no mark: not "
                   "distinguishable; '–': the model predicts no such quantity.</p>")
    found, caveats = findings(body)
    if found:
        out.append("<h3>Findings</h3><ul>" + "".join(f"<li>{html.escape(f)}</li>" for f in found)
                   + "</ul>")
    if caveats:
        out.append("<h3>Caveats</h3><ul class='muted'>"
                   + "".join(f"<li>{html.escape(c)}</li>" for c in caveats) + "</ul>")
    return out


def _interval_cell(r, digits: int) -> str:
    if r is None or r.estimate != r.estimate:
        return "–"
    txt = f"{r.estimate:.{digits}f}"
    if r.low == r.low and r.high == r.high:
        txt += f" <span class='ci'>[{r.low:.{digits}f}, {r.high:.{digits}f}]</span>"
    mark = {"better": " <span class='up'>▲</span>", "worse": " <span class='down'>▼</span>"}
    return txt + mark.get(r.verdict, "")


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
    metrics = _load_json(run / runfiles.METRICS)
    if (metrics or {}).get("source") == "recording":  # a recorded study's own report
        return write_recorded_report(run, metrics, out or run / runfiles.REPORT)
    cfg_path = run / "config.toml"
    cfg_text = read_run_text(cfg_path) if os.path.lexists(cfg_path) else ""  # no link, no FIFO
    try:
        cfg = tomllib.loads(cfg_text) if cfg_text else {}
    except tomllib.TOMLDecodeError as exc:
        raise ValueError(f"{cfg_path}: not a valid TOML file: {exc}") from None
    cfg = _checked_config(cfg, cfg_path)
    parts = [
        "<!DOCTYPE html><html lang='en'><head><meta charset='utf-8'>",
        "<meta name='viewport' content='width=device-width, initial-scale=1'>",
        f"<title>rfidstudy report: {html.escape(str(cfg.get('scene', run.name)))}</title>",
        f"<style>{REPORT_CSS}</style></head><body>",
        f"<h1>RFID sensor-model study: {html.escape(str(cfg.get('scene', '?')))}</h1>",
        "<p>Ray-traced UHF RFID sensor model (Cicirelli, Milella &amp; Di Paola 2011): "
        "RSSI model f<sub>s</sub>(d, &alpha;) and detection model f<sub>T</sub>(d, &alpha;), "
        "FCM-initialised Takagi-Sugeno systems trained by ANFIS (Jang 1993), "
        "&rho; = f<sub>s</sub> f<sub>T</sub>.</p>",
        f"<p class='muted'>Run directory <code>{html.escape(str(run.resolve()))}</code>; "
        f"report written {_dt.datetime.now(_dt.timezone.utc).isoformat(timespec='seconds')}.</p>",
    ]

    smoke = smoke_scale_reasons(cfg)
    if smoke:
        parts.append("<div class='smoke'><strong>Smoke-scale settings: these numbers measure what "
                     "the study costs, not how good the models are.</strong> "
                     + "; ".join(html.escape(r) for r in smoke)
                     + ". Rerun with the default settings before drawing a conclusion.</div>")
    pngs = _figure_files(run)
    captions = figure_captions(run)
    body = (metrics or {}).get("evaluation", metrics or {})
    held_out = isinstance(body.get("heldout"), dict)
    # 1. the answer: headline figure, held-out table with intervals, findings, caveats
    parts.append("<h2>Summary</h2>")
    if metrics is None:
        parts.append("<p>metrics.json is missing (evaluation did not run).</p>")
    if "baselines" in pngs:
        parts.append(_figure_html(pngs.pop("baselines"), run, embed, captions))
    if metrics is not None:
        parts.extend(_summary_html(run, body))
    # 2. sections in pipeline order, each with its tables and figures
    sections = {title: [n for n in names if n in pngs] for title, names in SECTIONS}
    for title, names in sections.items():
        tables = []
        if held_out and title == "Scene and tour":
            tables = mcl_html(body)
        elif held_out and title == "Model against the ray-traced truth":
            tables = [*heldout_html(body), *budget_html(body), *sites_html(body)]
        elif held_out and title == "Downstream localisation":
            tables = downstream_html(body)
        if not names and not tables:
            continue
        parts.append(f"<h2>{html.escape(title)}</h2>")
        parts.extend(tables)
        parts.extend(_figure_html(pngs.pop(n), run, embed, captions) for n in names)
    if pngs:
        parts.append("<h2>Other figures</h2>")
        parts.extend(_figure_html(png, run, embed, captions) for png in pngs.values())
    if held_out:
        ranks = intervals_html(body)
        if ranks:
            parts.append("<h2>Rankings with 95 % intervals</h2>")
            parts.append("<details><summary>every headline metric: each model's estimate, "
                         "its difference to ANFIS and the verdict</summary>")
            parts.extend(ranks[1:])  # the section title is the summary line's
            parts.append("</details>")
    parts.extend(_methods_html(run, cfg))
    # 3. the run and every remaining number, collapsed
    parts.append("<h2>The run</h2>")
    summary = [
        ["scene", cfg.get("scene")],
        ["seed", manifest.get("seed", cfg.get("seed"))],
        ["frequency [Hz]", cfg.get("frequency_hz")],
        # The report stage runs last, after every other stage succeeded, while the
        # manifest still says "running": only a recorded failure makes it incomplete.
        ["status", "failed" if manifest.get("failure") else "complete"],
        ["elapsed [s]", manifest.get("elapsed_s")],
        ["peak memory [MiB]", manifest.get("peak_rss_mib")],
    ]
    backend = manifest.get("backend") or {}
    if isinstance(backend, dict) and backend:
        summary.append(["Dr.Jit variant", backend.get("variant")])
    parts.append(table_html("run", ["item", "value"], summary))
    stages = manifest.get("stages") or {}
    if stages:
        rows = [[n, s.get("status"), s.get("elapsed_s"), s.get("peak_rss_mib")] for n, s in stages.items()]
        parts.append(table_html("stages", ["stage", "status", "elapsed [s]", "peak memory [MiB]"],
                                 rows))
    if metrics is not None:
        rest = dict(body)
        for key in ("heldout", "fig7", "error_budget", "localisation", "tag_sites",
                    "tag_localisation", "robot_localisation", "intervals", "comparisons"):
            if held_out:
                rest.pop(key, None)
        raw = []
        if isinstance(rest.get("models"), dict):
            raw.append("<p>ANFIS (trained on MCL poses) against the baselines, and against the "
                       "same models trained on true poses (the localisation-error split).</p>")
            for title, cols, rows in model_comparison_tables(rest.pop("models")):
                raw.append(table_html(title, cols, rows))
        split = rest.pop("localisation_split", None)
        if isinstance(split, dict) and isinstance(split.get("difference"), dict):
            # evaluate_all writes the differences flat: {"rssi_dbm.mae": x, ...}
            rows = [[k, v] for k, v in sorted(flatten_scalars(split["difference"]).items())]
            raw.append("<p>Each value is the metric of the model trained on MCL poses minus "
                       "that of the model trained on true poses: the share of the error that "
                       "localisation adds.</p>")
            raw.append(table_html("MCL-pose minus true-pose model", ["metric", "difference"],
                                   rows))
        if isinstance(rest.get("in_sample"), dict):
            raw.append("<p class='muted'>In-sample (training tour, training tags): scored on "
                       "the reads the models were fitted on: optimistic, kept for comparison "
                       "with the held-out numbers.</p>")
        for title, cols, rows in metrics_tables(rest):
            raw.append(table_html(title, cols, rows))
        if raw:
            parts.append("<details><summary>every other number in metrics.json (in-sample "
                         "scores, Fig. 6 view, coverage, model fits)</summary>")
            parts.extend(raw)
            parts.append("</details>")
    parts.append("<details><summary>configuration (resolved)</summary>")
    parts.append(f"<pre>{html.escape(cfg_text or '(config.toml missing)')}</pre></details>")
    parts.append("<details><summary>manifest</summary>")
    parts.append(f"<pre>{html.escape(json.dumps(manifest, indent=2, sort_keys=True))}</pre>"
                 "</details>")
    parts.append("</body></html>\n")
    out = run / runfiles.REPORT if out is None else Path(out)
    atomic_write_text(out, "\n".join(parts))
    log.info("report written to %s", out)
    return out
