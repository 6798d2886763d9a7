"""Pooled tracing (rays shot from a lattice, exact paths at every position) and channels."""

import numpy as np
import pytest

from propagation import free_space_gain_db, trace_links, two_ray_gain_db
from propagation.channels import link_channels
from propagation.pathsolve import _trace_chunk, bytes_per_source
from propagation.pooled import lattice_points, pooling_plan, trace_pooled
from propagation.sionna_scene import load_sionna_scene
from propagation.tracing import tag_dipole_axes
from scenes import material
from tests.helpers.scenes import make_corridor

pytestmark = pytest.mark.filterwarnings("ignore::scenes.materials.FrequencyRangeWarning")

F = 865e6
C0 = 299_792_458.0


def test_pooling_own_candidates_reproduces_the_path_solver(corridor_scene):
    # shooting from the positions themselves and pooling nothing else is exactly what
    # Sionna's PathSolver does: same candidates, same image method, same field
    tags = corridor_scene.tags.positions_m[:6]
    pos = np.array([[3.0, 1.2, 0.7], [3.05, 1.21, 0.7], [8.0, 0.8, 1.0]])
    rts = load_sionna_scene(corridor_scene, F)
    direct = _trace_chunk(rts, pos, tags, 3, 5000, 1)
    pooled = trace_pooled(rts, pos, pos, [[0], [1], [2]], tags, np.ones((3, len(tags)), bool), 3, 5000, 1)
    for a, b in zip(direct, pooled, strict=True):
        np.testing.assert_array_equal(a.offsets, b.offsets)
        # float32 solver output, same kernels: equal to rounding
        np.testing.assert_allclose(np.sort(a.tau_s), np.sort(b.tau_s), rtol=1e-6)
        np.testing.assert_allclose(np.sort(np.abs(a.transfer).ravel()), np.sort(np.abs(b.transfer).ravel()),
                                   rtol=1e-4, atol=1e-9)


def test_pooled_floor_links_are_exact_not_extrapolated(floor_scene):
    # Over a floor every chain is found from anywhere, so the pooled paths are the image
    # method's exact paths at each position: the two-ray closed form holds to the 0.5 dB
    # of the slab-vs-half-space difference (test_tracing), positions 0.1-0.2 m from
    # their lattice point included
    eps, sigma = material("concrete", F)
    d = np.linspace(2.0, 12.0, 21)
    h_r = 1.0
    heights = np.array([0.55, 0.62, 0.68, 0.81])
    tags = np.stack([d, 0 * d, 0 * d + h_r], axis=1)
    poses = np.column_stack([np.zeros(4), np.zeros(4), heights, np.zeros(4)])
    links = trace_links(floor_scene, poses, tags, max_depth=1, samples_per_src=20000, reader_pattern="iso",
                        tag_pattern="iso", lattice_spacing_m=0.5)
    assert links.settings["n_shooting_points"] < len(poses)  # shared lattice points
    for k, h_t in enumerate(heights):
        ref = two_ray_gain_db(d, h_t, h_r, F, eps, sigma, "V")
        # away from the deep two-ray nulls, where 0.2 m of slab vs half-space moves the null
        ok = ref > ref.max() - 15
        np.testing.assert_allclose(links.gain_db[k][ok], ref[ok], atol=0.5)


def test_pooled_tour_shoots_fewer_points_and_stays_within_seed_noise(tmp_path):
    scene = make_corridor()
    tags = scene.tags.positions_m
    x = np.arange(2.0, 8.0, 0.05)  # a read every 5 cm along the corridor
    poses = np.column_stack([x, 1.2 + 0.05 * np.sin(3 * x), np.full_like(x, 0.7), np.zeros_like(x)])
    kw = dict(max_depth=3, samples_per_src=5000, tag_normals=scene.tags.normals)
    ref1 = trace_links(scene, poses, tags, seed=1, **kw)
    ref2 = trace_links(scene, poses, tags, seed=2, **kw)
    pooled = trace_links(scene, poses, tags, seed=1, lattice_spacing_m=0.25, cache_dir=tmp_path,
                         memory_budget_bytes=16 * bytes_per_source(5000, 3), **kw)
    assert pooled.settings["n_shooting_points"] <= 0.5 * len(poses)
    strong = np.maximum(ref1.gain_db, ref2.gain_db) > ref1.gain_db.max() - 25
    seed_noise = np.median(np.abs(ref1.gain_db - ref2.gain_db)[strong])
    pooled_err = np.median(np.abs(ref1.gain_db - pooled.gain_db)[strong])
    # pooled paths are exact paths, so its difference to a direct trace is the direct
    # trace's own sampling noise (measured here with another seed); 1.5x allows for
    # the median's spread over these few hundred links
    assert pooled_err <= 1.5 * seed_noise + 0.05
    # cached: a rerun traces nothing and is bit-identical
    again = trace_links(scene, poses, tags, seed=1, lattice_spacing_m=0.25, cache_dir=tmp_path, **kw)
    assert again.n_traced_sources == 0
    np.testing.assert_array_equal(again.gain_db, pooled.gain_db)
    # a direct trace never reuses pooled cache entries (another settings key)
    direct = trace_links(scene, poses[:3], tags, seed=1, cache_dir=tmp_path, **kw)
    assert direct.n_traced_sources == 3


def test_pooling_plan_chunks_and_neighbours(corridor_scene):
    x = np.arange(2.0, 10.0, 0.05)
    pos = np.column_stack([x, np.full_like(x, 1.2), np.full_like(x, 0.7)])
    lat, nearest = lattice_points(pos, 0.25)
    assert np.all(np.linalg.norm(pos - lat[nearest], axis=1) <= 0.25 * np.sqrt(3) / 2 + 1e-12)
    plan = pooling_plan(corridor_scene, pos, 0.25, max_shoot_per_call=6)
    solved = np.sort(np.concatenate([c.positions for c in plan]))
    np.testing.assert_array_equal(solved, np.arange(len(pos)))  # each position once
    for c in plan:
        assert len(c.shoot_m) <= 6
        for i, nb in zip(c.positions, c.neighbours, strict=True):
            # nearest lattice point first, all within the pooling radius
            np.testing.assert_allclose(c.shoot_m[nb[0]], lat[nearest[i]])
            assert np.all(np.linalg.norm(c.shoot_m[nb] - pos[i], axis=1) <= 1.2 * 0.25 + 1e-9)
    # a lone position (no other position pools its lattice point) shoots its own rays:
    # a lattice point would save nothing and its candidates come from up to 0.22 m away
    lone = np.array([[2.0, 1.2, 0.7], [6.0, 1.1, 0.9]])
    plan = pooling_plan(corridor_scene, lone, 0.25, max_shoot_per_call=6)
    for c in plan:
        for i, nb in zip(c.positions, c.neighbours, strict=True):
            np.testing.assert_allclose(c.shoot_m[nb], lone[i][None])
    with pytest.raises(ValueError, match="lattice spacing"):
        lattice_points(pos, 0.0)


def test_channel_phase_frequency_and_position_gradient(far_floor_scene):
    # line of sight: h = |h| exp(-j 2 pi f d / c) at every channel from one trace
    pose = np.array([[0.0, 0.0, 1.0, 0.0]])
    tags = np.array([[2.0, 0.3, 1.0], [4.0, -1.0, 1.2]])
    d = np.linalg.norm(tags - pose[0, :3], axis=1)
    for f in (865.7e6, 867.5e6, 915e6):
        ls = trace_links(far_floor_scene, pose, tags, max_depth=0, samples_per_src=100, channel_hz=f)
        expected = np.exp(-2j * np.pi * f * d / C0)
        # float32 delays: 1e-7 relative of d ~ 1e-3 rad at 4 m
        np.testing.assert_allclose(np.angle(ls.h[0] * np.conj(expected)), 0.0, atol=1e-3)
        # the amplitude stays the traced carrier's (documented in link_channels): Friis
        # at the channel differs by 20 log10(f / F), 0.03 dB across the ETSI band
        base = trace_links(far_floor_scene, pose, tags, max_depth=0, samples_per_src=100)
        np.testing.assert_allclose(ls.gain_db[0], base.gain_db[0], atol=1e-9)
        assert abs(free_space_gain_db(d, 867.5e6) - free_space_gain_db(d, F)).max() < 0.03
    # dh/dpos against a central difference of h (1 mm steps); the gradient keeps only the
    # phase term, the 1/d amplitude term is smaller by 1 / (k d) ~ 2 %
    ls = trace_links(far_floor_scene, pose, tags, max_depth=0, samples_per_src=100, channel_gradient=True)
    eps = 1e-3
    for ax in range(3):
        step = np.zeros(4)
        step[ax] = eps
        hp = trace_links(far_floor_scene, pose + step, tags, max_depth=0, samples_per_src=100).h[0]
        hm = trace_links(far_floor_scene, pose - step, tags, max_depth=0, samples_per_src=100).h[0]
        fd = (hp - hm) / (2 * eps)
        scale = np.abs(ls.h[0]) * 2 * np.pi * F / C0
        np.testing.assert_allclose(ls.dh_dpos[0, :, ax], fd, atol=0.05 * scale.max())


def test_link_channels_rejects_nothing_silently(corridor_scene):
    # a link whose tag was never traced from its path set is an internal error, not a 0
    rts = load_sionna_scene(corridor_scene, F)
    tags = corridor_scene.tags.positions_m[:2]
    sp = _trace_chunk(rts, np.array([[3.0, 1.2, 0.7]]), tags[:1], 1, 1000, 1)
    with pytest.raises(RuntimeError, match="missing"):
        link_channels(sp, np.array([0]), np.array([1]), np.zeros((1, 6)), tags, F, "iso", "V", "iso",
                      tag_dipole_axes(None, 2))


def test_copies_are_found_by_tolerance_not_by_grid():
    """Float32 copies of one path straddling a 0.1 mm grid line are one path; a distinct
    path with the same length and departure but another arrival direction is kept."""
    from propagation.sionna_paths import path_copies as _copies

    k = np.array([0.6, 0.8, 0.0])
    t = np.eye(2, dtype=complex)[None].repeat(4, axis=0)
    length = np.array([12.34995, 12.34995 + 2e-6, 12.34995 + 3e-6, 12.34995 + 4e-6])  # grid line at 12.35
    k_rx = np.array([k, k + 1e-7, [0.0, 0.6, 0.8], k])
    src = np.zeros(4, np.int64)
    tg = np.array([0, 0, 0, 1])  # the last row is another tag: never a copy
    drop = _copies(src, tg, length, np.tile(k, (4, 1)), k_rx, t)
    np.testing.assert_array_equal(drop, [False, True, False, False])
