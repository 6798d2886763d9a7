"""Figures of a placement study, drawn from its summary table and run directories.

- ``ranking.png``: the primary objective of every candidate with its 95 % interval,
  best first, infeasible candidates greyed;
- ``heatmap.png`` (two-parameter grids): the primary objective over the grid, each
  cell with its interval's half-width; nothing averaged;
- ``marginal_<field>.png``: the primary objective against one grid field, one line per
  value of the other fields (the legend says which): no silent averaging;
- ``pareto.png``: the two ``pareto`` objectives with their intervals, the front marked;
- ``completeness_by_height.png``: completeness per tag-height band with intervals;
- ``readmap_<candidate>.png`` (recommended and runner-up): reads per metre of route
  against the distance driven, one row per tag (replicate 0's training tour);
- ``never_read_<candidate>.png`` (recommended and runner-up): a top view of the tags
  the tour never read.
"""

from __future__ import annotations

import io
from pathlib import Path

import numpy as np
import pandas as pd

from pipeline import runfiles
from pipeline.apps.placement.candidates import MOUNT_FIELDS
from pipeline.apps.placement.objectives import OBJECTIVES
from pipeline.apps.placement.results import band_key, candidate_dir, height_bands
from pipeline.engine.runstore import atomic_write_bytes, inside
from scenes.fileio import read_npz

__all__ = ["draw_figures", "route_distance_m"]


def _save(fig, path: Path) -> Path:
    import matplotlib.pyplot as plt

    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=150, bbox_inches="tight")
    plt.close(fig)
    return atomic_write_bytes(path, buf.getvalue())


def _err(df: pd.DataFrame, key: str) -> np.ndarray:
    v = df[key].to_numpy(float)
    lo = df.get(f"{key}_low", pd.Series(np.nan, index=df.index)).to_numpy(float)
    hi = df.get(f"{key}_high", pd.Series(np.nan, index=df.index)).to_numpy(float)
    return np.vstack([np.where(np.isfinite(lo), v - lo, 0.0), np.where(np.isfinite(hi), hi - v, 0.0)])


def _grid_fields(df: pd.DataFrame) -> list[str]:
    g = df[df["origin"] == "grid"]
    return [k for k in MOUNT_FIELDS if k in g and g[k].notna().any() and g[k].nunique() > 1]


def draw_figures(spec, out: Path, df: pd.DataFrame, datas: dict, answer: dict) -> list[Path]:
    """Draw every figure into ``out/placement/figures/``; return their paths."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    s = spec.settings

    fdir = inside(out, "placement/figures")  # a planted link is refused, never followed
    fdir.mkdir(parents=True, exist_ok=True)
    files = []
    prim = s.primary
    plab = OBJECTIVES[prim].label
    ok = df[df[prim].notna()]

    fig, ax = plt.subplots(figsize=(7.0, 0.35 * max(len(ok), 3) + 1.2))
    y = np.arange(len(ok))[::-1]
    colors = ["C0" if f else "0.6" for f in ok["feasible"]]
    ax.errorbar(ok[prim], y, xerr=_err(ok, prim), fmt="none", ecolor="0.4", capsize=3)
    ax.scatter(ok[prim], y, c=colors, zorder=3)
    ax.set_yticks(y, ok["candidate"], fontsize=8)
    ax.set_xlabel(f"{plab} (95 % interval)")
    ax.set_title("Candidates, best first (grey: misses a constraint)", fontsize=9)
    ax.grid(alpha=0.3)
    files.append(_save(fig, fdir / "ranking.png"))

    fields = _grid_fields(df)
    g = df[df["origin"] == "grid"]
    if len(fields) == 2:
        a, b = fields
        piv = g.pivot_table(index=a, columns=b, values=prim, aggfunc="first")
        hw = (g.assign(hw=(g[f"{prim}_high"] - g[f"{prim}_low"]) / 2)
              .pivot_table(index=a, columns=b, values="hw", aggfunc="first"))
        fig, ax = plt.subplots(figsize=(1.3 * len(piv.columns) + 2.5, 1.0 * len(piv.index) + 1.5))
        im = ax.imshow(piv.to_numpy(float), origin="lower", aspect="auto", cmap="viridis")
        for i in range(len(piv.index)):
            for j in range(len(piv.columns)):
                v, h = piv.iat[i, j], hw.iat[i, j] if hw.shape == piv.shape else np.nan
                txt = "–" if not np.isfinite(v) else (f"{v:.3g}" + (f"\n±{h:.2g}" if np.isfinite(h) else ""))
                ax.text(j, i, txt, ha="center", va="center", fontsize=8, color="w")
        ax.set_xticks(range(len(piv.columns)), [f"{v:g}" for v in piv.columns])
        ax.set_yticks(range(len(piv.index)), [f"{v:g}" for v in piv.index])
        ax.set_xlabel(b)
        ax.set_ylabel(a)
        fig.colorbar(im, ax=ax, label=plab)
        ax.set_title(f"{plab} over the grid (± half the 95 % interval)", fontsize=9)
        files.append(_save(fig, fdir / "heatmap.png"))
    for f in fields:
        others = [o for o in fields if o != f]
        fig, ax = plt.subplots(figsize=(5.5, 3.5))
        groups = g.groupby(others, dropna=False) if others else [((), g)]
        for key, part in groups:
            part = part.sort_values(f)
            lab = ", ".join(f"{o} = {v:g}" for o, v in zip(others, np.atleast_1d(key), strict=True))
            ax.errorbar(part[f], part[prim], yerr=_err(part, prim), marker="o", capsize=3,
                        label=lab or None)
        ax.set_xlabel(f)
        ax.set_ylabel(plab)
        ax.set_title(f"{plab} against {f}" + (f"; one line per {', '.join(others)} (not averaged)"
                                              if others else ""), fontsize=8)
        if others:
            ax.legend(fontsize=7)
        ax.grid(alpha=0.3)
        files.append(_save(fig, fdir / f"marginal_{f}.png"))

    a, b = s.pareto
    pp = df[df[a].notna() & df[b].notna()]
    if len(pp):
        front = set(answer.get("pareto_front") or [])
        fig, ax = plt.subplots(figsize=(5.5, 4.0))
        ax.errorbar(pp[a], pp[b], xerr=_err(pp, a), yerr=_err(pp, b), fmt="none", ecolor="0.7")
        on = pp["candidate"].isin(front).to_numpy()
        ax.scatter(pp[a][~on], pp[b][~on], c="0.5", label="dominated")
        ax.scatter(pp[a][on], pp[b][on], c="C3", label="Pareto front", zorder=3)
        for _, r in pp[on].iterrows():
            ax.annotate(r["candidate"], (r[a], r[b]), fontsize=7, xytext=(3, 3),
                        textcoords="offset points")
        ax.set_xlabel(OBJECTIVES[a].label)
        ax.set_ylabel(OBJECTIVES[b].label)
        ax.legend(fontsize=7)
        ax.grid(alpha=0.3)
        files.append(_save(fig, fdir / "pareto.png"))

    bands = height_bands(s.height_bands_m)
    top = df[df["completeness"].notna()].head(6)
    if len(top):
        fig, ax = plt.subplots(figsize=(6.0, 3.5))
        x = np.arange(len(bands))
        for j, (_, r) in enumerate(top.iterrows()):
            v = np.array([r.get(band_key(bd), np.nan) for bd in bands], float)
            lo = np.array([r.get(band_key(bd) + "_low", np.nan) for bd in bands], float)
            hi = np.array([r.get(band_key(bd) + "_high", np.nan) for bd in bands], float)
            err = np.vstack([np.where(np.isfinite(lo), v - lo, 0), np.where(np.isfinite(hi), hi - v, 0)])
            ax.errorbar(x + 0.08 * (j - len(top) / 2), v, yerr=err, marker="o", capsize=2,
                        label=r["candidate"], linestyle="none")
        ax.set_xticks(x, [f"{lo:g}-{hi:g} m" for lo, hi in bands])
        ax.set_xlabel("tag height band")
        ax.set_ylabel(f"tags read >= {s.min_reads} times per pass")
        ax.set_ylim(-0.05, 1.05)
        ax.legend(fontsize=7)
        ax.set_title("Completeness by tag height (bands without tags left empty)", fontsize=9)
        ax.grid(alpha=0.3)
        files.append(_save(fig, fdir / "completeness_by_height.png"))

    for name in (answer.get("recommended"), answer.get("runner_up")):
        if name:
            run = candidate_dir(out, name, 0)
            for p in (_read_map(run, fdir / f"readmap_{name}.png", name),
                      _never_read_map(run, fdir / f"never_read_{name}.png", name)):
                if p:
                    files.append(p)
    return files


def route_distance_m(track_xy_m, t_s, at_s) -> np.ndarray:
    """Distance driven along a track up to each time of ``at_s`` [m].

    Parameters
    ----------
    track_xy_m : numpy.ndarray, float64, (n, 2)
        The robot's true positions [m].
    t_s : numpy.ndarray, float64, (n,)
        Their times, increasing [s].
    at_s : array_like, float64
        Times to evaluate at (clamped to the track's span) [s].

    Returns
    -------
    numpy.ndarray, float64, same shape as ``at_s``
        Cumulative path length, linearly interpolated between poses [m].
    """
    xy = np.asarray(track_xy_m, np.float64)
    s = np.concatenate([[0.0], np.cumsum(np.hypot(*np.diff(xy, axis=0).T))])
    return np.interp(np.asarray(at_s, np.float64), np.asarray(t_s, np.float64), s)


def _read_map(run: Path, path: Path, name: str) -> Path | None:
    """Reads per metre of route, one row per tag, tags ordered by where along the route
    the robot passes them closest; drawn as an image so that a warehouse's hundreds of
    tags and a long route stay one readable page (tick labels only for a few tags)."""
    import matplotlib.pyplot as plt

    try:
        reads = pd.read_parquet(inside(run, runfiles.TRAIN_READS), columns=["time_s", "tag_id", "read"])
        tags = pd.read_parquet(inside(run, runfiles.SCENE_TAGS),
                               columns=["tag_id", "x_m", "y_m", "z_m"])
        with read_npz(inside(run, runfiles.TRAIN_TRACK)) as z:
            t_s, true = z["t_s"], z["true"]
    except (OSError, ValueError, KeyError):
        return None
    ids = reads["tag_id"].astype(str)
    tags = tags[tags["tag_id"].astype(str).isin(ids.unique())].reset_index(drop=True)
    if tags.empty or len(t_s) < 2:
        return None
    dist = route_distance_m(true[:, :2], t_s, t_s)
    # where along the route each tag is passed closest: the rows' order
    d2 = ((true[None, :, :2] - tags[["x_m", "y_m"]].to_numpy()[:, None, :]) ** 2).sum(-1)
    tags["s_closest_m"] = dist[np.argmin(d2, axis=1)]
    tags = tags.sort_values("s_closest_m", kind="stable").reset_index(drop=True)
    row = pd.Series(np.arange(len(tags)), index=tags["tag_id"].astype(str))
    hit = reads["read"].to_numpy(bool)
    s_read = route_distance_m(true[:, :2], t_s, reads["time_s"].to_numpy(np.float64)[hit])
    bins = np.arange(0.0, dist[-1] + 1.0, 1.0)  # 1 m of route per column
    img, _, _ = np.histogram2d(row.loc[ids[hit]].to_numpy(), s_read,
                               bins=[np.arange(len(tags) + 1) - 0.5, bins])
    never = img.sum(axis=1) == 0
    fig, ax = plt.subplots(figsize=(8.0, min(9.0, 1.8 + 0.05 * len(tags))))
    shown = np.where(img > 0, img, np.nan)
    im = ax.imshow(shown, aspect="auto", origin="lower", interpolation="nearest", cmap="viridis",
                   extent=(bins[0], bins[-1], -0.5, len(tags) - 0.5))
    ax.scatter(tags["s_closest_m"], np.arange(len(tags)), marker="|", c="k", s=12,
               label="closest approach")
    if never.any():
        ax.scatter(tags["s_closest_m"][never], np.flatnonzero(never), marker="x", c="C3", s=20,
                   label=f"never read ({int(never.sum())})")
    if len(tags) <= 40:
        ax.set_yticks(np.arange(len(tags)), [f"{t} ({z:g} m)" for t, z in
                                             zip(tags["tag_id"], tags["z_m"], strict=True)],
                      fontsize=6)
    else:
        ax.set_ylabel(f"tag ({len(tags)}), ordered by where the route passes it")
    ax.set_xlabel("distance driven along the training tour [m]")
    fig.colorbar(im, ax=ax, label="reads per metre of route")
    ax.set_title(f"{name}: where along the route each tag is read (replicate 0)", fontsize=9)
    ax.legend(fontsize=7, loc="upper left")
    return _save(fig, path)


def _never_read_map(run: Path, path: Path, name: str) -> Path | None:
    """Top view: the building's walls, the driven tour, every tag, the tags the tour
    never read marked (replicate 0)."""
    import matplotlib.pyplot as plt

    try:
        reads = pd.read_parquet(inside(run, runfiles.TRAIN_READS), columns=["tag_id", "read"])
        tags = pd.read_parquet(inside(run, runfiles.SCENE_TAGS),
                               columns=["tag_id", "x_m", "y_m", "z_m"])
        with read_npz(inside(run, runfiles.TRAIN_TRACK)) as z:
            true = z["true"]
        with read_npz(inside(run, runfiles.FLOORPLAN)) as z:
            walls = [z[k] for k in z.files if k.startswith("segments_")][:1]
    except (OSError, ValueError, KeyError):
        return None
    n_reads = reads.groupby(reads["tag_id"].astype(str))["read"].sum()
    tags = tags[tags["tag_id"].astype(str).isin(n_reads.index)]
    if tags.empty:
        return None
    never = (n_reads.reindex(tags["tag_id"].astype(str)) == 0).to_numpy()
    fig, ax = plt.subplots(figsize=(7.0, 6.0))
    for seg in walls:
        for a, b in seg:
            ax.plot([a[0], b[0]], [a[1], b[1]], c="0.35", lw=0.8)
    ax.plot(true[:, 0], true[:, 1], c="C0", lw=0.8, alpha=0.6, label="driven tour")
    ax.scatter(tags["x_m"][~never], tags["y_m"][~never], s=10, c="0.5", label="read")
    ax.scatter(tags["x_m"][never], tags["y_m"][never], s=40, marker="x", c="C3",
               label=f"never read ({int(never.sum())} of {len(tags)})")
    ax.set_aspect("equal")
    ax.set_xlabel("x [m]")
    ax.set_ylabel("y [m]")
    ax.set_title(f"{name}: tags the training tour never read (replicate 0)", fontsize=9)
    ax.legend(fontsize=7, loc="upper left", bbox_to_anchor=(1.01, 1.0))
    return _save(fig, path)
