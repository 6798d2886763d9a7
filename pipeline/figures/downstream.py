"""Downstream localisation figures: tag-error CDF per model, robot error over time.

Reads ``downstream/tag_errors.parquet`` (model, tag_id, error_m) and
``downstream/robot_error.parquet`` (model, t_s, error_m), written by the downstream stage.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd

from .common import new_figure, require, save_figure

__all__ = ["fig_downstream"]


def fig_downstream(run_dir, out_dir=None) -> list[Path]:
    """Left: CDF of the held-out tags' position errors per model; right: the RFID-only
    robot filter's position error over the evaluation tour (kidnapped halfway)."""
    run_dir = Path(run_dir)
    tags = pd.read_parquet(require(run_dir, "downstream/tag_errors.parquet"))
    robot = pd.read_parquet(require(run_dir, "downstream/robot_error.parquet"))
    fig = new_figure(10.0, 3.8)
    ax1, ax2 = fig.subplots(1, 2)
    for i, (name, sub) in enumerate(tags.groupby("model", sort=True)):
        e = np.sort(sub["error_m"].to_numpy(float))
        ax1.step(e, np.arange(1, len(e) + 1) / len(e), where="post", color=f"C{i % 10}",
                 ls="-" if i < 10 else "--",  # more models than colours (phase, oracle)
                 label=f"{name} (median {np.median(e):.2f} m)")
    ax1.set_xscale("symlog", linthresh=0.1)
    ax1.set_xlabel("tag position error [m]")
    ax1.set_ylabel("share of held-out tags")
    ax1.axvline(0.5, color="0.6", lw=0.8, ls=":")
    ax1.legend(fontsize=7, loc="lower right")
    ax1.set_title("Tag localisation (held-out tags)", fontsize=10)
    for i, (name, sub) in enumerate(robot.groupby("model", sort=True)):
        ax2.plot(sub["t_s"], sub["error_m"], color=f"C{i}", lw=0.9, label=name)
    ax2.set_yscale("log")
    ax2.set_xlabel("time on the evaluation tour [s]")
    ax2.set_ylabel("robot position error [m]")
    ax2.legend(fontsize=7)
    ax2.set_title("RFID-only robot localisation (kidnapped halfway)", fontsize=10)
    return save_figure(fig, out_dir or run_dir / "figures", "downstream")
