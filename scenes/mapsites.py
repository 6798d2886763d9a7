"""What a map scene offers beyond its geometry: shelf sites for held-out tags and a
description of what was recognised, for ``rfidstudy scenes show``.

Both read the scene's ``metadata["map"]`` (written by :func:`scenes.mapscene.build_map_scene`)
and, for the route, ``metadata["route"]`` (written by
:func:`pipeline.studyscene.map_route`).
"""

from __future__ import annotations

import numpy as np

from scenes.geometry import is_free, raycast
from scenes.mapscene import rack_frames
from scenes.scene import Scene
from scenes.tagsites import TagSites

__all__ = ["describe_map_scene", "shelf_sites"]


def shelf_sites(scene: Scene, spacing_m: float, z_range_m: tuple[float, float] | None = None,
                offset_m: float = 0.005):
    """Candidate tag sites on the front beams of a map scene's racks (held-out shelf tags).

    Along every rack face, ``spacing_m`` apart within its ends' margin (0.2 m), centred on
    the face, at the middle of every front beam within ``z_range_m``; a site is kept
    where it and the point 0.3 m in front of it are free space (a face against a wall or
    another rack keeps its open part). Empty for a scene without racks.

    Returns
    -------
    scenes.tagsites.TagSites
        Material ``"metal"``; clearance measured as :func:`scenes.tagsites.tag_sites` does.
    """
    m = scene.metadata.get("map") or {}
    racks = [o for o in m.get("obstacles", []) if o["kind"] == "rack" and "rectangle_m" in o]
    empty = TagSites(np.zeros((0, 3)), np.zeros((0, 3)), np.zeros(0, dtype=str), np.zeros(0))
    if not racks:
        return empty
    mids = np.asarray(m.get("shelf_levels_m", ()), float) + float(m.get("beam_height_m", 0.1)) / 2
    if z_range_m is not None:
        mids = mids[(mids >= z_range_m[0]) & (mids <= z_range_m[1])]
    pos, nrm = [], []
    for o in racks:
        c, u, v, length, depth = rack_frames(o["rectangle_m"])
        usable = length - 0.4
        if usable <= 0:
            continue
        n = int(np.floor(usable / spacing_m)) + 1
        s_ = (np.arange(n) - (n - 1) / 2) * spacing_m  # the draw keeps clear of training tags
        for w in (1.0, -1.0):
            for h in mids:
                for si in s_:
                    p = c + si * u + w * (depth / 2 + offset_m) * v
                    pos.append([p[0], p[1], h])
                    nrm.append([w * v[0], w * v[1], 0.0])
    if not pos:
        return empty
    pos, nrm = np.asarray(pos), np.asarray(nrm)
    keep = is_free(scene, pos) & is_free(scene, pos + 0.3 * nrm)
    pos, nrm = pos[keep], nrm[keep]
    order = np.lexsort((pos[:, 2], pos[:, 1], pos[:, 0]))
    pos, nrm = pos[order], nrm[order]
    hit = raycast(scene, pos + 1e-4 * nrm, nrm, max_range_m=2.0) if len(pos) else np.zeros(0)
    clearance = np.minimum(np.where(np.isfinite(hit), hit, 2.0), 2.0)
    return TagSites(pos, nrm, np.full(len(pos), "metal"), np.asarray(clearance, dtype=float))


def describe_map_scene(scene: Scene) -> list[str]:
    """Lines saying what was recognised in a map scene and what was dropped, and why.

    For ``rfidstudy scenes show``: obstacles by rule, the cleaning of the map
    (:mod:`scenes.mapclean`), the noise dropped, the radio surfaces, the planned route
    and the tag faces it skips (when ``scene.metadata["route"]`` is set by
    :func:`pipeline.studyscene.map_route`). Empty for a scene not from a map.
    """
    m = scene.metadata.get("map")
    if not m:
        return []
    from collections import Counter

    rules = Counter(o["rule"] for o in m["obstacles"])
    out = ["  map: " + ", ".join(f"{n} {r}" + ("s" if n != 1 and not r.endswith("s") else "")
                                 for r, n in sorted(rules.items())) if rules else "  map: no obstacle"]
    c = m.get("cleaning")
    if c:
        area = sum(f["area_m2"] for f in c["filled"])
        out.append(f"  cleaning: {c['gap_cells']} gap cells closed; {len(c['filled'])} enclosed outlines "
                   f"filled ({area:.1f} m^2); {c['kept_enclosed']} enclosed regions kept (rooms, free "
                   "pockets)")
    if m.get("noise_dropped"):
        out.append(f"  dropped as noise (under min_area_m2): {m['noise_dropped']} specks, "
                   f"{m['noise_dropped_m2']:.3f} m^2 in all")
    if not rules.get("rack"):
        out.append("  no rack recognised: a rack is a filled rectangle (rack_min_fill, rack_min_depth_m, "
                   "rack_min_length_m); override an obstacle with kind = \"rack\" where one is missed")
    out.append(f"  radio surfaces: {len(scene.radio_surfaces)}")
    r = scene.metadata.get("route")
    if r:
        out.append(f"  planned route: {r['length_m']:.0f} m, {r['passes']} passes")
        for sk in r["skipped"]:
            out.append(f"  skipped {len(sk['tags'])} tags ({sk['tags'][0]}...): {sk['reason']}")
    return out
