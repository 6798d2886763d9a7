"""Scene and robot figures: top view with trajectories, MCL error, ray-traced RSSI fields.

Inputs (run directory):

- top view: ``scene/floorplan.npz`` (or ``fields/floorplan.npz``): wall segments
  under keys ``segments*`` (k, 2, 2) [m] (the highest cut is drawn), optional
  ``route_m`` (n, 2); ``scene/tags.parquet`` (or ``truth/tags.parquet``);
  ``poses.parquet`` (true and MCL poses); optional ``eval_poses.parquet``;
- MCL error: ``poses.parquet`` (and ``eval_poses.parquet`` if present);
- fields: ``fields/field_*.npz`` (``propagation.RssiField.save``: the plane
  gain ``plane_gain`` with ``plane_centers_m`` and ``antenna_pose``; wall
  triangles are not drawn).

:func:`scene_top_view` draws a Scene object directly (``rfidstudy scenes show``).
"""

from __future__ import annotations

import logging
from pathlib import Path

import numpy as np
import pandas as pd
from matplotlib.collections import LineCollection

from pipeline import runfiles
from pipeline.engine.runstore import run_files
from pipeline.evaluation.localisation import localisation_errors
from pipeline.evaluation.tables import read_tags
from pipeline.figures.common import find_first, new_figure, require, save_figure
from scenes.fileio import read_npz
from scenes.geometry import floor_plan_segments
from scenes.sources import traits_of

__all__ = ["fig_fields", "fig_mcl_error", "fig_scene_top_view", "scene_top_view"]

log = logging.getLogger(__name__)
_MAX_FIELDS = 4


def _segments(z) -> np.ndarray | None:
    keys = sorted(k for k in z.files if k.startswith("segments"))
    if not keys:
        return None
    return np.asarray(z[keys[-1]], dtype=float).reshape(-1, 2, 2)


def _plan_height_in(segments, width_in: float) -> float:
    """Figure height [in] fitting a top view of ``segments`` (k, 2, 2) at ``width_in``:
    the plan's aspect plus room for the title, axis labels and a legend row."""
    if segments is None or not len(segments):
        return 4.5
    pts = np.asarray(segments, float).reshape(-1, 2)
    dx, dy = np.ptp(pts[:, 0]) or 1.0, np.ptp(pts[:, 1]) or 1.0
    return float(np.clip((width_in - 0.8) * dy / dx + 1.6, 2.4, 9.0))


def _draw_plan(ax, segments, tags_xy, tag_ids=None, route=None, held_out=None):
    if segments is not None and len(segments):
        ax.add_collection(LineCollection(segments, colors="0.2", linewidths=1.0, label="walls"))
    if route is not None and len(route):
        ax.plot(route[:, 0], route[:, 1], ":", color="0.5", lw=0.8, label="route")
    if tags_xy is not None and len(tags_xy):
        held = np.zeros(len(tags_xy), bool) if held_out is None else np.asarray(held_out, bool)
        ax.plot(tags_xy[~held, 0], tags_xy[~held, 1], "s", color="C3", ms=4,
                label="training tags" if held.any() else "tags")
        if held.any():
            ax.plot(tags_xy[held, 0], tags_xy[held, 1], "D", color="C4", ms=4,
                    label="held-out tags")
        if tag_ids is not None and len(tag_ids) <= 40:
            for (x, y), t in zip(tags_xy, tag_ids, strict=True):
                ax.annotate(str(t), (x, y), fontsize=5, xytext=(2, 2), textcoords="offset points")
    ax.set_aspect("equal")
    ax.autoscale_view()
    ax.set_xlabel("x [m]")
    ax.set_ylabel("y [m]")


def fig_scene_top_view(run_dir, out_dir=None) -> list[Path]:
    """Top view: walls, tags, route, true and MCL trajectories (training tour and evaluation path)."""
    run_dir = Path(run_dir)
    plan = require(run_dir, runfiles.FLOORPLAN, runfiles.LEGACY_FLOORPLAN)
    with read_npz(plan) as z:
        segs = _segments(z)
        route = np.asarray(z["route_m"], float) if "route_m" in z.files else None
    tags = read_tags(require(run_dir, runfiles.SCENE_TAGS, runfiles.LEGACY_SCENE_TAGS))
    poses = pd.read_parquet(require(run_dir, runfiles.TRAIN_POSES))
    fig = new_figure(10.0, _plan_height_in(segs, 10.0))
    ax = fig.subplots()
    held = (tags["split"] == "eval").to_numpy() if "split" in tags.columns else None
    _draw_plan(ax, segs, tags[["x_m", "y_m"]].to_numpy(float), tags["tag_id"].tolist(), route,
               held_out=held)
    ax.plot(poses["true_x_m"], poses["true_y_m"], "-", color="C0", lw=0.8, label="true (tour)")
    ax.plot(poses["est_x_m"], poses["est_y_m"], "-", color="C1", lw=0.6, alpha=0.8,
            label="MCL (tour)")
    ev = find_first(run_dir, runfiles.EVAL_POSES)
    if ev is not None:
        e = pd.read_parquet(ev)
        ax.plot(e["true_x_m"], e["true_y_m"], ".", color="C2", ms=2, label="evaluation path")
    fig.legend(fontsize=7, loc="outside lower center", ncol=7, frameon=False)
    ax.set_title("Scene top view: walls, tags and robot trajectories")
    return save_figure(fig, out_dir or run_dir / "figures", "scene_top_view")


def _draw_map_recognition(ax, scene, rm) -> None:
    """Under a map scene's plan: its map ``rm`` as given (grey levels), the racks and pillars
    the extraction recognised (filled), and the tags the planned route skips (red crosses)."""
    m = scene.metadata["map"]
    shade = np.array([0.6, 0.93, 0.1])  # unknown, free, occupied (cell classes -1, 0, 1)
    img = shade[np.clip(np.asarray(rm.cell_class, int), -1, 1) + 1]
    (x0, y0), (x1, y1) = rm.extent_m
    ax.imshow(img, origin="lower", extent=(x0, x1, y0, y1), cmap="gray", vmin=0, vmax=1,
              interpolation="nearest", alpha=0.45, zorder=0)
    for kind, colour in (("rack", "tab:blue"), ("pillar", "tab:purple")):
        rects = [np.asarray(o["rectangle_m"]) for o in m["obstacles"]
                 if o["kind"] == kind and "rectangle_m" in o]
        for i, r in enumerate(rects):
            ax.fill(r[:, 0], r[:, 1], color=colour, alpha=0.35, lw=0, zorder=1,
                    label=f"{len(rects)} {kind}s recognised" if i == 0 else None)
    skipped = [xy for sk in scene.metadata.get("route", {}).get("skipped", []) for xy in sk.get("xy_m", [])]
    if skipped:
        xy = np.asarray(skipped, float)
        ax.plot(xy[:, 0], xy[:, 1], "x", color="tab:red", ms=5, zorder=4,
                label=f"{len(xy)} tags the route skips")


def scene_top_view(scene, png, z_m: float = 1.0) -> Path:
    """Top view of a ``scenes.Scene`` (walls cut at `z_m`, tags, route) written to `png`.

    Used by ``rfidstudy scenes show``; writes the PNG (and a PDF beside it). A map scene
    shows the map as given under it, the racks and pillars recognised and the tags the
    planned route skips.
    """
    png = Path(png)
    segs = floor_plan_segments(scene, z_m)
    fig = new_figure(10.0, _plan_height_in(segs, 10.0))
    ax = fig.subplots()
    grid = traits_of(scene).grid(scene)
    if grid is not None and scene.metadata.get("map"):
        _draw_map_recognition(ax, scene, grid)
    _draw_plan(ax, segs, np.asarray(scene.tags.positions_m)[:, :2], list(scene.tags.ids),
               None if scene.route_m is None else np.asarray(scene.route_m)[:, :2])
    fig.legend(fontsize=7, loc="outside lower center", ncol=4, frameon=False)
    ax.set_title(f"{scene.name}: walls at z = {z_m:.2f} m, {len(scene.tags)} tags")
    return save_figure(fig, png.parent, png.stem)[0]


def fig_mcl_error(run_dir, out_dir=None) -> list[Path]:
    """MCL position and heading error over time (tour, and evaluation path if present)."""
    run_dir = Path(run_dir)
    tables = {"tour": pd.read_parquet(require(run_dir, runfiles.TRAIN_POSES))}
    ev = find_first(run_dir, runfiles.EVAL_POSES)
    if ev is not None:
        tables["evaluation path"] = pd.read_parquet(ev)
    fig = new_figure(8.0, 5.0)
    ax_p, ax_h = fig.subplots(2, 1, sharex=False)
    for i, (name, df) in enumerate(tables.items()):
        err = localisation_errors(df, "est")
        odo = localisation_errors(df, "odom")
        s = err.position_summary
        ax_p.plot(err.time_s, err.position_m, color=f"C{i}", lw=0.8,
                  label=f"MCL, {name} (median {s.median:.3f} m)")
        ax_p.plot(odo.time_s, odo.position_m, color=f"C{i}", lw=0.6, ls=":",
                  label=f"odometry, {name}")
        ax_h.plot(err.time_s, np.degrees(err.heading_rad), color=f"C{i}", lw=0.8, label=name)
    ax_p.set_ylabel("position error [m]")
    ax_p.set_xlabel("time [s]")
    ax_p.legend(fontsize=7)
    ax_h.set_ylabel("heading error [deg]")
    ax_h.set_xlabel("time [s]")
    ax_h.legend(fontsize=7)
    fig.suptitle("Localisation error (Monte Carlo Localization vs ground truth)")
    return save_figure(fig, out_dir or run_dir / "figures", "mcl_error")


def _field_arrays(path: Path) -> dict:
    """Plane gain of a saved ``propagation.RssiField``: x, y [m], gain_db [dB], pose (6,) or None.

    ``RssiField.save`` layout: ``plane_gain`` (ny, nx) linear one-way gain (0 where
    no ray arrived) and ``plane_centers_m`` (ny, nx, 3), ``antenna_pose`` (6,).
    Also accepted: ``gain_db`` with ``x_m``/``y_m`` axes or meshes.
    """
    with read_npz(path) as z:
        files = set(z.files)
        pose = np.array(z["antenna_pose"], float).ravel() if "antenna_pose" in files else None
        if "plane_gain" in files and "plane_centers_m" in files:
            g = np.array(z["plane_gain"], float)
            c = np.array(z["plane_centers_m"], float)
            with np.errstate(divide="ignore"):
                gdb = np.where(g > 0, 10.0 * np.log10(np.where(g > 0, g, 1.0)), np.nan)
            return {"x": c[..., 0], "y": c[..., 1], "gain_db": gdb, "pose": pose}
        if "gain_db" in files and "x_m" in files and "y_m" in files:
            return {"x": np.array(z["x_m"], float), "y": np.array(z["y_m"], float),
                    "gain_db": np.array(z["gain_db"], float), "pose": pose}
        raise ValueError(f"{path}: not an RssiField file (keys {sorted(files)})")


def fig_fields(run_dir, out_dir=None) -> list[Path]:
    """Ray-traced one-way gain over the field plane for the sample antenna poses (up to 4)."""
    run_dir = Path(run_dir)
    files = run_files(run_dir, "fields", "field_*.npz")[:_MAX_FIELDS]
    if not files:
        require(run_dir, runfiles.FIELD.format(i=0))
    plan = find_first(run_dir, runfiles.FLOORPLAN, runfiles.LEGACY_FLOORPLAN)
    segs = None
    if plan is not None:
        with read_npz(plan) as z:
            segs = _segments(z)
    fig = new_figure(10.0, 2.6 * len(files))
    axes = np.atleast_1d(fig.subplots(len(files), 1))
    for ax, f in zip(axes, files, strict=True):
        a = _field_arrays(f)
        g = np.where(np.isfinite(a["gain_db"]), a["gain_db"], np.nan)
        fin = g[np.isfinite(g)]
        vmax = float(fin.max()) if fin.size else 0.0
        kw = {"cmap": "inferno", "vmin": vmax - 60.0, "vmax": vmax, "rasterized": True}
        m = ax.pcolormesh(a["x"], a["y"], np.ma.masked_invalid(g), shading="auto", **kw)
        if segs is not None and len(segs):
            ax.add_collection(LineCollection(segs, colors="w", linewidths=0.6))
        if a["pose"] is not None and a["pose"].size >= 4:
            p = a["pose"]
            ax.plot(p[0], p[1], "c^", ms=6)
        ax.set_aspect("equal")
        ax.set_xlabel("x [m]")
        ax.set_ylabel("y [m]")
        ax.set_title(f"{f.stem}: one-way channel gain", fontsize=9)
        fig.colorbar(m, ax=ax, label="gain [dB]")
    fig.suptitle("Ray-traced field of sample antenna poses (Sionna RT, 865 MHz)")
    return save_figure(fig, out_dir or run_dir / "figures", "fields")
