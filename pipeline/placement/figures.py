"""Figures of a placement study, drawn from its summary table and run directories.

- ``ranking.png``: the primary objective of every candidate with its 95 % interval,
  best first, infeasible candidates greyed;
- ``heatmap.png`` (two-parameter grids): the primary objective over the grid, each
  cell with its interval's half-width; nothing averaged;
- ``marginal_<field>.png``: the primary objective against one grid field, one line per
  value of the other fields (the legend says which): no silent averaging;
- ``pareto.png``: the two ``pareto`` objectives with their intervals, the front marked;
- ``completeness_by_height.png``: completeness per tag-height band with intervals;
- ``readmap_<candidate>.png`` (recommended and runner-up): where along the route each
  tag is read (replicate 0's training tour), one row per tag, by antenna.
"""

from __future__ import annotations

import io
from pathlib import Path

import numpy as np
import pandas as pd

from pipeline.runstore import atomic_write_bytes

from .objectives import OBJECTIVES

__all__ = ["draw_figures"]


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
    from .spec import MOUNT_FIELDS

    g = df[df["origin"] == "grid"]
    return [k for k in MOUNT_FIELDS if k in g and g[k].notna().any() and g[k].nunique() > 1]


def draw_figures(spec, out: Path, df: pd.DataFrame, datas: dict, answer: dict) -> list[Path]:
    """Draw every figure into ``out/placement/figures/``; return their paths."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    s = spec.settings
    from pipeline.runstore import inside

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

    from .summary import _bands, band_key

    bands = _bands(s.height_bands_m)
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
            from .runner import candidate_dir

            p = _read_map(candidate_dir(out, name, 0), fdir / f"readmap_{name}.png", name)
            if p:
                files.append(p)
    return files


def _read_map(run: Path, path: Path, name: str) -> Path | None:
    import matplotlib.pyplot as plt

    from pipeline.runstore import inside

    try:
        reads = pd.read_parquet(inside(run, "reads.parquet"),
                                columns=["tag_id", "read", "antenna", "true_ant_x_m"])
        tags = pd.read_parquet(inside(run, "scene/tags.parquet"), columns=["tag_id", "x_m", "z_m"])
    except (OSError, ValueError):
        return None
    tags = tags[tags["tag_id"].isin(reads["tag_id"].astype(str).unique())].sort_values("x_m")
    row = {t: i for i, t in enumerate(tags["tag_id"])}
    r = reads[reads["read"]]
    fig, ax = plt.subplots(figsize=(7.0, 0.22 * len(tags) + 1.5))
    for a, part in r.groupby("antenna"):
        ax.scatter(part["true_ant_x_m"], part["tag_id"].astype(str).map(row), s=3, alpha=0.5,
                   label=f"antenna {a}")
    ax.scatter(tags["x_m"], np.arange(len(tags)), marker="|", c="k", s=40, label="tag position")
    ax.set_yticks(np.arange(len(tags)), [f"{t} ({z:g} m)" for t, z in zip(tags["tag_id"], tags["z_m"],
                                                                              strict=True)],
                  fontsize=6)
    ax.set_xlabel("antenna x along the route [m]")
    ax.set_title(f"{name}: where each tag is read (replicate 0, training tour)", fontsize=9)
    ax.legend(fontsize=7, markerscale=3)
    ax.grid(alpha=0.3)
    return _save(fig, path)
