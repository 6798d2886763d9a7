"""Chain sharing between neighbouring antenna positions (propagation.shared)."""

import numpy as np
import pytest

from propagation import TraceOptions, trace_links, two_ray_gain_db
from propagation.constants import SPEED_OF_LIGHT
from propagation.pathsolve import _trace_chunk
from propagation.shared import (
    chain_ids,
    own_ray_levels,
    shared_rows,
    sharing_neighbours,
    trace_shared,
)
from propagation.sionna_paths import path_copies
from propagation.sionna_scene import load_sionna_scene
from scenes import material
from tests.helpers.kernels import launched_kernels
from tests.helpers.scenes import make_corridor

pytestmark = pytest.mark.filterwarnings("ignore::scenes.materials.FrequencyRangeWarning")

F = 865e6
C0 = SPEED_OF_LIGHT


def test_chain_ids_name_equal_rows_alike():
    rng = np.random.default_rng(3)
    rows = rng.integers(-1, 4, size=(60, 7))
    key = rows[rng.integers(0, 60, size=500)]
    ids = chain_ids(key)
    same_id = ids[:, None] == ids[None, :]
    same_row = np.all(key[:, None, :] == key[None, :, :], axis=2)
    np.testing.assert_array_equal(same_id, same_row)
    assert chain_ids(np.zeros((0, 3), np.int64)).shape == (0,)


def _row_hash(row) -> int:
    # chain_ids' hash of one row, in Python integers
    h, mask = 0, (1 << 64) - 1
    for v in row:
        h = ((h ^ (v & mask)) * 0x100000001B3) & mask
        h ^= h >> 29
    return h


def test_chain_ids_across_blocks_and_through_a_hash_collision(monkeypatch):
    # rows hashed in blocks (7 rows here) name equal rows alike across blocks
    monkeypatch.setattr("propagation.shared._HASH_BLOCK_ROWS", 7)
    rng = np.random.default_rng(4)
    key = rng.integers(-3, 3, size=(8, 4))[rng.integers(0, 8, size=50)]
    ids = chain_ids(key)
    np.testing.assert_array_equal(ids[:, None] == ids[None, :],
                                  np.all(key[:, None, :] == key[None, :, :], axis=2))
    # two different rows with one hash: (a, b) and (a2, b ^ g(a) ^ g(a2)), g the hash of
    # one column; they must get different ids (the exact row-wise fallback)
    mask = (1 << 64) - 1
    a, a2, b = 5, 9, 7
    b2 = b ^ _row_hash([a]) ^ _row_hash([a2])
    rows = [[a, b], [a2, b2], [a, b]]
    assert _row_hash(rows[0]) == _row_hash(rows[1])  # a real collision
    key = np.array([[x & mask for x in r] for r in rows], np.uint64).view(np.int64)
    ids = chain_ids(key)
    assert ids[0] == ids[2] != ids[1]


@pytest.mark.parametrize("dense_keys", [1 << 27, 0])  # a table of the keys, or a hash table
def test_shared_rows_gives_each_position_its_neighbours_new_valid_chains(dense_keys, monkeypatch):
    monkeypatch.setattr("propagation.shared._DENSE_KEYS", dense_keys)
    # rows: (source, chain id, valid at its source)
    src = np.array([0, 0, 1, 1, 1, 2, 2])
    chain = np.array([10, 11, 10, 12, 13, 14, 11])
    valid = np.array([True, False, True, True, False, True, True])
    rows, dest = shared_rows(src, chain, valid, [np.array([1]), np.array([0, 2]), np.array([1])])
    got = sorted(zip(dest.tolist(), chain[rows].tolist(), strict=True))
    # position 0 takes 12 from 1 (10 is its own, 13 is not valid at 1); position 1 takes
    # 14 and 11 from 2 (11 only once, though invalid at 0); position 2 takes 10 and 12
    assert got == [(0, 12), (1, 11), (1, 14), (2, 10), (2, 12)]
    # the rows themselves, by position, then neighbour as listed, then chain id
    assert (rows.tolist(), dest.tolist()) == ([3, 6, 5, 2, 3], [0, 1, 1, 2, 2])
    # a chain valid at two neighbours is solved once (0 takes 21 from 1 and 2); a
    # position without neighbours gets nothing, nor one whose neighbour's valid chains are
    # its own (2); an invalid row goes to nobody (3's 22); 3 takes 20 from 0;
    # no positions, no rows
    src = np.array([0, 1, 2, 3])
    chain = np.array([20, 21, 21, 22])
    valid = np.array([True, True, True, False])
    rows, dest = shared_rows(src, chain, valid, [np.array([1, 2, 3]), np.array([], np.int64),
                                                  np.array([1]), np.array([0])])
    assert sorted(zip(dest.tolist(), chain[rows].tolist(), strict=True)) == [(0, 21), (3, 20)]
    assert (rows.tolist(), dest.tolist()) == ([1, 0], [0, 3])  # 21 from 1, listed first
    rows, dest = shared_rows(src, chain, valid, [np.array([2, 1, 3]), np.array([], np.int64),
                                                  np.array([1]), np.array([0])])
    assert (rows.tolist(), dest.tolist()) == ([2, 0], [0, 3])  # now from 2, listed first
    with pytest.raises(ValueError, match="sources must lie in"):
        shared_rows(np.array([0, 4]), chain[:2], valid[:2], [np.array([1])] * 4)
    rows, dest = shared_rows(np.zeros(0, np.int64), np.zeros(0, np.int64), np.zeros(0, bool), [])
    assert rows.shape == dest.shape == (0,)


def test_sharing_neighbours_within_radius():
    pos = np.array([[0.0, 0, 0], [0.3, 0, 0], [0.9, 0, 0], [5.0, 0, 0]])
    nbs = sharing_neighbours(pos, 0.65)
    assert [nb.tolist() for nb in nbs] == [[1], [0, 2], [1], []]
    with pytest.raises(ValueError, match="radius"):
        sharing_neighbours(pos, -1.0)


def test_own_ray_levels_fill_a_short_neighbourhood_up_to_the_minimum():
    # 3,000 rays each, minimum 30,000: a lone position (traced alone anyway) and one with
    # 9 or more neighbours need nothing; one neighbour: 27,000 missing -> the cap (30,000);
    # 5 neighbours: 15,000 -> 24,000 (3,000 x 8); 8 neighbours: 6,000 -> 6,000 (3,000 x 2)
    nbs = [np.zeros(0, np.int64), np.arange(1), np.arange(5), np.arange(8), np.arange(9), np.arange(20)]
    levels = own_ray_levels(nbs, 3000, 30000)
    assert levels.tolist() == [0, 30000, 24000, 6000, 0, 0]
    n_nb = np.array([len(nb) for nb in nbs])
    short = levels > 0
    assert np.all(levels[short] + 3000 * n_nb[short] >= 30000)  # the guarantee
    assert np.all(levels[short] >= 6000)  # never the shared rays' own lattice again
    assert own_ray_levels(nbs, 3000, 0).tolist() == [0] * 6  # off
    # 7 neighbours: 9,000 missing -> 12,000; a minimum below two positions' rays: nothing
    assert own_ray_levels([np.arange(7)], 3000, 30000).tolist() == [12000]
    assert own_ray_levels([np.arange(1)], 3000, 5000).tolist() == [0]
    with pytest.raises(ValueError, match="min_samples"):
        own_ray_levels(nbs, 3000, -1)


def _path_rows(sp):
    """(tag, length, k_tx, k_rx) of every path of a SourcePaths."""
    tag = np.repeat(np.arange(len(sp.offsets) - 1), np.diff(sp.offsets))
    return tag, sp.tau_s * C0, sp.k_tx, sp.k_rx


def _unmatched_fraction(paths, reference) -> float:
    """Fraction of the paths that the reference trace lacks at the same position and tag."""
    missing, total = 0, 0
    for s, d in zip(paths, reference, strict=True):
        ts, ls, ks, kr = _path_rows(s)
        td, ld, kd, krd = _path_rows(d)
        for t, length, a, b in zip(ts, ls, ks, kr, strict=True):
            # float32 solver geometry: 1 mm of length and 1e-3 of direction are far above
            # its rounding and far below the separation of two distinct paths
            hit = (td == t) & (np.abs(ld - length) < 1e-3)
            hit &= (np.abs(kd - a).max(axis=1) < 1e-3) & (np.abs(krd - b).max(axis=1) < 1e-3)
            missing += not hit.any()
            total += 1
    return missing / max(total, 1)


def test_shared_paths_are_exact_paths_found_by_dense_tracing(corridor_scene):
    # Sharing hands a position chains found elsewhere and re-solves them with the image
    # method at the position. Its paths must be real paths of that position: a dense
    # reference trace (1e5 rays) must find them as often as it finds the paths of an
    # ordinary direct trace (20,000 rays); copying a neighbour's path unsolved (0.1-0.5 m
    # off) or inventing one would leave it unmatched. And it must find more paths than
    # the same rays without sharing.
    tags = corridor_scene.tags.positions_m[:6]
    x = np.arange(3.0, 4.6, 0.1)
    pos = np.column_stack([x, 1.2 + 0.05 * np.sin(4 * x), np.full_like(x, 0.7)])
    rts = load_sionna_scene(corridor_scene, F)
    shared = trace_shared(rts, pos, tags, sharing_neighbours(pos, 0.5), 3, 1000, 1)
    alone = _trace_chunk(rts, pos, tags, 3, 1000, 1)
    direct = _trace_chunk(rts, pos, tags, 3, 20000, 2)
    reference = _trace_chunk(rts, pos, tags, 3, 100000, 3)
    assert sum(len(s.tau_s) for s in shared) > 1.3 * sum(len(s.tau_s) for s in alone)  # measured 1.8x
    # measured: 4.2 % of the shared paths and 4.9 % of the direct ones are not in the
    # reference (weak high-order chains its own sampling missed); 2 points of margin
    # for the seeds' spread
    assert _unmatched_fraction(shared, reference) <= _unmatched_fraction(direct, reference) + 0.02
    # and no copies (the same reflection on another triangle of a wall, found through a
    # neighbour): the tolerance test the solver output is cleaned with finds none
    for s in shared:
        t, length, a, b = _path_rows(s)
        order = np.lexsort((length, t))
        assert not path_copies(np.zeros(len(t), np.int64), t[order], length[order], a[order], b[order],
                               s.transfer[order]).any()


def test_chains_left_to_the_completion_are_the_completions_paths(corridor_scene):
    # With completion on, shared positions neither solve nor share the chains the
    # completion enumerates (1..order reflections on large planes): merged with the
    # completion, the paths must be those of solving them twice. Same path set (length,
    # directions), and the same transfer matrices: on this corridor every plane is one
    # material, so the ray's and the completion's candidate of a chain are solved on the
    # same surface (1e-3 relative: float32 geometry; on corridor_lab, whose walls mix
    # glass into plasterboard, 27 of 5,136 links moved by > 0.01 dB, none readable).
    # Fewer candidates must have been solved, or nothing was left to the completion.
    from propagation.completion import complete_specular, large_planes, merge_paths, plane_lookup

    tags = corridor_scene.tags.positions_m[:6]
    x = np.arange(3.0, 4.6, 0.2)
    pos = np.column_stack([x, 1.2 + 0.05 * np.sin(4 * x), np.full_like(x, 0.7)])
    rts = load_sionna_scene(corridor_scene, F)
    planes = large_planes(rts, 1.0)
    lookup = plane_lookup(rts, planes)
    nbs = sharing_neighbours(pos, 0.5)
    both = trace_shared(rts, pos, tags, nbs, 3, 1000, 1)
    left = trace_shared(rts, pos, tags, nbs, 3, 1000, 1, completion=(lookup, 2))
    extra = complete_specular(rts, pos, tags, 2, planes)
    assert sum(len(s.tau_s) for s in left) < sum(len(s.tau_s) for s in both)
    for a, b, e in zip(both, left, extra, strict=True):
        ma, mb = merge_paths(a, e), merge_paths(b, e)
        ta, la, ka, ra = _path_rows(ma)
        tb, lb, kb, rb = _path_rows(mb)
        oa, ob = np.lexsort((la, ta)), np.lexsort((lb, tb))
        np.testing.assert_array_equal(ta[oa], tb[ob])
        np.testing.assert_allclose(la[oa], lb[ob], atol=1e-3)  # float32 geometry
        np.testing.assert_allclose(ka[oa], kb[ob], atol=1e-3)
        np.testing.assert_allclose(ra[oa], rb[ob], atol=1e-3)
        scale = np.abs(ma.transfer).max()
        np.testing.assert_allclose(ma.transfer[oa], mb.transfer[ob], rtol=0, atol=1e-3 * scale)
    # every covered row is a pure reflection chain on planes up to the order, no plane
    # twice in a row (the completion never enumerates that): an order-3 chain, a
    # refraction, a repeated plane or a triangle off the planes is not covered
    from sionna.rt.constants import InteractionType

    from propagation.completion import PlaneLookup

    spec, refr, none = (int(InteractionType.SPECULAR), int(InteractionType.REFRACTION),
                        int(InteractionType.NONE))

    def shape_and_prim(tri):
        k = int(np.searchsorted(lookup.offset, tri, side="right") - 1)
        return int(lookup.shape_ptr[k]), tri - int(lookup.offset[k])

    on = np.flatnonzero(lookup.plane >= 0)  # triangles on large planes
    a = int(on[0])
    b = int(on[lookup.plane[on] != lookup.plane[a]][0])  # one on another plane
    (pa, qa), (pb, qb) = shape_and_prim(a), shape_and_prim(b)
    types = np.array([[spec, none, none], [spec, spec, none], [spec, spec, spec],
                      [spec, refr, none], [none, none, none], [spec, spec, none]])
    shapes = np.tile([pa, pb, pa], (len(types), 1)).astype(np.int64)
    prims = np.tile([qa, qb, qa], (len(types), 1)).astype(np.int64)
    shapes[-1, 1], prims[-1, 1] = pa, qa  # the same plane twice in a row
    assert lookup.covered(types, shapes, prims, 2).tolist() == [True, True, False, False, False,
                                                                False]
    unknown = np.full((1, 3), int(lookup.shape_ptr.max()) + 100, np.int64)  # no such shape
    assert not lookup.covered(types[:1], unknown, prims[:1, :3], 2)[0]
    nothing = PlaneLookup(np.zeros(0, np.int64), np.zeros(1, np.int64), np.zeros(0, np.int64))
    assert nothing.planes_of(shapes[:2], prims[:2]).tolist() == [[-1] * 3] * 2
    assert not nothing.covered(types, shapes, prims, 2).any()


def test_chains_named_by_planes_are_not_solved_twice(corridor_scene, monkeypatch):
    # Named by planes (triangle_planes), a chain a neighbour found on other triangles of
    # the same wall is not solved again at a position that has it: fewer rows solved,
    # and the same paths as naming chains by triangles (whose extra rows were copies,
    # dropped by the tolerance test). Fails if two different planes shared an id (a
    # path would go missing) or if nothing was saved.
    import propagation.shared as shared_mod
    from propagation.completion import triangle_planes

    tags = corridor_scene.tags.positions_m[:6]
    x = np.arange(3.0, 4.6, 0.2)
    pos = np.column_stack([x, 1.2 + 0.05 * np.sin(4 * x), np.full_like(x, 0.7)])
    rts = load_sionna_scene(corridor_scene, F)
    nbs = sharing_neighbours(pos, 0.5)
    solved = []
    real = shared_mod.to_source_paths

    def counting(out, *a):
        solved.append(sum(len(v) for v in out["src"]))  # valid rows before copies go
        return real(out, *a)

    monkeypatch.setattr(shared_mod, "to_source_paths", counting)
    by_tri = trace_shared(rts, pos, tags, nbs, 3, 1000, 1)
    by_plane = trace_shared(rts, pos, tags, nbs, 3, 1000, 1, plane_ids=triangle_planes(rts))
    assert solved[1] < solved[0]
    for a, b in zip(by_tri, by_plane, strict=True):
        ta, la, ka, ra = _path_rows(a)
        tb, lb, kb, rb = _path_rows(b)
        oa, ob = np.lexsort((la, ta)), np.lexsort((lb, tb))
        np.testing.assert_array_equal(ta[oa], tb[ob])
        np.testing.assert_allclose(la[oa], lb[ob], atol=1e-3)  # float32 geometry
        np.testing.assert_allclose(ka[oa], kb[ob], atol=1e-3)
        np.testing.assert_allclose(ra[oa], rb[ob], atol=1e-3)


def test_triangle_planes_name_coplanar_triangles_alike(corridor_scene):
    from propagation.completion import large_planes, plane_lookup, triangle_planes

    rts = load_sionna_scene(corridor_scene, F)
    ids = triangle_planes(rts)
    # the same grouping as the large planes' (tolerance) grouping, where both apply
    big = plane_lookup(rts, large_planes(rts, 0.0))
    np.testing.assert_array_equal(ids.shape_ptr, big.shape_ptr)
    same_id = ids.plane[:, None] == ids.plane[None, :]
    same_plane = big.plane[:, None] == big.plane[None, :]
    np.testing.assert_array_equal(same_id, same_plane)
    assert len(np.unique(ids.plane)) > 6  # walls, floor, ceiling, ends: not all one id


def test_shared_floor_links_match_two_ray(floor_scene):
    # Over a floor, shared positions (0.1 m apart) are solved exactly: the two-ray closed
    # form holds to the 0.5 dB of the slab-vs-half-space difference (test_tracing)
    eps, sigma = material("concrete", F)
    d = np.linspace(2.0, 12.0, 21)
    h_r = 1.0
    heights = np.array([0.6, 0.7, 0.8])
    tags = np.stack([d, 0 * d, 0 * d + h_r], axis=1)
    poses = np.column_stack([np.zeros(3), np.zeros(3), heights, np.zeros(3)])
    links = trace_links(floor_scene, poses, tags, TraceOptions(method="shared", completion_order=0, max_depth=1, samples_per_src=20000, reader_pattern="iso", tag_pattern="iso", share_radius_m=0.25, shared_samples_per_src=2000, reader_polarization="V"))
    assert links.settings["share_radius_m"] == 0.25
    for k, h_t in enumerate(heights):
        ref = two_ray_gain_db(d, h_t, h_r, F, eps, sigma, "V")
        ok = ref > ref.max() - 15  # away from the deep two-ray nulls
        np.testing.assert_allclose(links.gain_db[k][ok], ref[ok], atol=0.5)


def test_shared_tour_is_closer_to_a_dense_trace_and_caches(tmp_path):
    # Without completion most of a corridor trace's error is chains its rays missed;
    # sharing hands each position the chains of ~10 neighbours, so at the same rays per
    # position it must come clearly closer to a dense reference (30x the rays) than
    # direct tracing does (measured: p90 |error| 2.8 vs 5.0 dB against a 1e5-ray
    # reference). With completion the large planes' chains are complete either way and
    # the two are alike (docs/physics.md). On 3 m of the pass (30 positions; 6 m before):
    # p90 ratio 0.53 and 1.77x the paths, as on the whole 6 m (0.53, 1.79) and on its
    # other half (0.48, 1.83).
    scene = make_corridor()
    tags = scene.tags.positions_m
    x = np.arange(2.0, 5.0, 0.1)
    poses = np.column_stack([x, 1.2 + 0.05 * np.sin(3 * x), np.full_like(x, 0.7), np.zeros_like(x)])
    kw = dict(tag_normals=scene.tags.normals)
    direct_opts = TraceOptions(method="direct", max_depth=3, seed=1, samples_per_src=1000)
    share = TraceOptions(max_depth=3, seed=1, share_radius_m=0.5, shared_samples_per_src=1000,
                         samples_per_src=1000, completion_order=0)
    reference = trace_links(scene, poses, tags, direct_opts.replace(seed=7, samples_per_src=30000), **kw)
    direct = trace_links(scene, poses, tags, direct_opts, **kw)
    shared = trace_links(scene, poses, tags, share, cache_dir=tmp_path, **kw)
    strong = reference.gain_db > reference.gain_db.max() - 25
    direct_err = np.percentile(np.abs(direct.gain_db - reference.gain_db)[strong], 90)
    shared_err = np.percentile(np.abs(shared.gain_db - reference.gain_db)[strong], 90)
    assert shared_err < 0.8 * direct_err
    assert shared.n_paths.sum() > 1.3 * direct.n_paths.sum()
    again = trace_links(scene, poses, tags, share, cache_dir=tmp_path, **kw)
    assert again.n_traced_sources == 0
    np.testing.assert_array_equal(again.gain_db, shared.gain_db)
    # a lone position shoots samples_per_src rays, as in direct tracing
    lone = trace_links(scene, poses[:1], tags, share.replace(shared_samples_per_src=10), **kw)
    alone = trace_links(scene, poses[:1], tags, direct_opts, **kw)
    # the solver's own rays, image method and fields (this corridor gives no copies); its
    # threads may order a path differently (1e-3 dB)
    np.testing.assert_allclose(lone.gain_db, alone.gain_db, atol=1e-3)
    with pytest.raises(ValueError, match="share_radius_m"):
        share.replace(share_radius_m=0.0)


def _solver_paths(rts, source, receivers, max_depth, samples, seed) -> dict:
    """Sionna's bare PathSolver from one source: ``valid`` and ``tau`` (n_rx, P), and per
    valid path (row-major) ``k_tx``, ``k_rx`` (3,) and the 2x2 transfer matrix ``a``."""
    import sionna.rt as rt

    from propagation.patterns import unit_vec_from_theta_phi
    from propagation.sionna_scene import clear_devices, place_devices

    place_devices(rts, source, receivers)
    paths = rt.PathSolver()(rts, max_depth=max_depth, samples_per_src=samples,
                            max_num_paths_per_src=samples * (max_depth + 1), synthetic_array=True,
                            los=True, specular_reflection=True, diffuse_reflection=False,
                            refraction=True, diffraction=False, seed=seed)
    n_rx = len(receivers)
    a_re, a_im = (x.numpy() for x in paths.a)  # (n_rx, 2, 1, 2, P)
    n_p = a_re.shape[-1]
    a = (a_re + 1j * a_im).reshape(n_rx, 2, 2, n_p).transpose(0, 3, 1, 2)
    per_rx = {k: getattr(paths, k).numpy().reshape(n_rx, n_p)
              for k in ("valid", "tau", "theta_t", "phi_t", "theta_r", "phi_r")}
    clear_devices(rts)
    v = per_rx["valid"].astype(bool)
    return {"valid": v, "tau": per_rx["tau"].astype(float), "a": a[v],
            "k_tx": unit_vec_from_theta_phi(per_rx["theta_t"][v], per_rx["phi_t"][v]),
            "k_rx": unit_vec_from_theta_phi(per_rx["theta_r"][v], per_rx["phi_r"][v])}


def test_lone_position_is_the_solvers_paths_without_its_copies():
    # A position with no neighbour is solved as the sharing's step 1: Sionna's own rays,
    # image method and fields, without its Paths object. Sionna's PathSolver returns some
    # paths twice (the same reflection through two triangles of one plane: same length,
    # directions and transfer matrix; 21 of 2,388 paths at this corridor_lab pose); the
    # sharing and direct tracing count them once. One Dr.Jit thread, so every call finds
    # the same chains.
    import scenes
    from propagation.backend import CUDA_VARIANT, ensure_variant, set_deterministic

    if ensure_variant() == CUDA_VARIANT:
        pytest.skip("the same chains in both calls need one CPU thread: set_deterministic refuses CUDA")
    from scenes.tagsites import tag_sites

    scene = scenes.load("corridor_lab")
    pose = np.array([[6.77, 1.22, 0.7, 0.2]])  # an evaluation-tour pose of the default study
    # tags on the surfaces, as the truth's tag sites (21 copies here, 0 at some poses)
    sites = tag_sites(scene, spacing_m=0.5, z_range_m=(0.2, 1.6)).positions_m
    tags = sites[np.linalg.norm(sites - pose[0, :3], axis=1) < 3.0]
    rts = load_sionna_scene(scene, F)
    set_deterministic(True)
    try:
        lone = trace_links(scene, pose, tags, TraceOptions(method="shared", completion_order=0, max_depth=5, samples_per_src=30000, share_radius_m=1.0, shared_samples_per_src=3000, seed=42))
        raw = _solver_paths(rts, pose[:, :3], tags, 5, 30000, 42)
        direct = trace_links(scene, pose, tags, TraceOptions(method="direct", max_depth=5, samples_per_src=30000, seed=42))
    finally:
        set_deterministic(False)
    n_rx = len(tags)
    tg = np.nonzero(raw["valid"])[0]
    order = np.lexsort((raw["tau"][raw["valid"]], tg))
    tau = raw["tau"][raw["valid"]][order]
    copies = path_copies(np.zeros(len(tg), np.int64), tg[order], tau * C0, raw["k_tx"][order],
                         raw["k_rx"][order], raw["a"][order])
    assert copies.sum() > 0  # the scene and pose are chosen to have some
    per_tag = np.bincount(tg, minlength=n_rx) - np.bincount(tg[order][copies], minlength=n_rx)
    np.testing.assert_array_equal(lone.n_paths[0], per_tag)
    # direct tracing counts them once too
    np.testing.assert_array_equal(direct.n_paths[0], per_tag)
    np.testing.assert_allclose(direct.gain_db, lone.gain_db, atol=1e-3)


def test_own_shared_and_completion_rows_share_one_image_method_kernel(corridor_scene):
    # The own rows, the neighbours' rows and the completion's chains are solved by the
    # same image method and field calculator: one kernel of each must serve all three
    # buffers (each buffer's arrays in memory of their own, the completion's chains in
    # buffers of the trace's depth), and the own rows' validity must not be evaluated in
    # a kernel of its own (which left the image method's points to a second kernel that
    # computed them again). Before this was so, a chunk compiled four image-method
    # kernels (own, its fields again, shared, completion): ~6 s of LLVM builds per process.
    from propagation.completion import complete_specular, large_planes, plane_lookup

    tags = corridor_scene.tags.positions_m[:5]
    x = np.arange(3.0, 4.0, 0.1)
    pos = np.column_stack([x, np.full_like(x, 1.2), np.full_like(x, 0.7)])
    rts = load_sionna_scene(corridor_scene, F)
    planes = large_planes(rts, 1.0)
    paths = {}

    def run():
        paths["shared"] = trace_shared(rts, pos, tags, sharing_neighbours(pos, 0.5), 3, 500, 1,
                                       completion=(plane_lookup(rts, planes), 2))
        paths["extra"] = complete_specular(rts, pos, tags, 2, planes, buffer_depth=3)

    big = launched_kernels(run, 3000)
    shared, extra = paths["shared"], paths["extra"]
    assert sum(len(s.tau_s) for s in shared) > 0 and sum(len(s.tau_s) for s in extra) > 0
    # the shooting (~3,800 operations at depth 3), then the image method (~5,900) for
    # the own rows, the shared rows (this scene has rows of both) and the completion
    ops = [e["operation_count"] for e in big]
    assert len(big) == 4, ops
    assert len({e["hash"] for e in big[1:]}) == 1 and big[0]["hash"] != big[1]["hash"], ops


def test_sharing_trace_links_completes_in_its_own_kernels(corridor_scene, tmp_path):
    # Through trace_links (the study's path): a chunk of sharing positions with the
    # completion on builds two big kernels, its shooting and one image method for the
    # own rows, the shared rows and the completion's chains (the completion solved in
    # buffers of the tracer's depth, not of its order). The minimum ray budget is off: the
    # path's two ends have 4 neighbours (2,500 rays < 3,000) and would shoot 1,000 more
    # alone, in a shooting kernel of that ray count (propagation.shared.own_ray_levels)
    x = np.arange(3.0, 3.6, 0.1)
    poses = np.column_stack([x, np.full_like(x, 1.2), np.full_like(x, 0.7), np.zeros_like(x)])
    traced = []
    big = launched_kernels(lambda: traced.append(trace_links(corridor_scene, poses, corridor_scene.tags.positions_m[:5], TraceOptions(method="shared", samples_per_src=3000, max_depth=3, seed=2, share_radius_m=0.5, shared_samples_per_src=500, completion_order=2, min_samples_per_position=0), frequency_hz=F, cache_dir=tmp_path)), 3000)
    links = traced[0]
    assert links.n_traced_sources == len(poses)
    ops = [e["operation_count"] for e in big]
    assert len(big) >= 3, ops  # the shooting, then at least the own rows and the completion
    assert len({e["hash"] for e in big}) == 2, ops
