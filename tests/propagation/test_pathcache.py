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
