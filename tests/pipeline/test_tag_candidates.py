"""The downstream stage's tag candidates: every surface height a tag could have, whatever
band the evaluation drew its held-out tags from (issue 37, item 6)."""

from __future__ import annotations

import numpy as np

import scenes
from pipeline.config import StudyConfig, replace_path
from pipeline.studyscene import study_scene, tag_candidates


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


def test_candidates_lie_off_the_held_out_grid_whatever_the_face_sizes():
    # faces 4.07 x 2.47 m and 2.07 x 2.47 m: floor(W / 0.05) odd on every axis, where two
    # grids each centred on its face coincide; the candidate grid is laid half a step off
    # the held-out tags' grid, so every site of that grid is exactly half a candidate cell
    # diagonal from its nearest candidates
    from scipy.spatial import cKDTree

    from pipeline.studyscene import EVAL_TAG_SPACING_M
    from scenes.tagsites import tag_sites

    sc = scenes.corridor(length_m=4.07, width_m=2.07, height_m=2.47, name="odd_faces")
    cfg = StudyConfig()
    step = cfg.downstream.candidate_spacing_m
    assert np.floor(4.07 / step) % 2 == 1 and np.floor(2.47 / step) % 2 == 1
    held = tag_sites(sc, spacing_m=EVAL_TAG_SPACING_M, z_range_m=None).positions_m
    cand = tag_candidates(sc, cfg).positions_m
    d = cKDTree(cand).query(held)[0]
    assert len(held) > 1000
    np.testing.assert_allclose(d, step / np.sqrt(2), atol=1e-6)
    # the candidates still cover the faces at the candidate spacing
    assert len(cand) > 3.5 * len(held)


def test_held_out_tags_lie_between_candidates_not_on_them():
    # the study's own held-out tags, drawn on the 0.1 m grid: the candidate grid is laid
    # half a 0.05 m step off it, so no held-out tag sits exactly on a candidate (no free
    # exact hit) and each is half a cell diagonal from its nearest, whatever the band
    cfg = StudyConfig()
    sc, split = study_scene(cfg)
    cand = tag_candidates(sc, cfg).positions_m
    held = sc.tags.positions_m[split == "eval"]
    d = np.min(np.linalg.norm(held[:, None] - cand[None], axis=2), axis=1)
    step = cfg.downstream.candidate_spacing_m
    assert len(held) == cfg.evaluation.n_eval_tags
    np.testing.assert_allclose(d, step / np.sqrt(2), atol=1e-6)
