"""NumPy arrays handed to Dr.Jit, aligned so that the kernels reading them never change.

Dr.Jit maps NumPy memory without copying it and marks memory that is not aligned to its
vector width (32 bytes for 8 float32 lanes) as unaligned; a kernel reading such memory
is generated with another load instruction (``align 1``), so it hashes differently and
is compiled anew. NumPy aligns its allocations to 16 bytes only, so the same computation
compiles one kernel or another depending on where NumPy happened to allocate: Sionna's
shooting kernel (~1 s to compile on 2 cores) and its field kernels would be rebuilt call
after call (how often in a cold default study: CHANGELOG.md, 2026-11-29). Every array
this package hands to Dr.Jit goes through :func:`jit_array` or :func:`jit_points`.
"""

from __future__ import annotations

import numpy as np

__all__ = ["ALIGNMENT_BYTES", "aligned_copy", "jit_array", "jit_points"]

#: Alignment of the arrays handed to Dr.Jit: a cache line, above any vector width.
ALIGNMENT_BYTES = 64


def aligned_copy(values, dtype) -> np.ndarray:
    """A C-contiguous copy of ``values`` in ``dtype`` starting on a 64-byte boundary.

    Parameters
    ----------
    values : array_like
        Any shape.
    dtype : numpy dtype

    Returns
    -------
    numpy.ndarray
        Same shape and values, ``dtype``; ``ctypes.data % ALIGNMENT_BYTES == 0``.
    """
    a = np.asarray(values, dtype=dtype)
    item = a.dtype.itemsize
    buf = np.empty(a.size + ALIGNMENT_BYTES // item, dtype=a.dtype)
    start = (-buf.ctypes.data % ALIGNMENT_BYTES) // item
    out = buf[start:start + a.size].reshape(a.shape)
    out[...] = a
    return out


def jit_array(cls, values, dtype):
    """``cls(values)`` (a Dr.Jit array or tensor type) from an aligned copy in ``dtype``."""
    return cls(aligned_copy(values, dtype))


def jit_points(cls, xyz):
    """``cls`` (``mitsuba.Point3f``, ``Vector3f``) of the rows of ``xyz`` (n, 3), float32."""
    a = np.asarray(xyz, dtype=np.float32).reshape(-1, 3)
    return cls(*(aligned_copy(a[:, k], np.float32) for k in range(3)))
