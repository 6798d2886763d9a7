"""Atomic file writes: a temporary file in the destination folder, then ``os.replace``.

A killed process never leaves a file under the final name that looks complete
(``docs/physics.md``, Conventions). Shared by :mod:`scenes` and :mod:`propagation`
(and usable by :mod:`pipeline`).
"""

from __future__ import annotations

import errno
import os
import tempfile
import zipfile
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

import numpy as np

__all__ = ["atomic_output", "atomic_save_npz", "atomic_write_bytes", "atomic_write_text", "read_npz",
           "write_error"]


@contextmanager
def atomic_output(path, suffix: str = "") -> Iterator[Path]:
    """Yield a temporary path beside ``path``; on success rename it onto ``path``.

    For writers that want a file name (``DataFrame.to_parquet``, ``Figure.savefig``,
    ``numpy.savez``): write to the yielded path inside the ``with`` block. On an
    exception the temporary file is removed and ``path`` is left as it was.

    Parameters
    ----------
    path : str or Path
        Final destination (parent folders are created).
    suffix : str
        Ending of the temporary name, for writers that infer the format from it or
        append one (``numpy.savez`` appends ``.npz`` unless the name ends with it).
    """
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.", suffix=f".tmp{suffix}")
    os.close(fd)
    try:
        yield Path(tmp)
        os.chmod(tmp, 0o644)  # mkstemp creates 0600; give the usual file mode
        os.replace(tmp, path)
    except BaseException as exc:
        Path(tmp).unlink(missing_ok=True)
        err = write_error(exc, path)
        if err is not None:
            raise err from exc
        raise


#: errno values that mean the file system is full (no blocks, or the user's quota).
_FULL = (errno.ENOSPC, errno.EDQUOT)


def write_error(exc: BaseException, path) -> OSError | None:
    """The file-system error behind a failed write of ``path``, named and readable.

    A writer may hide the ``OSError`` it met behind an error of its own (Matplotlib's PDF
    backend, writing into a full disk, once ended in "'Stream' object has no attribute
    'pos'"); the chain of causes is searched for the first ``OSError``. Returns an
    ``OSError`` with its errno and ``path`` as filename when the disk is full (the message
    says so) or when the writer hid the ``OSError``; None otherwise (an ``OSError``
    raised as such, e.g. of a file the writer reads, keeps its own name).
    """
    seen, cur = set(), exc
    while cur is not None and id(cur) not in seen:
        if isinstance(cur, OSError) and cur.errno is not None:
            break
        seen.add(id(cur))
        cur = cur.__cause__ or cur.__context__
    else:
        return None
    full = cur.errno in _FULL
    if not full and isinstance(exc, OSError):
        return None
    reason = cur.strerror or str(cur)
    if full:
        reason = f"{reason} (the disk holding it is full)"
    return OSError(cur.errno, reason, str(path))


def _atomic_write(path, write) -> Path:
    with atomic_output(path) as tmp, open(tmp, "wb") as fh:
        write(fh)
    return Path(path)


def atomic_write_bytes(path, data: bytes) -> Path:
    """Write ``data`` to ``path`` atomically (parent folder created); returns the path."""
    return _atomic_write(path, lambda fh: fh.write(data))


def atomic_write_text(path, text: str, encoding: str = "utf-8") -> Path:
    """Write ``text`` to ``path`` atomically (parent folder created); returns the path."""
    return atomic_write_bytes(path, text.encode(encoding))


def atomic_save_npz(path, compressed: bool = False, **arrays) -> Path:
    """Save ``arrays`` as an NPZ file atomically; returns the path.

    Parameters
    ----------
    path : str or Path
        Destination; written as given (no ``.npz`` suffix is appended).
    compressed : bool
        Use ``numpy.savez_compressed`` instead of ``numpy.savez``.
    **arrays : array_like
        Named arrays; object arrays are refused so that the file loads with
        ``allow_pickle=False``.
    """
    data = {k: np.asarray(v) for k, v in arrays.items()}
    for k, v in data.items():
        if v.dtype == object:
            raise TypeError(f"atomic_save_npz: array {k!r} has dtype object (would need pickle)")
    save = np.savez_compressed if compressed else np.savez
    return _atomic_write(path, lambda fh: save(fh, **data))


class _NamedNpz:
    """A read-only view of an open ``NpzFile`` whose every failure names the file."""

    def __init__(self, z, path):
        self._z, self._path = z, path
        self.files = list(z.files)

    def __contains__(self, key):
        return key in self._z

    def __iter__(self):
        return iter(self.files)

    def keys(self):
        return self._z.keys()

    def __getitem__(self, key):
        if key not in self._z:
            raise KeyError(f"{self._path}: no array {key!r} (it holds {self.files})")
        try:
            return self._z[key]
        except (ValueError, OSError, EOFError, zipfile.BadZipFile) as exc:
            # a pickled (object) array among them: refused, not unpickled
            raise ValueError(f"{self._path}: array {key!r} cannot be read: {exc}") from None


@contextmanager
def read_npz(path) -> Iterator[_NamedNpz]:
    """``numpy.load`` of an NPZ file without pickles, every error naming ``path``.

    A file that is no NPZ, or an array stored as pickled objects (refused: unpickling runs
    code), raises ``ValueError`` naming the file (and the array); a missing array raises
    ``KeyError`` naming both; a missing file stays ``FileNotFoundError``.
    """
    try:
        z = np.load(path, allow_pickle=False)
    except FileNotFoundError:
        raise
    except (ValueError, OSError, EOFError, zipfile.BadZipFile) as exc:
        raise ValueError(f"{path}: not a readable NPZ file: {exc}") from None
    if not isinstance(z, np.lib.npyio.NpzFile):
        raise ValueError(f"{path}: not an NPZ file (a single array)")
    with z:
        yield _NamedNpz(z, path)
