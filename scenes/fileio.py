"""Atomic file writes: a temporary file in the destination folder, then ``os.replace``.

A killed process never leaves a file under the final name that looks complete
(``docs/physics.md``, Conventions). Shared by :mod:`scenes` and :mod:`propagation`
(and usable by :mod:`pipeline`).
"""

from __future__ import annotations

import os
import tempfile
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

import numpy as np

__all__ = ["atomic_output", "atomic_save_npz", "atomic_write_bytes", "atomic_write_text"]


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
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise


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
