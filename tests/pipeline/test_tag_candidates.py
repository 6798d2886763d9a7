"""The downstream stage's tag candidates: every surface height a tag could have, whatever
band the evaluation drew its held-out tags from (issue 37, item 6)."""

from __future__ import annotations

import numpy as np

import scenes
from pipeline.config import StudyConfig, replace_path
from pipeline.stages.common import study_scene, tag_candidates


def test_candidates_do_not_depend_on_the_held_out_heights():
    sc = scenes.corridor(length_m=4.0, width_m=2.0, height_m=2.5, name="cand_test")
    base = StudyConfig()
    narrow = replace_path(base, "evaluation.eval_tag_heights_m", (0.9, 1.1))
    a, b = tag_candidates(sc, base), tag_candidates(sc, narrow)
    np.testing.assert_array_equal(a.positions_m, b.positions_m)
    # floor to ceiling on the walls: below and above the default band (0.2, 1.6) m
    z = a.positions_m[:, 2]
    spacing = base.downstream.candidate_spacing_m
    assert z.min() <= spacing and z.max() >= 2.5 - spacing
    lo, hi = base.evaluation.eval_tag_heights_m
    outside = (z < lo) | (z > hi)
    assert outside.mean() > 0.3  # what the band-limited candidates left out


def test_held_out_tags_lie_between_candidates_not_on_them():
    # drawn on the 0.1 m grid of cell centres, which fall between the 0.05 m grid's: no
    # held-out tag sits exactly on a candidate (no free exact hit), none is farther than
    # half a cell diagonal from one, whatever the height band
    cfg = StudyConfig()
    sc, split = study_scene(cfg)
    cand = tag_candidates(sc, cfg).positions_m
    held = sc.tags.positions_m[split == "eval"]
    d = np.min(np.linalg.norm(held[:, None] - cand[None], axis=2), axis=1)
    step = cfg.downstream.candidate_spacing_m
    assert len(held) == cfg.evaluation.n_eval_tags
    assert d.min() >= step / 2 - 1e-6 and d.max() <= step / np.sqrt(2) + 1e-6
