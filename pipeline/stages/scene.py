"""Stage ``scene``: load the scene, draw the held-out tag layout, write ``scene/``.

It always runs (it is cheap), so an edited scene file changes its outputs' digest and
everything downstream re-runs.
"""

from __future__ import annotations

import numpy as np

from pipeline import runfiles
from pipeline.engine.runstore import atomic_write_json, save_npz
from pipeline.engine.study import Stage
from pipeline.evaluation.tables import write_tags
from pipeline.runfiles import STAGE_OUTPUTS
from pipeline.stages.common import load_scene
from pipeline.studyscene import study_route, warn_skipped_faces
from scenes.geometry import floor_plan_segments

__all__ = ["STAGE", "stage_scene"]


def stage_scene(ctx) -> dict:
    """Load the scene; write ``scene/scene.json``, ``scene/tags.parquet``, floor plan.

    A scene whose route was planned (a map) lists the tag faces the route skips in
    ``scene.json``'s ``route_skipped`` (their tags, positions and reasons), and says how
    many on the console once (:func:`pipeline.studyscene.warn_skipped_faces`)."""
    sc = load_scene(ctx)
    warn_skipped_faces(sc)
    cfg = ctx.config
    lo, hi = sc.bounds_m
    route = study_route(sc, cfg)
    summary = {
        "name": sc.name,
        "source": str(sc.source),
        "content_hash": sc.content_hash(),
        "bounds_m": [lo.tolist(), hi.tolist()],
        "materials": sc.materials,
        "n_tags": len(sc.tags),
        "n_tags_train": int(np.sum(ctx.memo["tag_split"] == "train")),
        "n_tags_eval": int(np.sum(ctx.memo["tag_split"] == "eval")),
        "route_m": None if route is None else np.round(route, 6).tolist(),
    }
    if "route" in sc.metadata:  # a planned route (a map scene): the tag faces it skips, and why
        summary["route_skipped"] = sc.metadata["route"]["skipped"]
    atomic_write_json(ctx.out(runfiles.SCENE_SUMMARY), summary)
    write_tags(ctx.out(runfiles.SCENE_TAGS), sc.tags.ids, sc.tags.positions_m, sc.tags.normals,
               split=ctx.memo["tag_split"])
    heights = sorted({0.35, 1.0})
    segs = {f"segments_z{int(h * 100):03d}cm": floor_plan_segments(sc, h) for h in heights}
    save_npz(ctx.out(runfiles.FLOORPLAN), heights_m=np.asarray(heights),
             route_m=np.zeros((0, 2)) if route is None else route, **segs)
    return {"scene": sc.name, "n_tags": len(sc.tags), "content_hash": summary["content_hash"][:16]}


STAGE = Stage("scene", stage_scene, ("scene", "materials", "seed", "tour.max_length_m", "evaluation.n_eval_tags",
                                     "evaluation.eval_tag_min_separation_m",
                                     "evaluation.eval_tag_heights_m", "training.d_max_m"),
              (), version=2,  # each version's change: CHANGELOG.md
              description="load the scene", always=True,
              outputs=STAGE_OUTPUTS["scene"])
