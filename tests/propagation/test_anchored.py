"""Gains carried from anchor paths (propagation.anchored) against closed forms."""

import numpy as np
import pytest

from propagation import two_ray_gain_db
from propagation.anchored import anchor_groups, anchored_gains_db, specular_model_paths
from scenes import material

F = 865e6
ISO = {"reader_pattern": "iso", "reader_polarization": "V", "tag_pattern": "iso"}


def _two_ray_setup():
    d = np.linspace(2.0, 10.0, 17)
    anchors = np.stack([d, 0 * d, 0 * d + 1.0], axis=1)
    src = np.array([[0.0, 0.0, 0.62]])
    return d, anchors, src


@pytest.mark.parametrize("shift", [(0.2, 0.0, 0.0), (-0.15, 0.1, 0.0), (0.0, 0.0, 0.12)])
def test_carried_floor_links_are_two_ray_at_the_target(floor_scene, shift):
    d, anchors, src = _two_ray_setup()
    paths = specular_model_paths(floor_scene, src, anchors, np.ones((1, len(d)), bool), F, 1)
    targets = anchors + np.asarray(shift)
    n = len(d)
    pose = np.zeros((n, 6))
    carried = anchored_gains_db(paths, np.zeros(n, int), anchors, np.arange(n), targets,
                                np.tile([1.0, 0.0, 0.0], (n, 1)), pose, F, **ISO)
    # the same model solved at the targets themselves: the carrying keeps the anchor's
    # Fresnel coefficient, whose grazing angle moves by up to 2.5 degrees here (0.27 dB
    # measured at most, near grazing where the coefficient changes fastest) -> 0.4 dB
    direct_paths = specular_model_paths(floor_scene, src, targets, np.ones((1, n), bool), F, 1)
    direct = anchored_gains_db(direct_paths, np.zeros(n, int), targets, np.arange(n), targets,
                               np.tile([1.0, 0.0, 0.0], (n, 1)), pose, F, **ISO)
    eps, sigma = material("concrete", F)
    horizontal = np.hypot(targets[:, 0], targets[:, 1])
    ref = two_ray_gain_db(horizontal, 0.62, targets[:, 2], F, eps, sigma, "V")
    ok = ref > ref.max() - 15  # away from the deep nulls, where 0.1 dB of level is any dB
    np.testing.assert_allclose(carried[ok], direct[ok], atol=0.4)
    # Sionna's 0.2 m slab vs the closed form's half-space: 0.28 dB measured, 0.5 dB as in
    # test_completion, plus the carrying's 0.4 dB above
    np.testing.assert_allclose(carried[ok], ref[ok], atol=0.9)
    # and the carrying matters: the anchor's own gains are farther from the target's
    at_anchor = anchored_gains_db(paths, np.zeros(n, int), anchors, np.arange(n), anchors,
                                  np.tile([1.0, 0.0, 0.0], (n, 1)), pose, F, **ISO)
    assert np.mean(np.abs(carried - direct)[ok]) < 0.5 * np.mean(np.abs(at_anchor - direct)[ok])


def test_local_mean_is_the_power_sum(floor_scene):
    d, anchors, src = _two_ray_setup()
    n = len(d)
    paths = specular_model_paths(floor_scene, src, anchors, np.ones((1, n), bool), F, 1)
    args = (paths, np.zeros(n, int), anchors, np.arange(n), anchors, np.tile([1.0, 0, 0], (n, 1)),
            np.zeros((n, 6)), F)
    mean = anchored_gains_db(*args, incoherent=True, **ISO)
    coherent = anchored_gains_db(*args, **ISO)
    eps, sigma = material("concrete", F)
    ref = two_ray_gain_db(d, 0.62, 1.0, F, eps, sigma, "V")
    ok = ref > ref.max() - 15
    np.testing.assert_allclose(coherent[ok], ref[ok], atol=0.5)
    # |a + b|^2 swings about |a|^2 + |b|^2: the local mean lies between the fading
    # extremes (|a| - |b|)^2 and (|a| + |b|)^2 and is smooth in d (no sign changes of
    # its slope beyond the direct path's 1/d^2 fall)
    assert np.all(np.diff(mean) < 0)
    assert np.any(coherent > mean + 1.0) and np.any(coherent < mean - 1.0)


def test_specular_model_paths_are_cached(floor_scene, tmp_path, monkeypatch):
    import propagation.anchored

    d, anchors, src = _two_ray_setup()
    need = np.ones((1, len(d)), bool)
    first = specular_model_paths(floor_scene, src, anchors, need, F, 1, cache_dir=tmp_path)
    assert any(tmp_path.rglob("*.npz"))

    def no_solver(*args, **kwargs):
        raise AssertionError("the cached specular model was recomputed")

    # the name anchored calls (imported there at module level)
    monkeypatch.setattr(propagation.anchored, "complete_specular", no_solver)
    again = specular_model_paths(floor_scene, src, anchors, need, F, 1, cache_dir=tmp_path)
    np.testing.assert_array_equal(first[0].tau_s, again[0].tau_s)
    np.testing.assert_array_equal(first[0].transfer, again[0].transfer)
    with pytest.raises(ValueError, match="need must have shape"):
        specular_model_paths(floor_scene, src, anchors, need[:, :3], F, 1)


def test_anchor_groups_cells_never_mix_orientations():
    y = np.arange(0.0, 2.0, 0.05)
    wall_a = np.stack([0 * y, y, 0 * y + 1.0], 1)
    wall_b = np.stack([0 * y + 0.01, y, 0 * y + 1.0], 1)  # the other face, 1 cm away
    pos = np.vstack([wall_a, wall_b])
    nrm = np.vstack([np.tile([1.0, 0, 0], (len(y), 1)), np.tile([-1.0, 0, 0], (len(y), 1))])
    anchors, member = anchor_groups(pos, nrm, 0.4)
    assert np.all(nrm[anchors[member]] == nrm)  # every point's anchor faces its way
    assert np.all(np.linalg.norm(pos[anchors[member]] - pos, axis=1) <= 0.4 * np.sqrt(3))
    assert len(anchors) == 2 * 5  # 2 m of wall in 0.4 m cells, per face
    with pytest.raises(ValueError, match="spacing_m"):
        anchor_groups(pos, nrm, 0.0)
    empty = anchor_groups(np.zeros((0, 3)), np.zeros((0, 3)), 0.4)
    assert len(empty[0]) == 0 and len(empty[1]) == 0


def test_global_oracle_finds_a_wall_tag_without_seeing_it(corridor_scene, tmp_path):
    """A tag on the corridor wall, read along a straight pass with reads drawn from the
    oracle's own likelihood: the coarse-to-fine search lands within a window of it.

    Both searches share a path cache: the blind one reads the paths the first traced (the
    truth's own paths, traced only for ``truth_preferred``, are never asked for by it)."""
    from pipeline.localisation import Observations, OracleLikelihood
    from pipeline.localisation.global_oracle import OracleSearch, global_oracle
    from propagation import LinkBudget, TraceOptions, trace_links
    from scenes.tagsites import tag_sites

    sites = tag_sites(corridor_scene, spacing_m=0.1, z_range_m=(0.8, 1.2))
    true = sites.subset([int(np.argmin(np.linalg.norm(sites.positions_m - [6.0, 0.0, 1.0], axis=1)))])
    x = np.linspace(2.0, 10.0, 33)
    yaw = np.where(np.arange(len(x)) % 2 == 0, -np.pi / 2, np.pi / 2)  # toward either wall
    poses = np.column_stack([x, 0 * x + 1.2, 0 * x + 0.7, yaw, 0 * x, 0 * x])
    trace = TraceOptions(method="direct", max_depth=2, samples_per_src=3000)
    gains = trace_links(corridor_scene, poses, true.positions_m, trace, tag_normals=true.normals,
                        frequency_hz=F).gain_db  # (S, 1)
    oracle = OracleLikelihood(LinkBudget(), miss_probability=0.0, rssi_noise_db=1.0)
    read, rssi = oracle.sample(gains.T, np.random.default_rng(3))
    assert 5 <= read.sum() < len(x)  # informative: some reads, some misses
    obs = Observations(("t",), np.arange(len(x), dtype=float), yaw < 0, poses, read, rssi,
                       np.ones_like(read))
    res = global_oracle(obs, poses, sites, corridor_scene, oracle, search=OracleSearch(),
                        frequency_hz=F, trace=trace, cache_dir=tmp_path,
                        pattern_kw={"reader_pattern": "tr38901", "reader_polarization": "V",
                                    "tag_pattern": "hw_dipole"},
                        truth_m=true.positions_m, truth_normals=true.normals)
    err = np.linalg.norm(res.posteriors.map_m[0] - true.positions_m[0])
    # the reads' own ambiguity along the wall is a few wavelengths at most on a 8 m pass;
    # the window (0.4 m) bounds what a search that found the right basin can miss by
    assert err <= 0.4, f"oracle estimate {res.posteriors.map_m[0]} vs truth {true.positions_m[0]}"
    assert res.n_traced_links > 0 and res.n_model_links > res.n_traced_links
    assert not res.truth_preferred[0]  # the estimate scores at least as well as the truth
    # the search never looks at the truth: without it (or with a wrong one) the same answer
    blind = global_oracle(obs, poses, sites, corridor_scene, oracle, search=OracleSearch(),
                          frequency_hz=F, trace=trace, cache_dir=tmp_path,
                          pattern_kw={"reader_pattern": "tr38901", "reader_polarization": "V",
                                      "tag_pattern": "hw_dipole"})
    assert blind.truth_preferred is None
    np.testing.assert_array_equal(blind.posteriors.map_m, res.posteriors.map_m)
    # the same paths (from the cache), summed in another order with float32
    # cos/sin (window_gains_db: ~1e-6 dB per gain): 4e-6 in the log posterior measured
    np.testing.assert_allclose(blind.posteriors.log_posterior, res.posteriors.log_posterior,
                               atol=1e-4)


@pytest.mark.parametrize("shift", [(0.2, 0.0, 0.0), (0.0, 0.15, 0.1)])
def test_moved_antenna_local_mean_is_the_image_methods(floor_scene, shift):
    """The antenna-side twin: paths traced from one antenna position, carried to a moved
    antenna, against the image-method solution from the moved antenna itself."""
    from propagation.anchored import moved_antenna_local_mean_db

    d, tags, src = _two_ray_setup()
    n = len(d)
    moved = src[0] + np.asarray(shift)
    pose = np.tile(np.r_[moved, 0.3, 0.1, 0.0], (n, 1))  # yaw and tilt: the pattern moves too
    paths = specular_model_paths(floor_scene, src, tags, np.ones((1, n), bool), F, 1)
    normals = np.tile([1.0, 0.0, 0.0], (n, 1))
    pat = {"reader_pattern": "tr38901", "reader_polarization": "V", "tag_pattern": "hw_dipole"}
    carried = moved_antenna_local_mean_db(paths, np.zeros(n, int), tags, np.arange(n), normals,
                                          pose, **pat)
    direct_paths = specular_model_paths(floor_scene, moved[None], tags, np.ones((1, n), bool), F, 1)
    direct = anchored_gains_db(direct_paths, np.zeros(n, int), tags, np.arange(n), tags, normals,
                               pose, F, incoherent=True, **pat)
    # the traced Fresnel coefficient at an incidence angle up to ~2.5 degrees off, as in
    # the tag-side test (0.4 dB there); the reader pattern is evaluated exactly
    np.testing.assert_allclose(carried, direct, atol=0.4)
    unmoved = moved_antenna_local_mean_db(paths, np.zeros(n, int), tags, np.arange(n), normals,
                                          np.tile(np.r_[src[0], 0.3, 0.1, 0.0], (n, 1)), **pat)
    assert np.mean(np.abs(carried - direct)) < 0.5 * np.mean(np.abs(unmoved - direct))


def test_chunked_evaluation_is_identical(floor_scene, monkeypatch):
    """Large link sets are evaluated in chunks (bounded memory): the same gains, exactly."""
    import propagation.anchored as anchored

    d = np.linspace(2.0, 10.0, 40)
    tags = np.stack([d, 0 * d, 0 * d + 1.0], 1)
    src = np.array([[0.0, 0.0, 0.62], [0.0, 1.0, 0.7]])
    paths = specular_model_paths(floor_scene, src, tags, np.ones((2, 40), bool), F, 1)
    rng = np.random.default_rng(0)
    n = 3000
    ai = rng.integers(0, 40, n)
    args = (paths, rng.integers(0, 2, n), tags, ai, tags[ai] + rng.normal(0, 0.1, (n, 3)),
            np.tile([1.0, 0, 0], (n, 1)), np.tile([0, 0, 0, 0.3, 0, 0.0], (n, 1)), F)
    pat = {"reader_pattern": "tr38901", "reader_polarization": "V", "tag_pattern": "hw_dipole"}
    whole = anchored_gains_db(*args, **pat)
    monkeypatch.setattr(anchored, "_LINKS_PER_CALL", 777)
    np.testing.assert_array_equal(anchored_gains_db(*args, **pat), whole)


def test_window_gains_are_the_per_link_gains(corridor_scene, monkeypatch):
    """The dense window form (one anchor, many targets) gives what the per-link form
    gives on every (pose, target) pair, also when split into blocks of targets."""
    import propagation.anchored as anchored
    from propagation.anchored import window_gains_db

    anchor = np.array([6.0, 0.0, 1.0])  # on the corridor's wall (normal +y)
    src = np.array([[3.0, 1.2, 0.7], [6.5, 1.0, 0.6], [9.0, 1.5, 0.8]])
    paths = specular_model_paths(corridor_scene, src, anchor[None], np.ones((3, 1), bool), F, 2)
    rng = np.random.default_rng(1)
    targets = anchor + np.column_stack([rng.uniform(-0.4, 0.4, 50), 0 * np.ones(50),
                                        rng.uniform(-0.3, 0.3, 50)])
    pos_index = np.array([0, 1, 2, 1, 0])  # two poses share a position, turned differently
    poses = np.column_stack([src[pos_index], [-1.2, -1.6, -2.0, -1.0, -1.4],
                             np.full(5, 0.2), np.zeros(5)])
    normal = np.array([0.0, 1.0, 0.0])
    pat = {"reader_pattern": "tr38901", "reader_polarization": "V", "tag_pattern": "hw_dipole"}
    window = window_gains_db(paths, pos_index, poses, anchor, targets, normal, F, **pat)
    s, m = np.meshgrid(np.arange(5), np.arange(50), indexing="ij")
    per_link = anchored_gains_db(paths, pos_index[s.ravel()], anchor[None], np.zeros(s.size, int),
                                 targets[m.ravel()], np.tile(normal, (s.size, 1)),
                                 poses[s.ravel()], F, **pat).reshape(5, 50)
    assert np.all(np.isfinite(window)) and np.ptp(window) > 3.0  # a real, varying field
    # the same sums with float32 cos/sin of the float64-reduced phase (|h| relative error
    # ~1e-7, i.e. ~1e-6 dB; 1e-4 dB at worst in a benchmark of 750 000 pairs): 1e-3 dB
    np.testing.assert_allclose(window, per_link, atol=1e-3)
    # a pose whose position has no path to the anchor, between poses that have: -inf
    # there, the others unchanged (the segment sum skips it)
    from propagation.pathcache import SourcePaths

    blind = SourcePaths(np.array([6.0, 1.2, 0.7]), anchor[None], np.zeros(2, np.int64),
                        np.zeros((0, 2, 2), complex), np.zeros(0), np.zeros((0, 3)), np.zeros((0, 3)))
    with_blind = window_gains_db([*paths, blind], np.array([0, 3, 1, 2, 3, 1, 0]),
                                 poses[[0, 0, 1, 2, 2, 3, 4]], anchor, targets, normal, F, **pat)
    assert np.all(np.isneginf(with_blind[[1, 4]]))
    np.testing.assert_array_equal(with_blind[[0, 2, 3, 5, 6]], window)
    monkeypatch.setattr(anchored, "_PAIRS_PER_BLOCK", 37)  # ~1 target per block
    np.testing.assert_allclose(window_gains_db(paths, pos_index, poses, anchor, targets, normal, F,
                                               **pat), window, atol=1e-5)


def test_specular_model_in_bounded_calls_is_the_same(corridor_scene, monkeypatch):
    """The solver split into groups of positions, candidate blocks and line-of-sight
    groups (bounded memory) returns the very same paths."""
    import propagation.anchored as anchored
    import propagation.completion as completion

    src = np.array([[3.0, 1.2, 0.7], [6.5, 1.0, 0.6], [9.0, 1.5, 0.8], [4.0, 0.6, 1.1]])
    tags = np.array([[6.0, 0.0, 1.0], [5.0, 2.4, 0.9], [8.0, 0.0, 1.3]])
    need = np.array([[1, 1, 0], [1, 1, 1], [0, 1, 1], [1, 0, 1]], bool)
    whole = specular_model_paths(corridor_scene, src, tags, need, F, 2)
    monkeypatch.setattr(anchored, "_MODEL_LINKS_PER_CALL", 5)  # two positions per call
    # each position group's candidates come in two blocks (57 + 319 and 45 + 254): calls of
    # 64 hold the first block over into the second, split it, and leave a rest (12 solver
    # calls; 5 per call made 136 and cost 19 s)
    monkeypatch.setattr(completion, "_CANDIDATES_PER_CALL", 64)
    monkeypatch.setattr(completion, "_LOS_PAIRS_PER_CALL", 4)
    split = specular_model_paths(corridor_scene, src, tags, need, F, 2)
    assert sum(len(sp.tau_s) for sp in whole) > 4 * need.sum()  # reflections, not only LOS
    for a, b in zip(whole, split, strict=True):
        np.testing.assert_array_equal(a.offsets, b.offsets)
        np.testing.assert_allclose(a.tau_s, b.tau_s, rtol=1e-6)  # float32 solver
        np.testing.assert_allclose(a.transfer, b.transfer, rtol=1e-4, atol=1e-12)
        np.testing.assert_allclose(a.k_tx, b.k_tx, atol=1e-6)
        np.testing.assert_allclose(a.k_rx, b.k_rx, atol=1e-6)
