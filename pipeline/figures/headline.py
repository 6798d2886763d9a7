"""The headline numbers of one or several runs as a table, and drawn with their intervals.

:func:`headline_table` reads a run directory's ``metrics.json`` (sections ``intervals``
and ``comparisons``, :mod:`pipeline.evaluation.headline`; a replicated study's top-level
file has the same sections, pooled over its replicates) into one row per (metric, model):
estimate, 95 % interval, and the verdict of the paired comparison with the chapter's ANFIS
on the same units. :func:`draw_headline` draws such tables as small multiples, one panel
per metric on its own axis and unit, each model a dot with its interval, several runs
side by side: the figure ``baselines`` of a run, and ``rfidstudy compare``.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pandas as pd
from matplotlib.figure import Figure

from pipeline import runfiles
from pipeline.engine.runstore import read_run_json
from pipeline.figures.common import model_metrics, new_figure, require, save_figure
from pipeline.sensormodels.registry import MODELS, model_label, table_order
from scenes.fileio import atomic_output

__all__ = ["HEADLINE_METRICS", "MODEL_LABELS", "HeadlineMetric", "compare_runs", "draw_headline",
           "fig_baselines", "headline_table", "model_label"]

#: Display names of the models, in the order tables list them (from
#: :data:`pipeline.sensormodels.registry.MODELS`, the one table of them).
MODEL_LABELS = {k: m.label for k, m in MODELS.items()}

@dataclass(frozen=True)
class HeadlineMetric:
    """One headline number: where it is in ``metrics.json`` and how to show it."""

    key: str
    """Key in ``metrics.json`` ``intervals`` (e.g. ``heldout.rssi_mae_db``)."""
    label: str
    """Axis and column label, with unit."""
    lower_is_better: bool = True
    """Direction of better."""
    digits: int = 2
    """Decimals shown."""


#: The headline metrics, in the order the figures and tables show them.
HEADLINE_METRICS = (
    HeadlineMetric("heldout.rssi_mae_db", "held-out RSSI MAE [dB]"),
    HeadlineMetric("heldout.rssi_rmse_db", "held-out RSSI RMSE [dB]"),
    HeadlineMetric("heldout.detection_brier", "held-out detection Brier [-]", digits=3),
    HeadlineMetric("fig7.median_pct", "Fig. 7 median error, in-domain [%]", digits=1),
    HeadlineMetric("tag_localisation.median_m", "tag localisation median [m]"),
    HeadlineMetric("robot_localisation.median_m", "robot median error [m]"),
)

_COLUMNS = ["metric", "label", "model", "estimate", "low", "high", "unit", "n_units",
            "verdict", "lower_is_better"]


def _read_metrics(run_dir) -> dict:
    path = require(run_dir, runfiles.METRICS)
    m = read_run_json(path)
    if not isinstance(m, dict):
        raise ValueError(f"{path}: not a metrics object")
    return m


def _num(v) -> float:
    return float(v) if isinstance(v, (int, float)) and not isinstance(v, bool) else np.nan


def headline_table(run_dir, metrics=HEADLINE_METRICS) -> pd.DataFrame:
    """One row per (metric, model) of a run's headline numbers.

    Parameters
    ----------
    run_dir : path
        A run directory (or a replicated study's top directory).
    metrics : sequence of HeadlineMetric

    Returns
    -------
    pandas.DataFrame
        Columns ``metric`` (key), ``label``, ``model``, ``estimate``, ``low``, ``high`` (the
        95 % interval; NaN where none was computed), ``unit`` (what was resampled: tag,
        filter run, replicate x tag), ``n_units``, ``verdict`` (``better`` / ``worse`` than
        ANFIS where the paired interval of the difference excludes 0, ``not
        distinguishable at 95 %``, or empty for ANFIS itself), ``lower_is_better``. A run
        without an ``intervals`` section gives its held-out point estimates with NaN
        intervals.
    """
    m = _read_metrics(run_dir)
    intervals = m.get("intervals") if isinstance(m.get("intervals"), dict) else {}
    comparisons = m.get("comparisons") if isinstance(m.get("comparisons"), dict) else {}
    comparisons = comparisons.get("metrics") if isinstance(comparisons.get("metrics"), dict) else {}
    rows = []
    for spec in metrics:
        iv = intervals.get(spec.key)
        if not isinstance(iv, dict) or not isinstance(iv.get("models"), dict):
            iv = {"models": _point_estimates(run_dir, spec.key)}
        by_model = comparisons.get(spec.key) if isinstance(comparisons.get(spec.key), dict) else {}
        for model, e in iv["models"].items():
            if not isinstance(e, dict):
                continue
            c = by_model.get(model) if isinstance(by_model.get(model), dict) else {}
            rows.append({"metric": spec.key, "label": spec.label, "model": model,
                         "estimate": _num(e.get("estimate")), "low": _num(e.get("low")),
                         "high": _num(e.get("high")), "unit": str(e.get("unit") or ""),
                         "n_units": e.get("n_units"), "verdict": str(c.get("verdict") or ""),
                         "lower_is_better": spec.lower_is_better})
    return pd.DataFrame(rows, columns=_COLUMNS)


def _point_estimates(run_dir, key: str) -> dict:
    """``{model: {"estimate": v}}`` for a metric key from the held-out sections of a run
    directory without ``intervals`` (:func:`~pipeline.figures.common.model_metrics`)."""
    where = {"heldout.rssi_mae_db": ("rssi_dbm", "mae"),
             "heldout.rssi_rmse_db": ("rssi_dbm", "rmse"),
             "heldout.detection_brier": ("detection", "brier"),
             "fig7.median_pct": ("fig7", "median_pct")}
    if key not in where:
        return {}
    sec, k = where[key]
    out = {}
    for model, v in model_metrics(run_dir).items():
        val = ((v or {}).get(sec) or {}).get(k) if isinstance(v, dict) else None
        if isinstance(val, (int, float)) and not isinstance(val, bool) and model != "bound":
            out[model] = {"estimate": val}
    return out


def draw_headline(tables: dict[str, pd.DataFrame], metrics=HEADLINE_METRICS,
                  title: str | None = None) -> Figure:
    """Small multiples of headline numbers: one panel per metric, models down the side.

    Parameters
    ----------
    tables : dict of str to DataFrame
        Run name -> :func:`headline_table` of that run; one run draws one dot per model,
        several runs draw theirs side by side in the run's colour.
    metrics : sequence of HeadlineMetric
        Panels, in order; a metric no run has is left out.
    title : str, optional

    Returns
    -------
    matplotlib.figure.Figure
        Each dot the estimate, each bar its 95 % interval; ▲ / ▼ beside a single run's dot:
        better / worse than ANFIS on the same units (paired interval excludes 0).
    """
    present = [s for s in metrics if any((t["metric"] == s.key).any() for t in tables.values())]
    if not present:
        raise ValueError("none of the headline metrics is in the run(s)")
    models = []
    for t in tables.values():
        for name in t["model"]:
            if name not in models:
                models.append(name)
    order = table_order(models)
    ncol = min(3, len(present))
    nrow = -(-len(present) // ncol)
    fig = new_figure(3.3 * ncol + 1.6, 0.22 * len(order) * nrow + 0.9 * nrow + 0.6)
    axes = np.atleast_1d(fig.subplots(nrow, ncol, sharey=True, squeeze=False)).ravel()
    y = {name: i for i, name in enumerate(order)}
    runs = list(tables)
    offs = (np.arange(len(runs)) - (len(runs) - 1) / 2) * (0.7 / max(len(runs), 1))
    for ax, spec in zip(axes, present, strict=False):
        for r, (run, t) in enumerate(tables.items()):
            sub = t[t["metric"] == spec.key]
            ys = np.array([y[n] for n in sub["model"]], float) + offs[r]
            est = sub["estimate"].to_numpy(float)
            lo, hi = sub["low"].to_numpy(float), sub["high"].to_numpy(float)
            err = np.vstack([np.where(np.isfinite(lo), est - lo, 0.0),
                             np.where(np.isfinite(hi), hi - est, 0.0)])
            colour = f"C{r % 10}"
            ax.errorbar(est, ys, xerr=err, fmt="o", ms=3.5, color=colour, elinewidth=1.0,
                        capsize=1.5, label=run if len(runs) > 1 else None)
            if len(runs) == 1:
                for yy, xx, v in zip(ys, np.where(np.isfinite(hi), hi, est), sub["verdict"],
                                     strict=True):
                    mark = {"better": "▲", "worse": "▼"}.get(v)
                    if mark:
                        ax.annotate(mark, (xx, yy), xytext=(3, 0), textcoords="offset points",
                                    va="center", fontsize=7,
                                    color="tab:green" if v == "better" else "tab:red")
        ax.set_title(spec.label + (" (lower is better)" if spec.lower_is_better
                                   else " (higher is better)"), fontsize=8.5)
        ax.grid(axis="x", visible=True)
    for ax in axes[len(present):]:
        ax.set_visible(False)
    for ax in axes[::ncol]:
        ax.set_yticks(range(len(order)), [model_label(n) for n in order])
    axes[0].invert_yaxis()  # shared y: the chapter's model on top
    if len(runs) > 1:
        fig.legend(*axes[0].get_legend_handles_labels(), loc="outside lower center",
                   ncols=min(len(runs), 4))
    if title:
        fig.suptitle(title)
    return fig


def fig_baselines(run_dir, out_dir=None) -> list[Path]:
    """Every model's held-out headline numbers with their 95 % intervals, one panel per metric
    (▲ / ▼: better / worse than ANFIS on the same tags or filter runs); reads metrics.json."""
    run_dir = Path(run_dir)
    fig = draw_headline({"run": headline_table(run_dir)},
                        title="Held-out scores against the ray-traced truth, 95 % intervals")
    return save_figure(fig, out_dir or run_dir / "figures", "baselines")


def _run_names(run_dirs) -> list[str]:
    """Short distinct names of run directories: their last path part, more where needed."""
    paths = [Path(p).resolve() for p in run_dirs]
    for depth in range(1, 6):
        names = ["/".join(p.parts[-depth:]) for p in paths]
        if len(set(names)) == len(names):
            return names
    return [str(p) for p in paths]


def compare_runs(run_dirs, out_dir) -> list[Path]:
    """The headline numbers of several runs side by side: ``compare.csv`` and a figure.

    Parameters
    ----------
    run_dirs : sequence of path
        Run directories (single or replicated studies), at least one, each read only.
    out_dir : path
        Where ``compare.csv`` (:func:`headline_table` rows with a ``run`` column) and
        ``compare.<format>`` (:func:`draw_headline`, in the formats of the current
        :class:`~pipeline.figures.common.FigureOutput`) are written.

    Returns
    -------
    list of pathlib.Path
        The files written.
    """
    if not run_dirs:
        raise ValueError("compare needs at least one run directory")
    names = _run_names(run_dirs)
    tables = {name: headline_table(d) for name, d in zip(names, run_dirs, strict=True)}
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    long = pd.concat([t.assign(run=name) for name, t in tables.items()], ignore_index=True)
    csv = out_dir / "compare.csv"
    with atomic_output(csv) as tmp:
        long[["run"] + _COLUMNS].to_csv(tmp, index=False)
    fig = draw_headline(tables, title="Headline numbers side by side, 95 % intervals")
    return [csv, *save_figure(fig, out_dir, "compare")]
