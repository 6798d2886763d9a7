"""Image-method completion over large planes: closed forms, a 1e6-ray reference, merging."""

import numpy as np
import pytest

from propagation import TraceOptions, two_ray_gain_db
from propagation.completion import PlaneLookup, complete_specular, large_planes, merge_paths
from propagation.constants import SPEED_OF_LIGHT
from propagation.pathcache import SourcePaths
from propagation.pathsolve import _trace_chunk
from propagation.sionna_scene import load_sionna_scene
from scenes import material
from tests.helpers.scenes import corridor_links

pytestmark = pytest.mark.filterwarnings("ignore::scenes.materials.FrequencyRangeWarning")

F = 865e6
C0 = SPEED_OF_LIGHT


def _gain_db(sp: SourcePaths) -> np.ndarray:
    """Per tag |sum a[V, V] exp(-j 2 pi f tau)|^2 in dB (iso V at both ends)."""
    h = sp.transfer[:, 0, 0] * np.exp(-2j * np.pi * F * sp.tau_s)
    tag = np.repeat(np.arange(len(sp.offsets) - 1), np.diff(sp.offsets))
    return 10 * np.log10(np.abs(np.bincount(tag, h.real, len(sp.offsets) - 1)
                                + 1j * np.bincount(tag, h.imag, len(sp.offsets) - 1)) ** 2)


def test_a_plane_of_small_pieces_is_not_large():
    # A row of 0.08 m x 2.2 m posts (0.18 m^2 faces, coplanar: 12 of them, 2.1 m^2 in
    # all, like a shelving rack's uprights) is not a large plane however long the row;
    # a 2 m x 2.2 m panel beside them is. Fails if planes are kept by their total area.
    import trimesh

    from scenes import Scene
    from tests.helpers.scenes import _tags, box
    posts = trimesh.util.concatenate([box([x, 0.0, 0.0], [x + 0.08, 0.08, 2.2]) for x in np.arange(12) * 1.0])
    panel = box([0.0, 3.0, 0.0], [2.0, 3.05, 2.2])
    rts = load_sionna_scene(Scene("posts", {"metal": posts, "concrete": panel}, _tags([[5.0, 1.5, 1.0]])), F)
    pl = large_planes(rts, 1.0)
    # the panel's two 4.4 m^2 faces only (its 0.11 m^2 edges are small too)
    assert sorted(np.round(pl.area_m2, 2).tolist()) == [4.4, 4.4]
    np.testing.assert_allclose(np.abs(pl.normal[:, 1]), 1.0)
    assert len(large_planes(rts, 0.1)) > 2  # the posts' faces come back below their size


def _duplicates(sp: SourcePaths) -> int:
    """Pairs of paths of one tag with lengths within 0.1 mm and departures within 1e-4."""
    n = 0
    for t in range(len(sp.offsets) - 1):
        s = slice(sp.offsets[t], sp.offsets[t + 1])
        d_len = np.abs(sp.tau_s[s, None] - sp.tau_s[None, s]) * C0
        d_dir = np.abs(sp.k_tx[s, None] - sp.k_tx[None, s]).max(axis=2)
        n += int(np.triu((d_len <= 1e-4) & (d_dir <= 1e-4), 1).sum())
    return n


def test_large_planes_of_a_slab(floor_scene):
    rts = load_sionna_scene(floor_scene, F)
    pl = large_planes(rts)
    # a box has 6 faces of 2 triangles each: top/bottom 70 x 60 m, sides 70 x 0.2 and 60 x 0.2 m
    assert len(pl) == 6
    np.testing.assert_allclose(np.sort(pl.area_m2), [12, 12, 14, 14, 4200, 4200], rtol=1e-6)
    top = np.flatnonzero(np.isclose(np.abs(pl.normal[:, 2]), 1) & np.isclose(np.abs(pl.offset_m), 0))
    assert len(top) == 1
    assert len(large_planes(rts, min_area_m2=100.0)) == 2
    # max_planes keeps the largest: the two 70 x 60 m faces, then the 70 x 0.2 m sides
    top3 = large_planes(rts, max_planes=3)
    np.testing.assert_allclose(top3.area_m2, [4200, 4200, 14], rtol=1e-6)
    np.testing.assert_allclose(top3.offset_m, pl.offset_m[:3])


def test_floor_reflection_is_exact_and_two_ray(floor_scene):
    rts = load_sionna_scene(floor_scene, F)
    eps, sigma = material("concrete", F)
    d = np.linspace(2.0, 12.0, 21)
    h_r = 1.0
    heights = np.array([0.55, 0.62, 0.81])
    tags = np.stack([d, 0 * d, 0 * d + h_r], axis=1)
    src = np.column_stack([np.zeros(3), np.zeros(3), heights])
    refl = complete_specular(rts, src, tags, max_order=1)
    both = complete_specular(rts, src, tags, max_order=1, los=True)
    for k, h_t in enumerate(heights):
        # exactly one reflection per link: the slab's top face (its sides and bottom are
        # either unreachable or outside their bounding boxes)
        np.testing.assert_array_equal(np.diff(refl[k].offsets), 1)
        image = np.hypot(d, h_t + h_r)  # distance from the source's image below z = 0
        # float32 vertices and lengths in Sionna: ~1e-7 relative per operation, 1e-6 bounds
        # a path of two segments
        np.testing.assert_allclose(refl[k].tau_s, image / C0, rtol=1e-6)
        # the departure points at the reflection point (d h_t / (h_t + h_r), 0, 0)
        k_tx = np.column_stack([d * h_t / (h_t + h_r), 0 * d, 0 * d - h_t])
        # Sionna finds the reflection point by a float32 ray intersection (a few um off at
        # these ranges: 4e-6 measured), 1e-5 per component bounds the direction error
        np.testing.assert_allclose(refl[k].k_tx, k_tx / np.linalg.norm(k_tx, axis=1, keepdims=True),
                                   atol=1e-5)
        np.testing.assert_array_equal(np.diff(both[k].offsets), 2)
        ref = two_ray_gain_db(d, h_t, h_r, F, eps, sigma, "V")
        # Sionna's 0.2 m slab vs the closed form's half-space: 0.28 dB measured
        # (docs/physics.md); 0.5 dB as in test_pooled, away from the deep nulls where the
        # slab moves the null
        ok = ref > ref.max() - 15
        np.testing.assert_allclose(_gain_db(both[k])[ok], ref[ok], atol=0.5)


def test_corridor_completion_contains_the_reference_and_merges_without_duplicates(corridor_scene):
    import sionna.rt as rt

    from propagation.sionna_scene import clear_devices, place_devices

    rts = load_sionna_scene(corridor_scene, F)
    tags = corridor_scene.tags.positions_m[[1, 5, 10, 14]]
    src = np.array([[3.0, 1.2, 0.7], [12.5, 0.6, 1.4], [20.0, 1.9, 2.2]])
    comp = complete_specular(rts, src, tags, max_order=2)
    # reference: Sionna's PathSolver with 1e6 rays, pure reflections up to order 2. Without
    # refraction every hit reflects (with it, the solver samples reflection or refraction
    # at each hit and misses weak reflections); a pure-reflection path is valid or not
    # whatever that flag
    place_devices(rts, src, tags)
    paths = rt.PathSolver()(rts, max_depth=2, samples_per_src=1_000_000, max_num_paths_per_src=20_000,
                            synthetic_array=True, los=False, specular_reflection=True,
                            diffuse_reflection=False, refraction=False, diffraction=False, seed=3)
    valid = paths.valid.numpy()  # (rx, tx, P)
    tau = paths.tau.numpy().astype(np.float64)
    a_re, a_im = (x.numpy() for x in paths.a)  # (rx, 2, tx, 2, P)
    clear_devices(rts)
    n_ref = 0
    for s in range(len(src)):
        for t in range(len(tags)):
            ref = np.flatnonzero(valid[t, s])
            ours = slice(comp[s].offsets[t], comp[s].offsets[t + 1])
            n_ref += len(ref)
            # every reference path is in the completion: same delay to float32 precision
            # (1e-6 relative; distinct paths here differ by > 1 cm, i.e. > 1e-3 relative)
            gap = np.abs(tau[t, s, ref, None] / comp[s].tau_s[None, ours] - 1)
            assert np.all(gap.min(axis=1) < 1e-6), (s, t)
            # and with the same field (same kernels, same material): float32 rounding
            match = np.argmin(gap, axis=1) + comp[s].offsets[t]
            np.testing.assert_allclose(np.abs(comp[s].transfer[match, 0, 0]),
                                       np.abs(a_re[t, 0, s, 0, ref] + 1j * a_im[t, 0, s, 0, ref]),
                                       rtol=1e-3)
    assert n_ref > 200  # 287: order-1/2 reflections on all 12 links
    # and the completion has nothing the reference lacks (287 = 287 measured; the
    # reference is a random sample, 2 paths of slack for its own misses)
    assert sum(len(c.tau_s) for c in comp) <= n_ref + 2
    # merged into a 3e4-ray depth-5 PathSolver trace: nothing counted twice
    trace = _trace_chunk(rts, src, tags, 5, 30_000, 7)
    for s in range(len(src)):
        merged = merge_paths(trace[s], comp[s])
        # The trace itself holds pairs of distinct paths with equal length and departure
        # (a bounce inside one wall slab then a reflection off the opposite wall, and the
        # reverse): merging keeps them and adds no pair of its own
        assert _duplicates(merged) == _duplicates(trace[s])
        np.testing.assert_array_equal(merged.tag_positions_m, trace[s].tag_positions_m)
        added = len(merged.tau_s) - len(trace[s].tau_s)
        assert 0 <= added <= len(comp[s].tau_s)
        # every trace path is kept, unchanged
        for t in range(len(tags)):
            mine = merged.tau_s[merged.offsets[t]:merged.offsets[t + 1]]
            theirs = trace[s].tau_s[trace[s].offsets[t]:trace[s].offsets[t + 1]]
            assert np.isin(theirs, mine).all()
        # merging is idempotent: the completion's paths are all already there
        assert len(merge_paths(merged, comp[s]).tau_s) == len(merged.tau_s)


def test_merge_paths_tolerates_float32_noise_not_distinct_paths():
    src = np.zeros(3)
    tags = np.array([[1.0, 0, 0], [2.0, 0, 0]])
    k = np.array([[1.0, 0, 0], [0, 1.0, 0], [0, 0, 1.0]])
    tau = np.array([10.0, 10.0, 12.0]) / C0
    a = SourcePaths(src, tags[:1], np.array([0, 3]), np.ones((3, 2, 2), complex), tau, k, k)
    # a's two 10 m paths again, 0.06 mm longer (across a 0.1 mm rounding-grid line, which
    # a grid-based dedupe would split) and 1e-7 off in direction, a new 11 m path, and a
    # path to a second tag
    tau_b = np.array([10.00006, 10.00004, 11.0, 5.0]) / C0
    k_b = np.array([[1.0, 1e-7, 0], [0, 1.0, 0], [0, 0, -1.0], [1.0, 0, 0]])
    b = SourcePaths(src, tags[[1, 0]], np.array([0, 1, 4]), 2 * np.ones((4, 2, 2), complex),
                    np.append(tau_b[3], tau_b[:3]), np.vstack([k_b[3], k_b[:3]]), np.vstack([k_b[3], k_b[:3]]))
    m = merge_paths(a, b)
    np.testing.assert_array_equal(m.tag_positions_m, tags)
    np.testing.assert_array_equal(m.offsets, [0, 4, 5])
    # a's copies kept (transfer 1), b's new path (transfer 2) added, sorted by delay;
    # paths of a are never merged with each other
    np.testing.assert_allclose(m.tau_s[:4] * C0, [10.0, 10.0, 11.0, 12.0])
    np.testing.assert_allclose(m.transfer[:4, 0, 0], [1, 1, 2, 1])
    twice = SourcePaths(src, tags[:1], np.array([0, 2]), np.ones((2, 2, 2), complex), tau[[0, 0]],
                        k[[0, 0]], k[[0, 0]])
    assert len(merge_paths(twice, a).tau_s) == 4
    with pytest.raises(ValueError, match="same antenna position"):
        merge_paths(a, SourcePaths.empty(np.ones(3)))


def test_trace_links_with_completion_adds_paths_and_keeps_its_own_cache(corridor_scene, tmp_path):
    """TraceOptions(completion_order=2): every path of the plain trace is kept, the missed
    low-order reflections are added, and the completed traces live under their own cache
    key (a plain trace must never be served a completed one, nor the reverse)."""
    from propagation import trace_links

    poses = np.array([[3.0, 1.1, 0.8, 0.0], [5.0, 1.3, 1.0, 0.5]])
    tags = np.array([[8.0, 0.3, 1.0], [2.0, 2.0, 1.5], [6.5, 1.0, 0.4]])
    plain_opts = TraceOptions(samples_per_src=3000, max_depth=3, seed=3, completion_order=0)
    plain = trace_links(corridor_scene, poses, tags, plain_opts, cache_dir=tmp_path)
    done = trace_links(corridor_scene, poses, tags, plain_opts.replace(completion_order=2), cache_dir=tmp_path)
    assert np.all(done.n_paths >= plain.n_paths)
    assert done.n_paths.sum() > plain.n_paths.sum()  # 3000 rays miss some order-2 reflections
    assert done.n_traced_sources == 2  # not served from the plain trace's cache entry
    again = trace_links(corridor_scene, poses, tags, plain_opts.replace(completion_order=2), cache_dir=tmp_path)
    assert again.n_traced_sources == 0
    np.testing.assert_array_equal(again.gain_db, done.gain_db)
    with pytest.raises(ValueError, match="completion_order"):
        plain_opts.replace(completion_order=4)


def test_completed_cache_never_holds_an_uncompleted_link(corridor_scene, tmp_path):
    """Positions needing disjoint tags share a solver call (each shot against the union of
    its tags): each keeps and caches its own links only, completed, so a later call
    needing the other pairs traces them and is served what a fresh completed trace gives.
    Fails if the cache holds the union's links (uncompleted, or completed for every
    position: the candidates of a chunk's union, ~4x a warehouse's own links)."""
    from propagation import trace_links
    from propagation.pathcache import PathCache

    poses = np.array([[3.0, 1.1, 0.8, 0.0], [3.4, 1.2, 0.9, 0.3]])
    tags = np.array([[8.0, 0.3, 1.0], [2.0, 2.0, 1.5]])
    opts = TraceOptions(samples_per_src=2000, shared_samples_per_src=2000, max_depth=3, seed=5,
                        completion_order=2)
    trace_links(corridor_scene, poses, tags, opts, pairs=np.eye(2, dtype=bool), cache_dir=tmp_path)
    held = [sp for d in tmp_path.iterdir() if d.is_dir() for sp in PathCache(d).load(poses[:, :3])]
    assert [len(sp.tag_positions_m) for sp in held] == [1, 1]  # each its own tag
    np.testing.assert_array_equal(np.concatenate([sp.tag_positions_m for sp in held]), tags)
    cached = trace_links(corridor_scene, poses, tags, opts, cache_dir=tmp_path)
    assert cached.n_traced_sources == 2  # the cross pairs traced now, the others cached ...
    fresh = trace_links(corridor_scene, poses, tags, opts, cache_dir=tmp_path / "fresh")
    # ... and hold the completed reflections: same path count; gains agree except for
    # the few high-order paths two samplings of 2000 rays find differently
    np.testing.assert_array_less(np.abs(cached.n_paths - fresh.n_paths), 0.2 * fresh.n_paths + 3)
    ok = trace_links(corridor_scene, poses, tags, opts.replace(max_depth=0),
                     cache_dir=tmp_path / "d0")  # completion order capped by max_depth
    assert np.all(ok.n_paths <= 1)


def _pretest_reference(planes, src, tgt, link_src, link_tgt, chains):
    """The pre-test pair by pair in float64: backtrack from the target through the chain's
    planes, each segment crossing its plane inside the plane's box (+1 mm slack), in a
    covered cell of the plane's raster.

    Returns ``{(link, chain): (kept, margin_m)}``, the margin being the smallest distance,
    over the tests made, of a point or image to its plane or of a reflection point to its
    box's faces or its raster cell's edges: how far the pair is from the other answer."""
    out = {}
    for li, (s, t) in enumerate(zip(link_src, link_tgt, strict=True)):
        for ci, chain in enumerate(chains):
            imgs = [src[s]]
            for p in chain:  # images of the source through the chain's planes
                d = imgs[-1] @ planes.normal[p] - planes.offset_m[p]
                imgs.append(imgs[-1] - 2.0 * d * planes.normal[p])
            pt, ok, margin = tgt[t], True, np.inf
            for j in range(len(chain) - 1, -1, -1):
                p, im = chain[j], imgs[j + 1]
                a = pt @ planes.normal[p] - planes.offset_m[p]
                b = im @ planes.normal[p] - planes.offset_m[p]
                margin = min(margin, abs(a), abs(b))
                if not a * b < 0.0:
                    ok = False
                    break
                pt = pt + a / (a - b) * (im - pt)
                lo, hi = planes.lo_m[p] - 1e-3, planes.hi_m[p] + 1e-3
                margin = min(margin, np.abs(pt - lo).min(), np.abs(pt - hi).min())
                if np.any(pt < lo) or np.any(pt > hi):
                    ok = False
                    break
                if planes.cover is not None:  # the cell of the plane's raster holding pt
                    cv = planes.cover
                    u = (pt - cv.lo_m[p]) * cv.inv_cell_per_m[p]
                    on = cv.strides[p] > 0
                    idx = np.clip(np.floor(u), 0, cv.dims[p] - 1).astype(np.int64)
                    frac = (u - np.floor(u))[on]
                    margin = min(margin, np.minimum(frac, 1.0 - frac).min() / cv.inv_cell_per_m[p])
                    if not cv.cells[cv.offset[p] + int((idx * cv.strides[p]).sum())]:
                        ok = False
                        break
            out[(li, ci)] = (ok, margin)
    return out


@pytest.mark.parametrize("punched", [False, True])
@pytest.mark.parametrize("shift_m", [0.0, 1_000_000.0])
def test_pretest_keeps_the_pairs_a_float64_backtrack_keeps(corridor_scene, shift_m, punched):
    # The dense float32 pre-test against a pair-by-pair float64 recomputation, also with
    # the whole scene 1,000 km from the origin (float32 rounds there to 6 cm, far above
    # the 1 mm slack: the pre-test must centre its coordinates; fails if it does not).
    # The answers may differ only for a pair within 1e-4 m of the other answer (a plane,
    # a box face or a raster cell's edge): float32
    # rounding of centred coordinates ~20 m across is ~1e-6 m, so 1e-4 m leaves room for
    # the few operations in between and is still 10x below the slack.
    import dataclasses

    from propagation.chain_pretest import _pretest
    from propagation.chain_pretest import chains as _chains

    rts = load_sionna_scene(corridor_scene, F)
    planes = large_planes(rts, 1.0)
    shift = np.array([shift_m, -shift_m, 0.0])
    rng = np.random.default_rng(5)
    # the corridor's planes fill their rasters: punched, half their cells at random are
    # not covered, so the reference's raster test and the sparse pre-test's drop pairs
    cells = rng.random(len(planes.cover.cells)) < 0.5 if punched else planes.cover.cells
    planes = dataclasses.replace(planes, offset_m=planes.offset_m + planes.normal @ shift,
                                 lo_m=planes.lo_m + shift, hi_m=planes.hi_m + shift,
                                 cover=dataclasses.replace(planes.cover, lo_m=planes.cover.lo_m + shift,
                                                           cells=cells))
    src, tgt, link_src, link_tgt = corridor_links(corridor_scene, rng, n_sources=6, tag_step=3, p_need=0.7)
    src, tgt = src + shift, tgt + shift
    n_kept = 0
    for order in (1, 2, 3):
        chains = _chains(len(planes), order)[:: 7 if order == 3 else 1]
        li, ci = _pretest(planes, src, tgt, link_src, link_tgt, chains)
        got = set(zip(li.tolist(), ci.tolist(), strict=True))
        want = _pretest_reference(planes, src, tgt, link_src, link_tgt, chains)
        assert got <= set(want)
        differ = [(pair, m) for pair, (kept, m) in want.items() if kept != (pair in got)]
        assert all(m < 1e-4 for _, m in differ), differ[:5]
        n_want = sum(kept for kept, _ in want.values())
        assert len(differ) <= 0.001 * n_want + 1, (len(differ), n_want)
        n_kept += n_want
    assert n_kept > 100  # the scene has reflections to keep (and most pairs are dropped)


def test_candidates_in_threads_are_the_blocks_one_after_the_other(corridor_scene, monkeypatch):
    # Blocks of the pre-test run side by side in threads: the candidates must be those of
    # one pre-test per order over all its chains, in that order (link-major within each
    # block, blocks in chain order). Small blocks make many of them, three threads run
    # them out of step; fails if the blocks are joined as they finish or a block is lost.
    from propagation import chain_pretest
    from propagation.chain_pretest import _pretest
    from propagation.chain_pretest import candidate_chains as _candidates
    from propagation.chain_pretest import chains as _chains

    rts = load_sionna_scene(corridor_scene, F)
    planes = large_planes(rts, 1.0)
    src, tgt, link_src, link_tgt = corridor_links(corridor_scene, np.random.default_rng(11))
    want_l, want_c = [], []
    for order in (1, 2, 3):
        chains = _chains(len(planes), order)
        step = max(1, 4096 // len(link_src))
        for c0 in range(0, len(chains), step):  # the blocks one after the other
            li, ci = _pretest(planes, src, tgt, link_src, link_tgt, chains[c0:c0 + step])
            want_l.append(li)
            want_c.append(np.pad(chains[c0:c0 + step][ci], ((0, 0), (0, 3 - order)), constant_values=-1))
    monkeypatch.setattr(chain_pretest, "_BLOCK", 4096)
    monkeypatch.setattr(chain_pretest, "_pretest_threads", lambda n: min(n, 3))
    li, ch = _candidates(planes, src, tgt, link_src, link_tgt, 1, 3)
    assert len(want_l) > 10 and len(li) > 100  # many blocks, and candidates to order
    np.testing.assert_array_equal(li, np.concatenate(want_l))
    np.testing.assert_array_equal(ch, np.concatenate(want_c))
    # one thread, whole blocks: the same again
    monkeypatch.setattr(chain_pretest, "_pretest_threads", lambda n: 1)
    li1, ch1 = _candidates(planes, src, tgt, link_src, link_tgt, 1, 3)
    np.testing.assert_array_equal(li1, li)
    np.testing.assert_array_equal(ch1, ch)


def test_planes_of_table_and_search_agree(monkeypatch):
    # planes_of looks pointers up in a dense table when they are small (Dr.Jit registry
    # ids) and searches the sorted pointers otherwise: both must name the same planes,
    # -1 for unknown pointers, negative or out-of-range primitives
    rng = np.random.default_rng(5)
    invalid_shape = 0xFFFFFFFF  # Sionna's INVALID_SHAPE, as the buffers hold it
    for dense in (1 << 20, 0):
        monkeypatch.setattr("propagation.completion._DENSE_POINTERS", dense)
        for ptr in ([2, 3, 7, 11], [0, 3, 7, 11]):  # pointer 0 a shape of the lookup or not
            ptr = np.array(ptr, np.int64)
            offset = np.array([0, 4, 4, 9, 12], np.int64)  # the second shape: no triangles
            lookup = PlaneLookup(ptr, offset, rng.integers(-1, 5, size=12))
            shapes = rng.integers(-2, 14, size=(400, 3))
            shapes[::17, 1] = invalid_shape
            prims = rng.integers(-2, 7, size=(400, 3))
            expect = np.full(shapes.shape, -1, np.int64)
            for (i, j), s in np.ndenumerate(shapes):
                k = np.flatnonzero(ptr == s)
                if len(k) and 0 <= prims[i, j] < offset[k[0] + 1] - offset[k[0]]:
                    expect[i, j] = lookup.plane[offset[k[0]] + prims[i, j]]
            got = lookup.planes_of(shapes, prims)
            assert got.dtype == np.int64
            np.testing.assert_array_equal(got, expect)
        nothing = PlaneLookup(np.zeros(0, np.int64), np.zeros(1, np.int64), np.zeros(0, np.int64))
        assert nothing.planes_of(shapes[:2], prims[:2]).tolist() == [[-1] * 3] * 2


def test_completion_in_deeper_buffers_gives_the_same_paths(corridor_scene):
    # buffer_depth pads the chains with "no interaction" so that the image method and
    # field kernels are the tracer's own (Sionna bakes the depth into them): the paths
    # must be the same, bit for bit (the padded steps do nothing); a depth below the
    # order cannot hold the chains
    rts = load_sionna_scene(corridor_scene, F)
    planes = large_planes(rts, 1.0)
    pos = np.array([[3.0, 1.2, 0.7], [4.5, 1.0, 0.9]])
    tags = corridor_scene.tags.positions_m[:4]
    a = complete_specular(rts, pos, tags, 2, planes)
    b = complete_specular(rts, pos, tags, 2, planes, buffer_depth=5)
    assert sum(len(x.tau_s) for x in a) > 0
    for x, y in zip(a, b, strict=True):
        np.testing.assert_array_equal(x.tau_s, y.tau_s)
        np.testing.assert_array_equal(x.transfer, y.transfer)
        np.testing.assert_array_equal(x.k_tx, y.k_tx)
        np.testing.assert_array_equal(x.k_rx, y.k_rx)
    with pytest.raises(ValueError, match="buffer_depth"):
        complete_specular(rts, pos, tags, 2, planes, buffer_depth=1)
