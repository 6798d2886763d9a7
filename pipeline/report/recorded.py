"""The report of a recorded study (``metrics.json`` ``source = "recording"``).

Sections: what the import read and left out (:mod:`pipeline.recording.load`), every
model on the held-out tags' recorded reads with 95 % intervals and the paired verdict
against the chapter's ANFIS, the held-out tags localised with every model (the
downstream stage, where it ran), and the simulation against the recording
(:mod:`pipeline.evaluation.simreal`) with its two figures, drawn here from
``sim_vs_real/links.parquet`` and ``scene/tags.parquet``: predicted against measured
mean RSSI per (tag, antenna) link, and a top view of each tag's mean residual.
"""

from __future__ import annotations

import base64
import html
import io
from pathlib import Path

import numpy as np

from pipeline import runfiles
from pipeline.engine.runstore import atomic_write_text, inside
from pipeline.report.tables import REPORT_CSS
from pipeline.runpaths import not_regular
from pipeline.sensormodels.registry import model_label

__all__ = ["draw_sim_vs_real", "write_recorded_report"]


def _fmt(iv: dict | None, digits: int = 2) -> str:
    if not iv or iv.get("estimate") is None or iv["estimate"] != iv["estimate"]:
        return "–"
    txt = f"{iv['estimate']:.{digits}f}"
    if iv.get("low") is not None and iv.get("high") is not None:
        txt += f" <span class='ci'>[{iv['low']:.{digits}f}, {iv['high']:.{digits}f}]</span>"
    return txt


def _verdict(c: dict | None) -> str:
    if not c:
        return ""
    v = c.get("verdict", "")
    return {"better": " <span class='up'>▲ better</span>",
            "worse": " <span class='down'>▼ worse</span>"}.get(v, " <span class='ci'>≈</span>")


def _png(fig) -> str:
    import matplotlib.pyplot as plt

    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=110, bbox_inches="tight")
    plt.close(fig)
    return base64.b64encode(buf.getvalue()).decode()


def draw_sim_vs_real(links, tags):
    """The two figures (matplotlib) of the simulation against the recording.

    Parameters
    ----------
    links : pandas.DataFrame
        ``sim_vs_real/links.parquet``.
    tags : pandas.DataFrame
        ``scene/tags.parquet`` (tag_id, x_m, y_m).

    Returns
    -------
    list of matplotlib.figure.Figure
        The RSSI scatter and the residual top view.
    """
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    ok = np.isfinite(links["measured_rssi_dbm"]) & np.isfinite(links["predicted_rssi_dbm"])
    f1, ax = plt.subplots(figsize=(5, 4.5))
    for split, colour in (("train", "#9e9e9e"), ("eval", "#1565c0")):
        s = links[ok & (links["split"] == split)]
        ax.scatter(s["measured_rssi_dbm"], s["predicted_rssi_dbm"], s=12, c=colour,
                   label="held-out tags" if split == "eval" else "training tags")
    if ok.any():
        lo = float(min(links.loc[ok, "measured_rssi_dbm"].min(), links.loc[ok, "predicted_rssi_dbm"].min()))
        hi = float(max(links.loc[ok, "measured_rssi_dbm"].max(), links.loc[ok, "predicted_rssi_dbm"].max()))
        ax.plot([lo, hi], [lo, hi], "k--", lw=0.8)
    ax.set_xlabel("measured mean RSSI [dBm]")
    ax.set_ylabel("ray-traced RSSI [dBm]")
    ax.legend(fontsize=8)
    res = links[ok].assign(res=links["predicted_rssi_dbm"] - links["measured_rssi_dbm"])
    per_tag = res.groupby("tag_id", observed=True)["res"].mean()
    pos = tags.set_index(tags["tag_id"].astype(str))
    f2, ax2 = plt.subplots(figsize=(6, 4))
    have = [t for t in per_tag.index.astype(str) if t in pos.index]
    if have:
        v = per_tag.loc[have].to_numpy(np.float64)
        lim = max(float(np.nanmax(np.abs(v))), 1.0)
        sc = ax2.scatter(pos.loc[have, "x_m"], pos.loc[have, "y_m"], c=v, cmap="RdBu_r",
                         vmin=-lim, vmax=lim, s=30, edgecolors="k", linewidths=0.3)
        f2.colorbar(sc, ax=ax2, label="mean residual, traced - measured [dB]")
    ax2.set_xlabel("x [m]")
    ax2.set_ylabel("y [m]")
    ax2.set_aspect("equal", adjustable="datalim")
    return [f1, f2]


#: The tag localisation table's columns: (interval key, heading, digits).
_TAG_COLUMNS = (("tag_localisation.median_m", "median [m]", 2),
                ("tag_localisation.p90_m", "p90 [m]", 2),
                ("tag_localisation.within_0_5m", "share within 0.5 m", 2))


def _tag_localisation_html(metrics: dict) -> list[str]:
    """The held-out tags localised with each model (the downstream stage on a recording):
    the MAP error against the recording's tag layout with 95 % intervals over tags, the
    verdict against ANFIS on the median; sources that did not run, and why."""
    esc = html.escape
    tl = metrics.get("tag_localisation")
    if not isinstance(tl, dict) or not tl:
        return []
    ivs, comps = metrics.get("intervals", {}), metrics.get("comparisons", {}).get("metrics", {})
    out = ["<h2>Held-out tags localised</h2><p class='muted'>Each held-out tag's most likely "
           "site among the candidates on the building's surfaces, from the recording's reads "
           "of it on the recorded poses; 3-D error against the recording's tag layout, 95 % "
           "intervals over held-out tags; ▲/▼ on the median: better/worse than ANFIS.</p>"
           "<div class='tw'><table><tr><th>model</th>"
           + "".join(f"<th>{h}</th>" for _, h, _ in _TAG_COLUMNS) + "<th>tags</th></tr>"]
    skipped = []
    for model, s in tl.items():
        if not isinstance(s, dict) or "not_run" in s:
            skipped.append((model, s.get("not_run") if isinstance(s, dict) else s))
            continue
        cells = []
        for key, _, digits in _TAG_COLUMNS:
            iv = ivs.get(key, {}).get("models", {}).get(model)
            if iv is None:  # no interval table: the stage's own estimate
                iv = {"estimate": s.get(key.split(".", 1)[1])}
            cells.append(_fmt(iv, digits) + (_verdict(comps.get(key, {}).get(model))
                                             if key.endswith("median_m") else ""))
        out.append(f"<tr><td>{esc(model_label(model))}</td>" + "".join(f"<td>{c}</td>" for c in cells)
                   + f"<td>{esc(str(s.get('n_tags', '–')))}</td></tr>")
    out.append("</table></div>")
    robot = metrics.get("robot_localisation")
    notes = [f"{esc(model_label(m))}: {esc(str(why))}" for m, why in skipped]
    if isinstance(robot, str):
        notes.append(f"RFID-only robot localisation not run: {esc(robot.removeprefix('not run: '))}"
                     if robot.startswith("not run: ") else f"robot localisation: {esc(robot)}")
    if notes:
        out.append("<p class='muted'>" + "<br>".join(notes) + "</p>")
    return out


def write_recorded_report(run_dir, metrics: dict, out) -> Path:
    """Write the recorded study's self-contained ``report.html`` (module doc)."""
    import pandas as pd


    run = Path(run_dir)
    rec = metrics.get("recording", {})
    esc = html.escape
    parts = ["<!DOCTYPE html><html lang='en'><head><meta charset='utf-8'>",
             "<title>rfidstudy: recorded study</title>", f"<style>{REPORT_CSS}</style></head><body>",
             "<h1>RFID sensor-model study on a recording</h1>",
             "<p>The chapter's experiment (Cicirelli, Milella &amp; Di Paola 2011) on a real "
             "reader's log: FCM + ANFIS and the competitors fitted on the training tags' reads, "
             "scored on the held-out tags' reads; the building traced at the recorded poses "
             "and compared with the log.</p>", "<h2>The recording</h2><table>"]
    for key, label in (("format", "format"), ("n_reads_in_file", "reads in the file"),
                       ("n_reads", "reads kept"), ("n_reads_unknown_epc", "reads of EPCs not in the layout"),
                       ("n_unknown_epcs", "unknown EPCs"), ("n_reads_outside_poses", "reads outside the poses' span"),
                       ("n_attempts", "attempts (cycle x antenna x tag)"),
                       ("n_off_schedule", "reads off the attempt schedule")):
        parts.append(f"<tr><td>{label}</td><td>{esc(str(rec.get(key, '–')))}</td></tr>")
    parts.append("</table>")
    lag = rec.get("pose_lag")
    if lag and lag.get("lag_s") is not None:
        note = (f"The reads fit the poses best {lag['lag_s']:+.1f} s shifted (RSSI residual "
                f"{lag['rmse_db_at_zero']:.2f} dB at 0 s, {lag['rmse_db']:.2f} dB there): check the "
                f"reader's and the robot's clocks; <code>recording.time_offset_s = {lag['lag_s']:.1f}"
                "</code> applies it." if abs(lag["lag_s"]) >= 0.3 else
                f"No clock offset between reads and poses found (best {lag['lag_s']:+.1f} s).")
        parts.append(f"<p class='muted'>{note} (pipeline.recording.lag)</p>")
    elif lag:
        parts.append("<p class='muted'>No clock offset between reads and poses could be "
                     f"estimated from {lag.get('n_reads')} training reads (pipeline.recording.lag).</p>")
    if rec.get("unknown_epcs"):
        parts.append("<p class='muted'>Unknown EPCs (reads): " + ", ".join(
            f"{esc(k)} ({v})" for k, v in rec["unknown_epcs"].items()) + "</p>")
    parts.append("<h2>Models on the held-out tags</h2><p class='muted'>Against the measured "
                 "RSSI and read outcomes; 95 % intervals over held-out tags; ▲/▼: better/worse "
                 "than the chapter's ANFIS on the same tags.</p>")
    ivs, comps = metrics.get("intervals", {}), metrics.get("comparisons", {}).get("metrics", {})
    for key, sec in ivs.items():
        if key.startswith("tag_localisation."):  # their own table (_tag_localisation_html)
            continue
        parts.append(f"<h3>{esc(sec.get('label', key))}</h3><div class='tw'><table><tr><th>model"
                     "</th><th>estimate [95 % interval]</th></tr>")
        for model, iv in sec.get("models", {}).items():
            parts.append(f"<tr><td>{esc(model_label(model))}</td><td>{_fmt(iv, 3)}"
                         f"{_verdict(comps.get(key, {}).get(model))}</td></tr>")
        parts.append("</table></div>")
    parts += _tag_localisation_html(metrics)
    svr = metrics.get("sim_vs_real", {}).get("heldout", {})
    parts.append("<h2>Simulation against the recording</h2><p class='muted'>The ray tracer's "
                 "prediction of each held-out attempt, against a log-distance model with a "
                 "per-antenna offset fitted on the training tags; "
                 f"{esc(str(svr.get('n_tags', '–')))} held-out tags, "
                 f"{esc(str(svr.get('n_attempts', '–')))} attempts in range.</p>"
                 "<table><tr><th>quantity</th><th>ray tracer</th><th>log-distance baseline</th>"
                 "<th>tracer - baseline</th></tr>")
    for key, val in svr.items():
        if not isinstance(val, dict):
            continue
        diff = val.get("difference", {})
        parts.append(f"<tr><td>{esc(val.get('label', key))}</td><td>{_fmt(val.get('ray_tracer'), 3)}</td>"
                     f"<td>{_fmt(val.get('baseline'), 3)}</td><td>{_fmt(diff, 3)}"
                     f"{_verdict(diff)}</td></tr>")
    parts.append("</table>")
    cal = metrics.get("calibration")
    if cal:
        parts.append("<h2>Calibration</h2><p class='muted'>The simulated reader fitted to the "
                     f"training tags ({cal.get('n_train_tags')} tags; 95 % intervals from "
                     f"{cal.get('n_boot')} refits on resampled tags). {esc(cal.get('fixed', ''))}. "
                     "The calibrated study: <code>calibrated.toml</code>.</p>"
                     + (f"<p><b>Warning:</b> {esc(cal['warning'])}</p>" if cal.get("warning") else "")
                     + "<table><tr><th>"
                     "parameter</th><th>value [95 % interval]</th><th>unit</th><th>as traced</th>"
                     "<th>note</th></tr>")
        for key, v in cal.get("parameters", {}).items():
            digits = 4 if v.get("unit") == "S/m" else 2
            traced = "" if v.get("traced") is None else f"{v['traced']:.{digits}f}"
            parts.append(f"<tr><td>{esc(key)}</td><td>{_fmt({'estimate': v['value'], **v}, digits)}</td>"
                         f"<td>{esc(v.get('unit', ''))}</td><td>{traced}</td>"
                         f"<td>{esc(v.get('note', ''))}</td></tr>")
        parts.append("</table>")
        cons = cal.get("constructions", {})
        for title, head, vs in (
                ("Out of fold on the training tags (folds of whole tags; what chose the overlay):",
                 "training, out of fold", cons.get("crossvalidated_against_reader_only", {})),
                ("The same held-out tags with the constructions fitted and with the reader's "
                 "parameters alone (a check of that choice):", "held-out",
                 cons.get("heldout_against_reader_only", {}))):
            vs = {k: v for k, v in vs.items() if isinstance(v, dict)}
            if not vs:
                continue
            parts.append(f"<p class='muted'>{esc(title)}</p><table><tr><th>{esc(head)}</th>"
                         "<th>reader only</th><th>with constructions</th><th>difference</th></tr>")
            for key, val in vs.items():
                diff = val.get("difference", {})
                parts.append(f"<tr><td>{esc(val.get('label', key))}</td><td>{_fmt(val['reader_only'], 3)}"
                             f"</td><td>{_fmt(val['with_constructions'], 3)}</td><td>{_fmt(diff, 3)}"
                             f"{_verdict(diff)}</td></tr>")
            parts.append("</table>")
        parts.append("<table><tr><th>held-out</th><th>before</th><th>after</th>"
                     "<th>after - before</th></tr>")
        for key, val in cal.get("heldout", {}).items():
            if isinstance(val, dict) and "after" in val:
                diff = val.get("difference", {})
                parts.append(f"<tr><td>{esc(val.get('label', key))}</td><td>{_fmt(val['before'], 3)}"
                             f"</td><td>{_fmt(val['after'], 3)}</td><td>{_fmt(diff, 3)}"
                             f"{_verdict(diff)}</td></tr>")
        parts.append("</table>")
    links_p, tags_p = inside(run, runfiles.SIM_VS_REAL.format(name="links.parquet")), inside(run, runfiles.SCENE_TAGS)
    for p in (links_p, tags_p):  # a link or a FIFO is refused, never followed
        why = not_regular(p)
        if why:
            raise ValueError(why)
    if links_p.is_file() and tags_p.is_file():
        for fig, cap in zip(draw_sim_vs_real(pd.read_parquet(links_p), pd.read_parquet(tags_p)),
                            ("Ray-traced against measured mean RSSI per (tag, antenna) link.",
                             "Each tag's mean RSSI residual (traced - measured) from above."),
                            strict=True):
            parts.append(f"<figure><img alt='{esc(cap)}' src='data:image/png;base64,{_png(fig)}'>"
                         f"<figcaption>{esc(cap)}</figcaption></figure>")
    parts.append("</body></html>")
    out = Path(out)
    atomic_write_text(out, "\n".join(parts))
    return out
