"""Downstream localisation figures: tag-error CDF per model, robot error over time.

Reads ``downstream/tag_errors.parquet`` (model, tag_id, error_m) and
``downstream/robot_steps.parquet`` (model, unit (filter run), t_s, error_m, after_kidnap;
``robot_error.parquet``, one run per model, where it is absent), written by the downstream
stage.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd

from pipeline import runfiles
from pipeline.figures.common import find_first, new_figure, require, save_figure
from pipeline.figures.headline import model_label

__all__ = ["fig_downstream"]


def fig_downstream(run_dir, out_dir=None) -> list[Path]:
    """Left: CDF of the held-out tags' position errors per model; right: the RFID-only
    robot filter's position error over the evaluation tour, one small panel per model
    (median over its filter runs, band from the best to the worst run; kidnapped halfway)."""
    run_dir = Path(run_dir)
    tags = pd.read_parquet(require(run_dir, runfiles.TAG_ERRORS))
    steps_path = find_first(run_dir, runfiles.ROBOT_STEPS)
    robot = pd.read_parquet(steps_path if steps_path is not None
                            else require(run_dir, runfiles.ROBOT_ERROR))
    fig = new_figure(11.0, 5.2)
    left, right = fig.subfigures(1, 2, width_ratios=[1.0, 1.35])
    ax1 = left.subplots()
    for i, (name, sub) in enumerate(tags.groupby("model", sort=True)):
        e = np.sort(sub["error_m"].to_numpy(float))
        ax1.step(e, np.arange(1, len(e) + 1) / len(e), where="post", color=f"C{i % 10}",
                 ls="-" if i < 10 else "--",  # more models than colours (phase, oracle)
                 label=f"{name} ({np.median(e):.2f} m)")  # keys: the labels are too wide
    ax1.set_xscale("symlog", linthresh=0.1)
    ax1.set_xlabel("tag position error [m]")
    ax1.set_ylabel("share of held-out tags")
    ax1.axvline(0.5, color="0.6", lw=0.8, ls=":")
    # below the axes: inside, the ten curves leave no corner free
    left.legend(*ax1.get_legend_handles_labels(), fontsize=6.5, loc="outside lower center",
                ncols=2, title="model (median)", title_fontsize=7)
    ax1.set_title("Tag localisation (held-out tags)")
    models = sorted(robot["model"].unique())
    ncol = 3
    nrow = max(1, -(-len(models) // ncol))
    axes = np.atleast_1d(right.subplots(nrow, ncol, sharex=True, sharey=True,
                                        squeeze=False)).ravel()
    has_runs = "unit" in robot.columns
    t_kidnap = None
    if "after_kidnap" in robot.columns and robot["after_kidnap"].any():
        t_kidnap = float(robot.loc[robot["after_kidnap"].astype(bool), "t_s"].min())
    for ax, name in zip(axes, models, strict=False):
        sub = robot[robot["model"] == name]
        if has_runs:
            per_t = sub.groupby("t_s")["error_m"]
            t = np.asarray(per_t.median().index, float)
            ax.fill_between(t, per_t.min().to_numpy(float), per_t.max().to_numpy(float),
                            color="C0", alpha=0.25, lw=0)
            ax.plot(t, per_t.median().to_numpy(float), color="C0", lw=0.9)
        else:
            ax.plot(sub["t_s"], sub["error_m"], color="C0", lw=0.9)
        if t_kidnap is not None:
            ax.axvline(t_kidnap, color="tab:red", lw=0.7, ls="--")
        ax.axhline(0.5, color="0.5", lw=0.6, ls=":")
        ax.set_yscale("log")
        ax.set_title(model_label(name), fontsize=7.5)
    for ax in axes[len(models):]:
        ax.set_visible(False)
    right.supxlabel("time on the evaluation tour [s]", fontsize=8)
    right.supylabel("robot position error [m]", fontsize=8)
    right.suptitle("RFID-only robot localisation: median of the filter runs, band best to "
                   "worst run; red: kidnapped", fontsize=9)
    return save_figure(fig, out_dir or run_dir / "figures", "downstream")
