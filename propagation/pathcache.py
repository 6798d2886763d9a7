"""Per-source path sets and their on-disk cache (NPZ, written to a temporary name then renamed).

The cached unit is everything needed to re-apply antenna patterns after tracing: per
antenna *position* and tag position, every path's 2x2 polarimetric transfer matrix
(traced with unrotated isotropic ``VH`` antennas at both ends), delay and departure /
arrival directions. Orientation changes, pattern or polarisation what-ifs hit the cache.

Layout: ``<cache_dir>/<settings_key>/<position_key>.npz`` where ``settings_key`` hashes
the scene's :meth:`~scenes.Scene.content_hash`, the frequency and the solver settings,
and ``position_key`` the exact float64 bytes of the antenna position.

A cache file that cannot be read is reported with a :class:`CacheWarning` naming the
file, removed, and its links traced again (a killed or corrupted run stays resumable).
"""

from __future__ import annotations

import hashlib
import json
import os
import tempfile
import warnings
from dataclasses import dataclass
from pathlib import Path

import numpy as np

__all__ = ["CacheWarning", "SourcePaths", "settings_key", "position_key", "load_source", "save_source"]

_FORMAT_VERSION = 1


class CacheWarning(UserWarning):
    """A cache entry was unreadable and is being recomputed."""


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
        """Row in ``tag_positions_m`` of each query position (exact match), -1 if absent."""
        lookup = {row.tobytes(): i for i, row in enumerate(np.ascontiguousarray(self.tag_positions_m))}
        q = np.ascontiguousarray(np.asarray(tag_positions_m, dtype=np.float64).reshape(-1, 3))
        return np.array([lookup.get(row.tobytes(), -1) for row in q], dtype=np.int64)

    def merged(self, other: SourcePaths) -> SourcePaths:
        """This path set plus the tags of ``other`` not already here."""
        new = np.flatnonzero(self.index_of(other.tag_positions_m) < 0)
        if len(new) == 0:
            return self
        counts = np.diff(other.offsets)[new]
        idx = np.concatenate([np.arange(other.offsets[i], other.offsets[i + 1]) for i in new])
        idx = idx.astype(np.int64)
        return SourcePaths(
            self.source_m,
            np.concatenate([self.tag_positions_m, other.tag_positions_m[new]]),
            np.concatenate([self.offsets, self.offsets[-1] + np.cumsum(counts)]),
            np.concatenate([self.transfer, other.transfer[idx]]),
            np.concatenate([self.tau_s, other.tau_s[idx]]),
            np.concatenate([self.k_tx, other.k_tx[idx]]),
            np.concatenate([self.k_rx, other.k_rx[idx]]),
        )


def settings_key(scene_hash: str, settings: dict) -> str:
    """Hash of the scene content and the solver settings (a cache sub-directory name)."""
    blob = json.dumps({"scene": scene_hash, "format": _FORMAT_VERSION, **settings}, sort_keys=True)
    return hashlib.sha256(blob.encode()).hexdigest()[:32]


def position_key(position_m) -> str:
    """Hash of the exact float64 bytes of an antenna position (a cache file stem)."""
    p = np.ascontiguousarray(np.asarray(position_m, dtype=np.float64).reshape(3))
    return hashlib.sha256(p.tobytes()).hexdigest()[:32]


def _path(directory: Path, position_m) -> Path:
    return Path(directory) / f"{position_key(position_m)}.npz"


def load_source(directory: Path, position_m) -> SourcePaths | None:
    """The cached path set of an antenna position, or None (missing or unreadable).

    An unreadable or mismatching file triggers a :class:`CacheWarning` naming it and is removed.
    """
    path = _path(directory, position_m)
    if not path.exists():
        return None
    try:
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
        n_paths = sp.offsets[-1] if len(sp.offsets) else -1
        if (not np.array_equal(sp.source_m, np.asarray(position_m, float))
                or len(sp.offsets) != len(sp.tag_positions_m) + 1
                or not (len(sp.tau_s) == len(sp.transfer) == len(sp.k_tx) == len(sp.k_rx) == n_paths)):
            raise ValueError("inconsistent arrays")
        return sp
    except Exception as exc:  # noqa: BLE001 - any damage means "recompute"
        warnings.warn(f"unreadable path cache file {path} ({exc}); removing it and tracing again",
                      CacheWarning, stacklevel=3)
        try:
            path.unlink()
        except OSError:
            pass
        return None


def save_source(directory: Path, sp: SourcePaths) -> Path:
    """Write a path set atomically (temporary file in the same folder, then rename)."""
    directory = Path(directory)
    directory.mkdir(parents=True, exist_ok=True)
    path = _path(directory, sp.source_m)
    fd, tmp = tempfile.mkstemp(dir=directory, prefix=f".{path.stem}.", suffix=".npz.tmp")
    try:
        with os.fdopen(fd, "wb") as fh:
            np.savez(
                fh,
                source_m=np.asarray(sp.source_m, np.float64),
                tag_positions_m=sp.tag_positions_m.astype(np.float64),
                offsets=sp.offsets.astype(np.int64),
                transfer_re=sp.transfer.real.astype(np.float32),
                transfer_im=sp.transfer.imag.astype(np.float32),
                tau_s=sp.tau_s.astype(np.float64),
                k_tx=sp.k_tx.astype(np.float64),
                k_rx=sp.k_rx.astype(np.float64),
            )
        os.replace(tmp, path)
    except BaseException:
        if os.path.exists(tmp):
            os.unlink(tmp)
        raise
    return path
