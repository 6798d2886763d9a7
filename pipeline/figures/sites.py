"""Per-location error map: the learned rho against the ray-traced truth at tag sites.

Reads ``truth/site_errors.parquet`` (:class:`pipeline.evaluation.sites.SiteComparison`
``per_site``, written by the evaluation stage for the ANFIS model). Each panel unfolds
the surfaces facing one direction (walls, box and cabinet sides) into an elevation view:
position along the surface against height, coloured by the mean signed error of rho
(model - truth) over the evaluation-tour poses that reach the site. Red: the model
expects reads the physics does not give (behind a cabinet, a wall); blue: it misses
reads. Sites mostly hidden from the antenna are ringed.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd

from pipeline import runfiles
from pipeline.figures.common import new_figure, require, save_figure

__all__ = ["fig_site_errors"]

# (label, normal direction, abscissa column)
_FACINGS = (("surfaces facing +y", (0.0, 1.0), "x_m"), ("surfaces facing -y", (0.0, -1.0), "x_m"),
            ("surfaces facing +x", (1.0, 0.0), "y_m"), ("surfaces facing -x", (-1.0, 0.0), "y_m"))


def fig_site_errors(run_dir, out_dir=None) -> list[Path]:
    """Mean signed rho error (ANFIS - truth) per tag site, one elevation panel per facing."""
    run_dir = Path(run_dir)
    t = pd.read_parquet(require(run_dir, runfiles.SITE_ERRORS))
    n = t[["nx", "ny"]].to_numpy(float)
    panels = []
    for label, direction, col in _FACINGS:
        sel = n @ np.asarray(direction) > 0.9
        if sel.sum() >= 3:
            panels.append((label, col, t.loc[sel]))
    panels = panels[:2] if len(panels) > 2 and sum(len(p[2]) for p in panels[2:]) < 10 else panels
    fig = new_figure(9.0, 1.9 * max(len(panels), 1) + 0.6)
    axes = fig.subplots(max(len(panels), 1), 1, squeeze=False)[:, 0]
    lim = float(np.nanpercentile(np.abs(t["rho_error_mean"]), 98)) if len(t) else 1.0
    lim = max(lim, 0.05)
    sc = None
    for ax, (label, col, sub) in zip(axes, panels, strict=False):
        sc = ax.scatter(sub[col], sub["z_m"], c=sub["rho_error_mean"], cmap="RdBu_r", vmin=-lim,
                        vmax=lim, s=18, marker="s")
        hid = sub["obstructed_fraction"] > 0.5
        ax.scatter(sub.loc[hid, col], sub.loc[hid, "z_m"], s=40, facecolors="none",
                   edgecolors="k", linewidths=0.6)
        ax.set_ylabel("height [m]")
        ax.set_title(label, fontsize=9, loc="left")
        ax.set_xlabel(f"{col[0]} [m]")
    if sc is not None:
        fig.colorbar(sc, ax=list(axes), label="rho error, ANFIS - truth [-]", shrink=0.9)
    fig.suptitle("Truth where tags are: mean rho error per tag site (ringed: mostly obstructed)",
                 fontsize=10)
    return save_figure(fig, out_dir or run_dir / "figures", "site_errors")
