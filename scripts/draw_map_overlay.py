"""Top view of a map scene: the ROS map, the extracted outlines, the traced centre lines,
the tags and the planned coverage route, in one picture.

    python scripts/draw_map_overlay.py warehouse_small docs/fig_warehouse_map.png
    python scripts/draw_map_overlay.py site.yaml top.png

Grey pixels are the map as the robot has it (black occupied, light free, mid-grey unknown);
coloured outlines the obstacles by kind (walls by material), thick coloured lines the
surfaces the ray tracer sees at wall centre lines, dots the tags, the dashed line the route.
"""

from __future__ import annotations

import argparse
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

import scenes  # noqa: E402
from pipeline.robot import Robot  # noqa: E402
from pipeline.studyscene import map_route  # noqa: E402
from scenes.mapextract import extract_obstacles  # noqa: E402
from scenes.mapspec import parse_map_table, rules_of  # noqa: E402

COLOURS = {"concrete": "tab:gray", "brick": "tab:red", "plasterboard": "tab:olive", "metal": "tab:blue",
           "glass": "tab:cyan", "wood": "tab:brown"}


KIND_FILL = {"rack": "tab:blue", "pillar": "tab:purple"}


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("scene")
    ap.add_argument("out", type=Path)
    args = ap.parse_args(argv)
    sc = scenes.load(args.scene)
    note = ""
    try:
        sc = map_route(sc, Robot())
    except ValueError as exc:  # shown, not fatal: the extraction is worth seeing anyway
        note = f"no route: {exc}"
    rm = sc.rosmap
    if rm is None:
        raise SystemExit(f"{args.scene}: not a map scene")
    spec = sc.metadata.get("spec", {}).get("map")
    rules = rules_of(parse_map_table(spec, "map")) if spec else None
    shown = {0: 0.93, 1: 0.1, -1: 0.6}
    img = np.vectorize(shown.get)(rm.cell_class)
    (x0, y0), (x1, y1) = rm.extent_m
    aspect = (y1 - y0) / (x1 - x0)
    fig, axes = plt.subplots(1, 2, figsize=(12, 6 * aspect + 1.2), sharex=True, sharey=True)
    for ax in axes:
        ax.imshow(img, origin="lower", extent=(x0, x1, y0, y1), cmap="gray", vmin=0, vmax=1,
                  interpolation="nearest", alpha=1.0 if ax is axes[0] else 0.45)
        ax.set_xlabel("x [m]")
        ax.set_aspect("equal")
    axes[0].set_ylabel("y [m]")
    axes[0].set_title("the map as given")
    kinds = {o["index"]: o for o in sc.metadata["map"]["obstacles"]}
    for o in extract_obstacles(rm, None, rules):
        k = kinds.get(o.index, {"material": o.material, "kind": o.kind})
        colour = KIND_FILL.get(k["kind"], COLOURS.get(k["material"], "k"))
        x, y = o.polygon.exterior.xy
        if k["kind"] in KIND_FILL:
            axes[1].fill(x, y, color=colour, alpha=0.5, lw=0)
        axes[1].plot(x, y, color=colour, lw=0.8)
    for s in sc.radio_surfaces:
        if s.kind in ("wall", "leaf"):
            v = s.mesh.vertices
            axes[1].plot(v[:2, 0], v[:2, 1], color=COLOURS.get(s.material, "k"), lw=2.0, alpha=0.8)
    t = sc.tags.positions_m
    axes[1].plot(t[:, 0], t[:, 1], ".", color="tab:orange", ms=3, label=f"{len(t)} tags")
    skipped = sc.metadata.get("route", {}).get("skipped", [])
    if skipped:
        ids = {str(i) for sk in skipped for i in sk["tags"]}
        raw = scenes.load(args.scene).tags
        xy = raw.positions_m[np.isin(raw.ids.astype(str), sorted(ids))]
        axes[1].plot(xy[:, 0], xy[:, 1], "x", color="tab:red", ms=5, label=f"{len(xy)} tags skipped")
    r = sc.route_m
    if r is not None:
        length = float(np.linalg.norm(np.diff(r, axis=0), axis=1).sum())
        axes[1].plot(r[:, 0], r[:, 1], "--", color="tab:green", lw=1.2, label=f"route {length:.0f} m")
    for kind, c in KIND_FILL.items():
        axes[1].fill([], [], color=c, alpha=0.5, label=kind)
    for mat, c in COLOURS.items():
        if mat in sc.materials and mat != "metal":
            axes[1].plot([], [], color=c, lw=2, label=mat)
    axes[1].set_title("recognised: racks, pillars, walls by material, tags, route" + (f"\n{note[:90]}" if note else ""),
                      fontsize=9)
    axes[1].legend(loc="upper center", bbox_to_anchor=(0.5, -0.08), ncol=4, fontsize=8, frameon=False)
    fig.suptitle(sc.name)
    fig.tight_layout()
    args.out.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(args.out, dpi=110)
    print(args.out)


if __name__ == "__main__":
    main()
