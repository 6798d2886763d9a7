"""Per-source path sets and their on-disk cache (NPZ + JSON, written to a temporary name then renamed).

The cached unit is everything needed to re-apply antenna patterns after tracing: per
antenna *position* and tag position, every path's 2x2 polarimetric transfer matrix
(traced with unrotated isotropic ``VH`` antennas at both ends), delay and departure /
arrival directions. Orientation changes, pattern or polarisation what-ifs hit the cache.

Layout: ``<cache_dir>/<settings_key>/pack-<id>.npz`` holds the path sets of all the
antenna positions of one solver call (concatenated, with offset arrays), and
``pack-<id>.json`` its index (the ``position_key`` of each slot, its tag count and the
SHA-256 of the pack's values). Packing matters for speed: NumPy parses every array
header of an NPZ with ``ast.literal_eval``, which cost ~36 ms per antenna position with
one file per position (format 1); with one file per solver call the load is a few files
per thousand positions. Format-1 files (``<position_key>.npz``) found in the same folder
are still read, then repacked and removed.

What the keys cover
-------------------
An entry is reused only when all of these are equal; anything else gets its own folder
(a new ``settings_key``) or misses (a new ``position_key``, an untraced tag):

- ``settings_key`` (the folder): the scene's :meth:`~scenes.Scene.content_hash` (solid
  meshes with their materials, radio surfaces with their thicknesses, tags,
  ``metadata["material_overrides"]``: a scene traced on its radio surfaces never meets
  an entry traced on closed wall boxes); the carrier frequency (materials are evaluated
  there); the solver settings :func:`propagation.trace_links` passes (``max_depth``,
  ``samples_per_src``, sampling ``seed``, ``los``, ``specular_reflection``,
  ``refraction``, ``diffuse_reflection``, ``diffraction``); the cache format; and the
  installed versions of ``sionna-rt``, ``mitsuba`` and ``drjit`` (another solver
  build may find other paths, so an upgrade starts a new folder).
- ``position_key`` (a slot in a pack): the exact float64 bytes of the antenna position.
- inside a slot, tags are matched by the exact float64 bytes of their position.

Not part of any key, because they are applied after tracing: antenna orientations, the
reader and tag patterns, the reader polarisation, tag normals (the tag dipole axis).
Also not part of the key: the Dr.Jit variant (LLVM or CUDA) and thread count
(``tracing.deterministic``), and the memory budget (how sources are chunked); the
multi-threaded solver itself finds about one path in a thousand differently from call to
call, so an entry is one valid trace, not the only one. Folders of older settings keys
(other versions, other settings) are never read again and may be deleted.

Integrity
---------
Packs are never rewritten: when more tags are traced at a cached position, a new pack
holds the merged set, and the slot with the most tags wins. Several processes may share
a cache folder (pack names are unique; each file appears atomically, the index last).
The index stores the SHA-256 of the pack's arrays (names, dtypes, shapes and bytes),
which :meth:`PathCache.load` checks: a pack whose values changed after it was written
(edited, bit rot, a file from elsewhere under the same name) is treated like a file that
cannot be read.

A cache file that cannot be read, or whose values do not match the checksum in its index,
is reported with a :class:`CacheWarning` naming the file, removed, and its links traced
again (a killed or corrupted run stays resumable, and never reuses wrong numbers).
"""
from __future__ import annotations

import functools
import hashlib
import json
import uuid
import warnings
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from scenes.fileio import atomic_save_npz, atomic_write_text

__all__ = ["CacheWarning", "PathCache", "SourcePaths", "position_key", "settings_key",
           "solver_versions", "values_sha256"]

# part of settings_key; the pack layout (format 3: format 2 plus the values' SHA-256 in
# the index) reads format-1 files in the same folder
_FORMAT_VERSION = 1
_PACK_FORMAT = 3

#: Distributions whose versions enter settings_key (the ray tracer and its back ends).
SOLVER_DISTRIBUTIONS = ("sionna-rt", "mitsuba", "drjit")


class CacheWarning(UserWarning):
    """A cache entry was unreadable or failed its checksum and is being recomputed."""


@dataclass
class SourcePaths:
    """Paths from one antenna position to a set of tag positions.

    Attributes
    ----------
    source_m : numpy.ndarray
        Antenna position, shape (3,), float64, metres.
    tag_positions_m : numpy.ndarray
        Tag positions traced from here, shape (k, 3), float64, metres.
    offsets : numpy.ndarray
        Path slice of tag i is ``offsets[i]:offsets[i+1]``, shape (k + 1,), int64.
    transfer : numpy.ndarray
        Per path 2x2 transfer matrix [rx (theta, phi), tx (theta, phi)] in the world
        spherical bases at the arrival / departure directions, including the free-space
        loss and the isotropic effective area (Sionna's ``a`` for ``iso``/``VH``),
        shape (P, 2, 2), complex128.
    tau_s : numpy.ndarray
        Path delays, shape (P,), float64, seconds.
    k_tx : numpy.ndarray
        Departure directions, unit vectors (P, 3), float64.
    k_rx : numpy.ndarray
        Arrival directions (pointing from the tag toward the incoming wave), (P, 3).
    """

    source_m: np.ndarray
    tag_positions_m: np.ndarray
    offsets: np.ndarray
    transfer: np.ndarray
    tau_s: np.ndarray
    k_tx: np.ndarray
    k_rx: np.ndarray

    @classmethod
    def empty(cls, source_m) -> SourcePaths:
        return cls(np.asarray(source_m, float), np.zeros((0, 3)), np.zeros(1, np.int64),
                   np.zeros((0, 2, 2), complex), np.zeros(0), np.zeros((0, 3)), np.zeros((0, 3)))

    def index_of(self, tag_positions_m) -> np.ndarray:
        """Row in ``tag_positions_m`` of each query position (exact match), -1 if absent.

        The lookup is built once per ``tag_positions_m`` array: replace the array, never
        change it in place."""
        lookup = self.__dict__.get("_lookup")
        if lookup is None or lookup[0] is not self.tag_positions_m:  # built once per array
            rows = np.ascontiguousarray(self.tag_positions_m)
            lookup = (self.tag_positions_m, {row.tobytes(): i for i, row in enumerate(rows)})
            self.__dict__["_lookup"] = lookup
        lookup = lookup[1]
        q = np.ascontiguousarray(np.asarray(tag_positions_m, dtype=np.float64).reshape(-1, 3))
        return np.array([lookup.get(row.tobytes(), -1) for row in q], dtype=np.int64)

    def subset(self, rows) -> SourcePaths:
        """The paths to the tags at ``rows`` (indices into ``tag_positions_m``), in that order."""
        rows = np.asarray(rows, dtype=np.int64).reshape(-1)
        if len(rows) == len(self.tag_positions_m) and np.array_equal(rows, np.arange(len(rows))):
            return self
        counts = np.diff(self.offsets)[rows]
        idx = _path_rows(self.offsets, rows)
        return SourcePaths(self.source_m, self.tag_positions_m[rows],
                           np.concatenate([[0], np.cumsum(counts)]).astype(np.int64),
                           self.transfer[idx], self.tau_s[idx], self.k_tx[idx], self.k_rx[idx])

    def merged(self, other: SourcePaths) -> SourcePaths:
        """This path set plus the tags of ``other`` not already here."""
        new = np.flatnonzero(self.index_of(other.tag_positions_m) < 0)
        if len(new) == 0:
            return self
        counts = np.diff(other.offsets)[new]
        idx = _path_rows(other.offsets, new)
        return SourcePaths(
            self.source_m,
            np.concatenate([self.tag_positions_m, other.tag_positions_m[new]]),
            np.concatenate([self.offsets, self.offsets[-1] + np.cumsum(counts)]),
            np.concatenate([self.transfer, other.transfer[idx]]),
            np.concatenate([self.tau_s, other.tau_s[idx]]),
            np.concatenate([self.k_tx, other.k_tx[idx]]),
            np.concatenate([self.k_rx, other.k_rx[idx]]),
        )


def _path_rows(offsets: np.ndarray, tags: np.ndarray) -> np.ndarray:
    """Path indices of the tags ``tags`` (in that order) of a path set with ``offsets``."""
    tags = np.asarray(tags, dtype=np.int64)
    counts = np.diff(offsets)[tags]
    starts = np.asarray(offsets, dtype=np.int64)[tags]
    # each tag's run start..start+count, in one go: a running index minus each run's shift
    shift = np.repeat(starts - (np.cumsum(counts) - counts), counts)
    return np.arange(int(counts.sum()), dtype=np.int64) + shift


@functools.lru_cache(maxsize=1)
def solver_versions() -> dict[str, str | None]:
    """Installed versions of :data:`SOLVER_DISTRIBUTIONS` (``None`` where not installed)."""
    from importlib import metadata

    out: dict[str, str | None] = {}
    for dist in SOLVER_DISTRIBUTIONS:
        try:
            out[dist] = metadata.version(dist)
        except metadata.PackageNotFoundError:
            out[dist] = None
    return out


def settings_key(scene_hash: str, settings: dict) -> str:
    """Hash of the scene content, the solver settings and the solver's versions.

    Parameters
    ----------
    scene_hash : str
        :meth:`scenes.Scene.content_hash` of the traced scene.
    settings : dict
        Frequency and solver settings (JSON-able), as :func:`propagation.trace_links`
        passes them.

    Returns
    -------
    str
        32 hex digits: the cache sub-directory name (see the module docstring for what
        it covers).
    """
    blob = json.dumps({"scene": scene_hash, "format": _FORMAT_VERSION,
                       "versions": solver_versions(), **settings}, sort_keys=True)
    return hashlib.sha256(blob.encode()).hexdigest()[:32]


def values_sha256(arrays: dict) -> str:
    """SHA-256 of named arrays: each name, dtype, shape and bytes, in name order."""
    h = hashlib.sha256()
    for name in sorted(arrays):
        a = np.ascontiguousarray(arrays[name])
        h.update(f"{name}|{a.dtype.str}|{a.shape}\n".encode())
        h.update(a.tobytes())
    return h.hexdigest()


def position_key(position_m) -> str:
    """Hash of the exact float64 bytes of an antenna position (a cache file stem)."""
    p = np.ascontiguousarray(np.asarray(position_m, dtype=np.float64).reshape(3))
    return hashlib.sha256(p.tobytes()).hexdigest()[:32]



def _check(sp: SourcePaths, position_m) -> SourcePaths:
    n_paths = sp.offsets[-1] if len(sp.offsets) else -1
    if (not np.array_equal(sp.source_m, np.asarray(position_m, float))
            or len(sp.offsets) != len(sp.tag_positions_m) + 1 or sp.offsets[0] != 0
            or np.any(np.diff(sp.offsets) < 0)
            or not (len(sp.tau_s) == len(sp.transfer) == len(sp.k_tx) == len(sp.k_rx) == n_paths)):
        raise ValueError("inconsistent arrays")
    return sp


class _ChecksumMismatch(ValueError):
    pass


def _warn_and_remove(files, exc, stacklevel=4) -> None:
    names = ", ".join(str(f) for f in files)
    what = "damaged" if isinstance(exc, _ChecksumMismatch) else "unreadable"
    warnings.warn(f"{what} path cache file {names} ({exc}); removing it and tracing again",
                  CacheWarning, stacklevel=stacklevel)
    for f in files:
        try:
            Path(f).unlink()
        except OSError:
            pass


def _load_legacy(path: Path, position_m) -> SourcePaths:
    """A format-1 file (one antenna position per NPZ)."""
    with np.load(path, allow_pickle=False) as z:
        sp = SourcePaths(
            source_m=z["source_m"],
            tag_positions_m=z["tag_positions_m"].reshape(-1, 3),
            offsets=z["offsets"].astype(np.int64),
            transfer=z["transfer_re"] + 1j * z["transfer_im"],
            tau_s=z["tau_s"],
            k_tx=z["k_tx"].reshape(-1, 3),
            k_rx=z["k_rx"].reshape(-1, 3),
        )
    return _check(sp, position_m)


class PathCache:
    """On-disk store of :class:`SourcePaths`, one pack file per solver call.

    Parameters
    ----------
    directory : str or Path
        The settings folder ``<cache_dir>/<settings_key>``; created on the first save.

    Notes
    -----
    The index (position key -> pack, slot) is read once, at construction, from the
    ``pack-*.json`` files; :meth:`save` adds to it.
    """

    def __init__(self, directory) -> None:
        self.directory = Path(directory)
        # position key -> (pack stem, slot, n_tags)
        self._index: dict[str, tuple[str, int, int]] = {}
        # pack stem -> SHA-256 of its values (from its index)
        self._sha256: dict[str, str] = {}
        if self.directory.is_dir():
            for js in sorted(self.directory.glob("pack-*.json")):
                self._read_index(js)

    def _read_index(self, js: Path) -> None:
        try:
            meta = json.loads(js.read_text())
            if (meta.get("format") != _PACK_FORMAT or len(meta["keys"]) != len(meta["n_tags"])
                    or not isinstance(meta.get("sha256"), str)):
                raise ValueError(f"not a format-{_PACK_FORMAT} pack index (keys, n_tags, sha256)")
            entries = [(str(k), int(n)) for k, n in zip(meta["keys"], meta["n_tags"], strict=True)]
            self._sha256[js.stem] = meta["sha256"]
        except Exception as exc:  # noqa: BLE001 - any damage means "recompute"
            _warn_and_remove([js, js.with_suffix(".npz")], exc, stacklevel=5)
            return
        for slot, (key, n_tags) in enumerate(entries):
            old = self._index.get(key)
            if old is None or n_tags > old[2]:
                self._index[key] = (js.stem, slot, n_tags)

    def __len__(self) -> int:
        return len(self._index)

    def load(self, positions_m) -> list[SourcePaths | None]:
        """Cached path sets of antenna positions (None where missing or unreadable).

        Parameters
        ----------
        positions_m : array_like
            Antenna positions, shape (n, 3), float64, metres (matched exactly).

        Returns
        -------
        list of SourcePaths or None
            One entry per position. An unreadable pack is reported with a
            :class:`CacheWarning` naming it and removed (its positions come back None),
            and so is a pack whose values do not match the SHA-256 in its index.
        """
        pos = np.asarray(positions_m, dtype=np.float64).reshape(-1, 3)
        out: list[SourcePaths | None] = [None] * len(pos)
        by_pack: dict[str, list[tuple[int, int]]] = {}
        legacy: list[int] = []
        for i, p in enumerate(pos):
            key = position_key(p)
            hit = self._index.get(key)
            if hit is not None:
                by_pack.setdefault(hit[0], []).append((i, hit[1]))
            elif (self.directory / f"{key}.npz").exists():
                legacy.append(i)
        for stem, wanted in by_pack.items():
            npz = self.directory / f"{stem}.npz"
            try:
                with np.load(npz, allow_pickle=False) as z:
                    arr = {k: z[k] for k in z.files}
                want_sha, got_sha = self._sha256.get(stem), values_sha256(arr)
                if got_sha != want_sha:
                    raise _ChecksumMismatch(f"SHA-256 of its values {got_sha[:12]}... is not the "
                                            f"{str(want_sha)[:12]}... recorded in {stem}.json")
                tag_off, path_off = arr["tag_offsets"], arr["path_offsets"]
                for i, slot in wanted:
                    t0, t1 = int(tag_off[slot]), int(tag_off[slot + 1])
                    p0, p1 = int(path_off[t0]), int(path_off[t1])
                    re = arr["transfer_re"][p0:p1]
                    im = arr["transfer_im"][p0:p1]
                    out[i] = _check(SourcePaths(
                        source_m=arr["source_m"][slot],
                        tag_positions_m=arr["tag_positions_m"][t0:t1],
                        offsets=path_off[t0:t1 + 1] - p0,
                        transfer=re + 1j * im,
                        tau_s=arr["tau_s"][p0:p1],
                        k_tx=arr["k_tx"][p0:p1],
                        k_rx=arr["k_rx"][p0:p1],
                    ), pos[i])
            except Exception as exc:  # noqa: BLE001 - any damage means "recompute"
                _warn_and_remove([npz, npz.with_suffix(".json")], exc)
                for i, _ in wanted:
                    out[i] = None
                self._index = {k: v for k, v in self._index.items() if v[0] != stem}
                self._sha256.pop(stem, None)
        if legacy:
            self._migrate(pos, legacy, out)
        return out

    def _migrate(self, pos, legacy, out) -> None:
        """Read format-1 files, write them as one pack, remove them."""
        done, files = [], []
        for i in legacy:
            path = self.directory / f"{position_key(pos[i])}.npz"
            try:
                out[i] = _load_legacy(path, pos[i])
            except Exception as exc:  # noqa: BLE001 - any damage means "recompute"
                _warn_and_remove([path], exc, stacklevel=5)
                continue
            done.append(out[i])
            files.append(path)
        if done:
            self.save(done)
            for f in files:
                f.unlink(missing_ok=True)

    def save(self, path_sets: list[SourcePaths]) -> Path:
        """Write path sets as one pack (NPZ, then its JSON index; each atomically).

        Returns
        -------
        Path
            The pack's NPZ file.
        """
        if not path_sets:
            raise ValueError("PathCache.save needs at least one path set")
        stem = f"pack-{uuid.uuid4().hex}"
        n_tags = [len(sp.tag_positions_m) for sp in path_sets]
        path_off, base = [np.zeros(1, np.int64)], 0
        for sp in path_sets:
            path_off.append(base + np.asarray(sp.offsets[1:], np.int64))
            base += int(sp.offsets[-1])
        transfer = np.concatenate([sp.transfer.reshape(-1, 2, 2) for sp in path_sets])
        arrays = dict(
            source_m=np.stack([np.asarray(sp.source_m, np.float64) for sp in path_sets]),
            tag_offsets=np.concatenate([[0], np.cumsum(n_tags)]).astype(np.int64),
            tag_positions_m=np.concatenate([sp.tag_positions_m.reshape(-1, 3) for sp in path_sets]),
            path_offsets=np.concatenate(path_off),
            transfer_re=transfer.real.astype(np.float32),
            transfer_im=transfer.imag.astype(np.float32),
            tau_s=np.concatenate([sp.tau_s for sp in path_sets]).astype(np.float64),
            k_tx=np.concatenate([sp.k_tx.reshape(-1, 3) for sp in path_sets]).astype(np.float64),
            k_rx=np.concatenate([sp.k_rx.reshape(-1, 3) for sp in path_sets]).astype(np.float64),
        )
        arrays = {k: np.ascontiguousarray(v) for k, v in arrays.items()}
        sha = values_sha256(arrays)
        npz = atomic_save_npz(self.directory / f"{stem}.npz", **arrays)
        keys = [position_key(sp.source_m) for sp in path_sets]
        atomic_write_text(self.directory / f"{stem}.json",
                          json.dumps({"format": _PACK_FORMAT, "keys": keys, "n_tags": n_tags,
                                      "sha256": sha}))
        self._sha256[stem] = sha
        for slot, (key, k) in enumerate(zip(keys, n_tags, strict=True)):
            old = self._index.get(key)
            if old is None or k >= old[2]:
                self._index[key] = (stem, slot, k)
        return npz
