"""Comparison figures: chapter Fig. 6 (rho) and Fig. 7 (percentage error).

Inputs (run directory):

- Fig. 6: ``truth/rho_points_*.npz`` (:meth:`pipeline.evaluation.RhoPoints.save`)
  and ``models/sensor.json`` (the learned rho is evaluated at the saved (d, alpha)
  unless the file carries ``anfis__rho``);
- Fig. 7: ``truth/fig7_errors.parquet`` (:meth:`pipeline.evaluation.Fig7Result.write_table`);
  if absent, computed with :func:`pipeline.evaluation.fig7_errors` from
  ``eval_reads.parquet``, ``eval_poses.parquet``, ``scene/tags.parquet`` (or
  ``truth/tags.parquet``), ``models/sensor.json`` and the antenna tilts of
  ``config.toml`` (``[[robot.antennas]] tilt_deg``; 0 without the file).

The models side by side with their intervals: :mod:`pipeline.figures.headline`.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd

from pipeline import runfiles
from pipeline.engine.runstore import read_run_text, run_files
from pipeline.evaluation.comparison import RhoPoints
from pipeline.evaluation.fig7 import fig7_errors, read_fig7_table
from pipeline.evaluation.tables import read_tags
from pipeline.figures.common import (
    load_sensor,
    new_figure,
    require,
    save_figure,
)
from scenes.fileio import read_npz

__all__ = ["fig_fig7_error", "fig_rho_vs_truth"]

_MAX_POSES = 4


def fig_rho_vs_truth(run_dir, out_dir=None) -> list[Path]:
    """Chapter Fig. 6: true and learned rho around sample antenna poses (top view, world x-y).

    One row per pose (at most 4): true rho, learned rho, difference.
    """
    run_dir = Path(run_dir)
    files = run_files(run_dir, "truth", "rho_points_*.npz")
    if not files:
        require(run_dir, runfiles.RHO_POINTS.format(i=0))
    files = files[:_MAX_POSES]
    sensor = None
    fig = new_figure(12.0, 3.2 * len(files))
    # the three panels of a row show the same place: shared axes, tick labels outside only;
    # one colour bar for both rho columns and one for the difference
    axes = np.atleast_2d(fig.subplots(len(files), 3, sharex="row", sharey="row"))
    meshes = {}
    for row, f in zip(axes, files, strict=True):
        rp = RhoPoints.load(f)
        with read_npz(f) as z:
            learned = np.array(z["anfis__rho"], float) if "anfis__rho" in z.files else None
        if learned is None:
            sensor = sensor or load_sensor(run_dir, "anfis")
            learned = np.asarray(sensor.rho(rp.d_m, rp.alpha_rad), dtype=float)
        x, y = rp.points_m[:, 0], rp.points_m[:, 1]
        for j, (ax, val, title, cmap, lim) in enumerate((
            (row[0], rp.rho_true, "true rho", "viridis", (0, 1)),
            (row[1], learned, "learned rho = fs * fT", "viridis", (0, 1)),
            (row[2], learned - rp.rho_true, "learned - true", "RdBu_r", (-1, 1)),
        )):
            if rp.grid_shape is not None:
                m = ax.pcolormesh(x.reshape(rp.grid_shape), y.reshape(rp.grid_shape),
                                  val.reshape(rp.grid_shape), shading="gouraud", cmap=cmap,
                                  vmin=lim[0], vmax=lim[1], rasterized=True)
            else:
                m = ax.scatter(x, y, c=val, s=12, cmap=cmap, vmin=lim[0], vmax=lim[1])
            meshes["rho" if j < 2 else "diff"] = m
            p = rp.antenna_pose
            ax.plot(p[0], p[1], "k^", ms=7)
            ax.annotate("", xy=(p[0] + 0.5 * np.cos(p[3]), p[1] + 0.5 * np.sin(p[3])),
                        xytext=(p[0], p[1]), arrowprops={"arrowstyle": "->"}
                        ).set_in_layout(False)  # inside the panel: nothing to make room for
            ax.set_aspect("equal")
            ax.set_title(f"{f.stem}: {title}", fontsize=9)
            ax.set_xlabel("x [m]")
        row[0].set_ylabel("y [m]")
    fig.colorbar(meshes["rho"], ax=axes[:, :2], label="rho [-]", shrink=0.8)
    fig.colorbar(meshes["diff"], ax=axes[:, 2], label="learned - true rho [-]", shrink=0.8)
    fig.suptitle("Fig. 6 (free-space view at antenna height, not where tags are): rho around "
                 "evaluation-tour antenna poses")
    return save_figure(fig, out_dir or run_dir / "figures", "rho_vs_truth")


def _fig7_table(run_dir: Path) -> pd.DataFrame:
    p = run_dir / runfiles.FIG7_ERRORS
    if p.is_file():
        return read_fig7_table(p)
    reads = pd.read_parquet(require(run_dir, runfiles.EVAL_READS))
    poses = pd.read_parquet(require(run_dir, runfiles.EVAL_POSES))
    tags = read_tags(require(run_dir, runfiles.SCENE_TAGS, runfiles.LEGACY_SCENE_TAGS))
    res = fig7_errors(reads, tags, load_sensor(run_dir, "anfis"),
                      pose_times_s=poses["time_s"].to_numpy(float),
                      antenna_pitch_rad=_tilts(run_dir), d_max_m=_training_d_max(run_dir))
    return res.table


def _training_d_max(run_dir: Path) -> float | None:
    """config.toml ``[training] d_max_m`` [m] (the Fig. 7 training domain); None if absent."""
    v = _run_config(run_dir).get("training", {}).get("d_max_m")
    return None if v is None else float(v)


def _tilts(run_dir: Path) -> dict | float:
    """Antenna index -> tilt [rad] from config.toml ``[[robot.antennas]] tilt_deg``; else 0."""
    ants = _run_config(run_dir).get("robot", {}).get("antennas", [])
    return {i: float(np.radians(a.get("tilt_deg", 0.0))) for i, a in enumerate(ants)} or 0.0


def _run_config(run_dir: Path) -> dict:
    """The run's config.toml as a table ({} where there is none); ValueError naming it
    when it is a link, a FIFO or another special file (never followed, never waited on:
    :func:`pipeline.engine.runstore.read_run_text`) or not TOML."""
    import os
    import tomllib


    p = Path(run_dir) / "config.toml"
    if not os.path.lexists(p):
        return {}
    try:
        return tomllib.loads(read_run_text(p))
    except tomllib.TOMLDecodeError as exc:
        raise ValueError(f"{p}: not valid TOML ({exc})") from None


def fig_fig7_error(run_dir, out_dir=None) -> list[Path]:
    """Chapter Fig. 7: Error = |f̄s - s| x 100 (chapter Sec. 5) along the evaluation path.

    s: measured RSSI normalised to [0, 1]; f̄s: the model's fs averaged within 10 cm
    of the tag. Points: per (pose, antenna, tag) within the training domain
    (``in_domain``); grey crosses: beyond it (d > training.d_max_m, extrapolation);
    lines: the in-domain mean per pose and antenna; dashed: the chapter's 20 % mark.
    """
    run_dir = Path(run_dir)
    t = _fig7_table(run_dir)
    inside = t["in_domain"].astype(bool).to_numpy()
    t_in, t_out = t.loc[inside], t.loc[~inside]
    fig = new_figure(8.0, 4.0)
    ax = fig.subplots()
    if len(t_out):
        ax.plot(t_out["pose"], t_out["error_pct"], "x", color="0.6", alpha=0.5, ms=3,
                label="beyond training domain")
    for i, (ant, sub) in enumerate(t_in.groupby("antenna", sort=True)):
        c = f"C{i}"
        ax.plot(sub["pose"], sub["error_pct"], ".", color=c, alpha=0.35, ms=4)
        mean = sub.groupby("pose")["error_pct"].mean()
        ax.plot(mean.index, mean.to_numpy(), "-", color=c, lw=1.2, label=f"antenna {ant}")
    ax.axhline(20.0, color="k", ls="--", lw=0.8, label="20 % (chapter)")
    ax.set_xlabel("evaluation pose [index]")
    ax.set_ylabel("|f̄s - s| x 100 [%]")
    if len(t):
        ax.set_ylim(0, max(25.0, float(np.nanpercentile(t["error_pct"], 98)) * 1.1))
    ax.legend(loc="upper right", fontsize=8)
    med = float(np.nanmedian(t_in["error_pct"])) if len(t_in) else float("nan")
    ax.set_title(f"Fig. 7: RSSI model error along the evaluation path (in-domain median "
                 f"{med:.1f} %)")
    return save_figure(fig, out_dir or run_dir / "figures", "fig7_error")
