"""The packed path cache: round trip, newest-largest slot wins, format-1 migration, damage."""

import json

import numpy as np
import pytest

from propagation import CacheWarning
from propagation.pathcache import PathCache, SourcePaths, position_key


def _paths(src, n_tags, rng):
    counts = rng.integers(0, 4, n_tags)
    p = int(counts.sum())
    return SourcePaths(
        source_m=np.asarray(src, float),
        tag_positions_m=rng.random((n_tags, 3)),
        offsets=np.concatenate([[0], np.cumsum(counts)]).astype(np.int64),
        # float32 on disk: values exactly representable so the round trip is exact
        transfer=(rng.integers(-8, 8, (p, 2, 2)) + 1j * rng.integers(-8, 8, (p, 2, 2))) / 16,
        tau_s=rng.random(p),
        k_tx=rng.random((p, 3)),
        k_rx=rng.random((p, 3)),
    )


def _equal(a, b):
    for name in ("source_m", "tag_positions_m", "offsets", "transfer", "tau_s", "k_tx", "k_rx"):
        np.testing.assert_array_equal(getattr(a, name), getattr(b, name), err_msg=name)


def test_pack_round_trip_and_largest_slot_wins(tmp_path):
    rng = np.random.default_rng(0)
    sets = [_paths([x, 1.0, 1.0], 5, rng) for x in (1.0, 2.0, 3.0)]
    cache = PathCache(tmp_path)
    cache.save(sets)
    bigger = sets[1].merged(_paths([2.0, 1.0, 1.0], 4, rng))
    cache.save([bigger])
    fresh = PathCache(tmp_path)  # index read back from the JSON files
    assert len(fresh) == 3
    got = fresh.load([[1.0, 1.0, 1.0], [2.0, 1.0, 1.0], [3.0, 1.0, 1.0], [9.0, 1.0, 1.0]])
    _equal(got[0], sets[0])
    _equal(got[1], bigger)  # 9 tags beat the first pack's 5
    _equal(got[2], sets[2])
    assert got[3] is None


def test_format1_files_are_read_repacked_and_removed(tmp_path):
    rng = np.random.default_rng(1)
    sp = _paths([4.0, 1.0, 0.5], 3, rng)
    legacy = tmp_path / f"{position_key(sp.source_m)}.npz"
    np.savez(legacy, source_m=sp.source_m, tag_positions_m=sp.tag_positions_m, offsets=sp.offsets,
             transfer_re=sp.transfer.real.astype(np.float32), transfer_im=sp.transfer.imag.astype(np.float32),
             tau_s=sp.tau_s, k_tx=sp.k_tx, k_rx=sp.k_rx)
    got = PathCache(tmp_path).load([sp.source_m])[0]
    _equal(got, sp)
    assert not legacy.exists() and len(list(tmp_path.glob("pack-*.npz"))) == 1
    _equal(PathCache(tmp_path).load([sp.source_m])[0], sp)


def test_damaged_index_and_inconsistent_pack_warn_by_name(tmp_path):
    rng = np.random.default_rng(2)
    cache = PathCache(tmp_path)
    npz = cache.save([_paths([1.0, 1.0, 1.0], 2, rng)])
    js = npz.with_suffix(".json")
    meta = json.loads(js.read_text())
    js.write_text("{broken")
    with pytest.warns(CacheWarning, match=js.name):
        assert len(PathCache(tmp_path)) == 0
    assert not npz.exists()
    # an index that points at a pack holding another position
    npz = cache.save([_paths([2.0, 1.0, 1.0], 2, rng)])
    meta["keys"] = [position_key([5.0, 1.0, 1.0])]
    npz.with_suffix(".json").write_text(json.dumps(meta))
    with pytest.warns(CacheWarning, match=npz.name):
        assert PathCache(tmp_path).load([[5.0, 1.0, 1.0]]) == [None]


def _scale_transfer(npz, factor):
    """Rewrite a pack as a valid NPZ whose transfer values are scaled (the index untouched)."""
    with np.load(npz, allow_pickle=False) as z:
        arr = {k: z[k] for k in z.files}
    arr["transfer_re"] = (arr["transfer_re"] * factor).astype(np.float32)
    arr["transfer_im"] = (arr["transfer_im"] * factor).astype(np.float32)
    with open(npz, "wb") as fh:
        np.savez(fh, **arr)


def test_index_holds_a_checksum_and_tampered_values_are_refused(tmp_path):
    rng = np.random.default_rng(3)
    sp = _paths([1.0, 2.0, 1.0], 4, rng)
    npz = PathCache(tmp_path).save([sp])
    meta = json.loads(npz.with_suffix(".json").read_text())
    assert len(meta["sha256"]) == 64
    _equal(PathCache(tmp_path).load([sp.source_m])[0], sp)  # intact: verified and read
    _scale_transfer(npz, 1.2)
    with pytest.warns(CacheWarning, match=rf"damaged path cache file .*{npz.name}.*SHA-256"):
        assert PathCache(tmp_path).load([sp.source_m]) == [None]
    assert not npz.exists() and not npz.with_suffix(".json").exists()


def test_index_without_checksum_is_not_trusted(tmp_path):
    rng = np.random.default_rng(4)
    sp = _paths([1.0, 2.0, 1.0], 2, rng)
    npz = PathCache(tmp_path).save([sp])
    js = npz.with_suffix(".json")
    meta = json.loads(js.read_text())
    del meta["sha256"]
    js.write_text(json.dumps(meta))
    with pytest.warns(CacheWarning, match=js.name):
        assert len(PathCache(tmp_path)) == 0


def test_settings_key_covers_solver_versions(monkeypatch):
    from propagation import pathcache

    settings = {"frequency_hz": 865e6, "max_depth": 2}
    key = pathcache.settings_key("abc", settings)
    assert set(pathcache.solver_versions()) == {"sionna-rt", "mitsuba", "drjit"}
    assert pathcache.solver_versions()["drjit"]  # installed here
    bumped = {**pathcache.solver_versions(), "sionna-rt": "99.0"}
    monkeypatch.setattr(pathcache, "solver_versions", lambda: bumped)
    assert pathcache.settings_key("abc", settings) != key
    assert pathcache.settings_key("abc", {**settings, "max_depth": 3}) != pathcache.settings_key("abc", settings)
    assert pathcache.settings_key("abd", settings) != pathcache.settings_key("abc", settings)


def test_tampered_pack_is_retraced_to_the_original_values(tmp_path, corridor_scene):
    """A real (small) trace: a pack whose transfer values were scaled by 1.2 is named,
    removed and traced again; the gains come back as the first trace gave them."""
    from propagation import TraceOptions, trace_links

    poses = np.array([[3.0, 1.2, 1.0, 0.0], [6.0, 1.2, 1.0, np.pi]])
    tags = corridor_scene.tags.positions_m[:4]
    kw = dict(options=TraceOptions(method="direct", max_depth=1, samples_per_src=2000), cache_dir=tmp_path)
    first = trace_links(corridor_scene, poses, tags, **kw)
    assert first.n_traced_sources == 2
    (npz,) = sorted(tmp_path.rglob("pack-*.npz"))
    _scale_transfer(npz, 1.2)
    with pytest.warns(CacheWarning, match=npz.name):
        again = trace_links(corridor_scene, poses, tags, **kw)
    assert again.n_traced_sources == 2 and not npz.exists()
    np.testing.assert_allclose(again.gain, first.gain, rtol=1e-5)
    third = trace_links(corridor_scene, poses, tags, **kw)  # the fresh pack verifies
    assert third.n_traced_sources == 0
    np.testing.assert_array_equal(third.gain, again.gain)
