"""Tag sites on a scene's surfaces and held-out tag layouts drawn from them."""

from __future__ import annotations

import numpy as np
import pytest

import scenes
from scenes.geometry import is_free
from scenes.tagsites import draw_tags, tag_sites


@pytest.fixture(scope="module")
def lab():
    return scenes.load("corridor_lab")


def test_sites_lie_in_free_space_in_front_of_vertical_surfaces(lab):
    s = tag_sites(lab, spacing_m=0.25, z_range_m=(0.2, 1.6))
    assert len(s) > 500
    assert np.all(is_free(lab, s.positions_m))
    assert np.allclose(s.normals[:, 2], 0.0) and np.allclose(np.linalg.norm(s.normals, axis=1), 1)
    assert s.positions_m[:, 2].min() >= 0.2 and s.positions_m[:, 2].max() <= 1.6
    # brick wall at y = 0 faces +y: its sites sit 5 mm in front of it
    brick = s.material == "brick"
    assert brick.any() and np.allclose(s.positions_m[brick & (s.normals[:, 1] > 0.9), 1], 0.005)
    # the wall behind cabinet C2 (x 13.55..14.45, 1 cm off the wall) has sites with ~1 cm room
    behind = (np.abs(s.positions_m[:, 0] - 14.0) < 0.4) & (s.positions_m[:, 1] < 0.01) & (
        s.positions_m[:, 2] < 1.7)
    assert behind.any() and np.all(s.clearance_m[behind] < 0.02)
    assert {"metal", "chipboard", "plasterboard", "glass"} <= set(s.material.tolist())


def test_draw_tags_keeps_apart_and_is_reproducible(lab):
    s = tag_sites(lab)
    avoid = lab.tags.positions_m
    a = draw_tags(s, 16, np.random.default_rng(3), avoid_m=avoid, min_separation_m=0.5)
    b = draw_tags(s, 16, np.random.default_rng(3), avoid_m=avoid, min_separation_m=0.5)
    np.testing.assert_array_equal(a.positions_m, b.positions_m)
    d = np.linalg.norm(a.positions_m[:, None] - a.positions_m[None], axis=2)
    assert d[~np.eye(16, dtype=bool)].min() >= 0.5
    assert np.linalg.norm(a.positions_m[:, None] - avoid[None], axis=2).min() >= 0.5
    assert list(a.ids[:2]) == ["E01", "E02"]


def test_draw_tags_names_the_setting_when_too_many(lab):
    s = tag_sites(lab)
    with pytest.raises(ValueError, match=r"evaluation.n_eval_tags = 5000.*only \d+ of 5000"):
        draw_tags(s, 5000, np.random.default_rng(0), min_separation_m=0.5,
                  where="evaluation.n_eval_tags = 5000")


def test_raycast_within_range_is_the_unlimited_cast_cut_at_the_range(lab):
    """A cast limited to ``max_range_m`` skips triangles out of its segments' reach; the
    hits must be exactly those of the unlimited cast (which tests every triangle) that lie
    within range: rays from tag sites along their normals (coherent, as tag_sites casts
    them) and random rays through the corridor (incoherent)."""
    from scenes.geometry import raycast

    rng = np.random.default_rng(2)
    s = tag_sites(lab, spacing_m=0.25, z_range_m=(0.2, 1.6))
    lo, hi = lab.bounds_m
    origins = np.concatenate([s.positions_m + 1e-4 * s.normals, rng.uniform(lo, hi, (3000, 3))])
    directions = np.concatenate([s.normals, rng.normal(size=(3000, 3))])
    full = raycast(lab, origins, directions)
    for r in (0.3, 2.0, 12.0):
        cut = raycast(lab, origins, directions, max_range_m=r)
        np.testing.assert_array_equal(cut, np.where(full <= r, full, np.inf))
        assert np.isfinite(cut).sum() > 100  # hits within range are exercised
    # one range per ray (obstructed_pairs: each ray as far as its site), mixed short and long
    r = rng.choice([0.3, 2.0, 12.0], len(origins))
    cut = raycast(lab, origins, directions, max_range_m=r)
    np.testing.assert_array_equal(cut, np.where(full <= r, full, np.inf))
    assert np.isfinite(cut).sum() > 100
