"""Dr.Jit / Mitsuba backend selection: CUDA when a GPU is usable, LLVM on the CPU.

Nothing here runs at import. :func:`select_variant` is the one place where a Mitsuba
variant is chosen; every module of :mod:`propagation` that needs Sionna calls it (through
:func:`ensure_variant`) before importing ``sionna.rt``, because importing ``sionna.rt``
first would pick a variant on its own.

The CPU variant (``llvm_ad_mono_polarized``) loads the system libLLVM at the first
kernel. Debian 12's default LLVM 15 aborts Dr.Jit 1.5 with ``LLVM ERROR: Cannot select
... fminimum`` (see ``docs/physics.md``, "Dr.Jit on the CPU"), so :func:`find_libllvm` only accepts
LLVM >= 16 and :func:`select_variant` sets ``DRJIT_LIBLLVM_PATH`` before ``drjit`` is
imported.
"""

from __future__ import annotations

import glob
import logging
import os
import re
import sys
from pathlib import Path

__all__ = [
    "CUDA_VARIANT",
    "LLVM_VARIANT",
    "MIN_LLVM_MAJOR",
    "BackendError",
    "backend_info",
    "ensure_variant",
    "find_libllvm",
    "select_variant",
    "set_deterministic",
]

logger = logging.getLogger(__name__)

#: Mitsuba variant used on an NVIDIA GPU.
CUDA_VARIANT = "cuda_ad_mono_polarized"
#: Mitsuba variant used on the CPU (needs libLLVM >= 16).
LLVM_VARIANT = "llvm_ad_mono_polarized"
#: Oldest LLVM major version Dr.Jit 1.5 runs with here (15 aborts, see module docstring).
MIN_LLVM_MAJOR = 16

_LIB_DIRS = (
    "/usr/lib/x86_64-linux-gnu",
    "/usr/lib/aarch64-linux-gnu",
    "/usr/lib64",
    "/usr/lib",
    "/usr/local/lib",
)

_state: dict = {}


class BackendError(RuntimeError):
    """No usable Dr.Jit backend (e.g. no libLLVM >= 16 for the CPU variant)."""


def _llvm_major(path: str) -> int | None:
    m = re.search(r"libLLVM[-.]?(\d+)", os.path.basename(path))
    if m:
        return int(m.group(1))
    m = re.search(r"llvm-(\d+)", path)
    return int(m.group(1)) if m else None


def find_libllvm() -> str:
    """Path of a libLLVM shared library that Dr.Jit 1.5 can use.

    ``DRJIT_LIBLLVM_PATH`` wins when it is set and names an existing file of LLVM >= 16.
    Otherwise the multiarch library directories (and ``/usr/lib/llvm-*/lib``) are
    searched, newest major version first. LLVM 14 and 15 are never picked.

    Returns
    -------
    str
        Absolute path of the library.

    Raises
    ------
    BackendError
        If none is found; the message says what to install (``apt-get install libllvm19``).
    """
    env = os.environ.get("DRJIT_LIBLLVM_PATH")
    if env:
        major = _llvm_major(env)
        if os.path.isfile(env) and (major is None or major >= MIN_LLVM_MAJOR):
            return env
        logger.warning(
            "DRJIT_LIBLLVM_PATH=%s is missing or LLVM < %d; searching the system instead",
            env, MIN_LLVM_MAJOR,
        )
    candidates: list[tuple[int, str]] = []
    patterns = [f"{d}/libLLVM-*.so*" for d in _LIB_DIRS] + [f"{d}/libLLVM.so.*" for d in _LIB_DIRS]
    patterns += ["/usr/lib/llvm-*/lib/libLLVM*.so*"]
    for pattern in patterns:
        for path in glob.glob(pattern):
            major = _llvm_major(path)
            if major is not None and major >= MIN_LLVM_MAJOR and os.path.isfile(path):
                candidates.append((major, path))
    if not candidates:
        raise BackendError(
            f"no libLLVM >= {MIN_LLVM_MAJOR} found (searched DRJIT_LIBLLVM_PATH and "
            f"{', '.join(_LIB_DIRS)}); Dr.Jit's CPU backend needs it: install it with "
            "`apt-get install libllvm19` (Debian/Ubuntu) or point DRJIT_LIBLLVM_PATH at a "
            "libLLVM-16..19 shared library. LLVM 15 crashes Dr.Jit 1.5 ('Cannot select "
            "... fminimum')."
        )
    # Newest major first; among equal majors prefer the shortest (unversioned) name.
    candidates.sort(key=lambda c: (-c[0], len(c[1])))
    return str(Path(candidates[0][1]))


def _cuda_usable() -> bool:
    import drjit as dr

    try:
        return bool(dr.has_backend(dr.JitBackend.CUDA))
    except Exception:  # noqa: BLE001 - any failure means "not usable"
        return False


def select_variant(prefer: str = "auto") -> str:
    """Choose and set the Mitsuba variant (once per process).

    Parameters
    ----------
    prefer : {"auto", "cuda", "llvm"}
        ``"auto"`` tries CUDA and falls back to LLVM; ``"cuda"`` requires a GPU;
        ``"llvm"`` forces the CPU.

    Returns
    -------
    str
        The variant set, ``"cuda_ad_mono_polarized"`` or ``"llvm_ad_mono_polarized"``.

    Raises
    ------
    ValueError
        For an unknown ``prefer``.
    BackendError
        If ``prefer="cuda"`` and no GPU is usable, or the CPU variant has no libLLVM.

    Notes
    -----
    A second call returns the variant already chosen (Mitsuba cannot switch variants
    safely once Sionna is imported); asking for a different one then raises.
    """
    if prefer not in ("auto", "cuda", "llvm"):
        raise ValueError(f"prefer must be 'auto', 'cuda' or 'llvm', got {prefer!r}")
    if "variant" in _state:
        chosen = _state["variant"]
        if (prefer == "cuda" and chosen != CUDA_VARIANT) or (
            prefer == "llvm" and chosen != LLVM_VARIANT
        ):
            raise BackendError(
                f"variant {chosen!r} already selected in this process; cannot switch to {prefer!r}"
            )
        return chosen
    libllvm = None
    if "drjit" not in sys.modules:
        try:
            libllvm = find_libllvm()
            os.environ["DRJIT_LIBLLVM_PATH"] = libllvm
        except BackendError:
            if prefer == "llvm":
                raise
            libllvm = None
    else:
        libllvm = os.environ.get("DRJIT_LIBLLVM_PATH")
    import mitsuba as mi

    variant = None
    if prefer in ("auto", "cuda") and _cuda_usable():
        try:
            mi.set_variant(CUDA_VARIANT)
            variant = CUDA_VARIANT
        except Exception as exc:  # noqa: BLE001
            if prefer == "cuda":
                raise BackendError(f"CUDA variant failed to start: {exc}") from exc
            logger.warning("CUDA variant unusable (%s); falling back to LLVM", exc)
    elif prefer == "cuda":
        raise BackendError("prefer='cuda' but Dr.Jit finds no usable CUDA device")
    if variant is None:
        if libllvm is None:
            find_libllvm()  # raises with the install hint
        mi.set_variant(LLVM_VARIANT)
        variant = LLVM_VARIANT
    _state["variant"] = variant
    _state["libllvm"] = libllvm
    logger.info("Mitsuba variant %s (libLLVM %s)", variant, libllvm)
    return variant


def ensure_variant() -> str:
    """The selected variant, selecting one with ``prefer="auto"`` if none was chosen."""
    return _state.get("variant") or select_variant("auto")


def set_deterministic(enabled: bool) -> int:
    """Make cold traces bit-reproducible by tracing on one Dr.Jit thread.

    Sionna RT 2.2's path solver on the multi-threaded LLVM backend does not find the
    same path set twice: two identical calls (same scene, sources, rays and seed) on
    ``corridor_lab`` differed in about one path per thousand, which moved 514 of 1440
    link gains, by up to 3 dB. With one thread, repeated calls are identical. Cached
    traces are always reused exactly, so this only matters for traces made afresh.

    Parameters
    ----------
    enabled : bool
        True: one thread (on 2 cores, tracing takes about twice as long). False: the
        thread count Dr.Jit chose at start-up.

    Raises
    ------
    BackendError
        ``enabled`` on the CUDA variant: one thread cannot make GPU traces reproducible.

    Returns
    -------
    int
        The Dr.Jit thread count now in force.
    """
    if ensure_variant() == CUDA_VARIANT and enabled:
        raise BackendError(
            "deterministic tracing needs the CPU variant (llvm_ad_mono_polarized): on CUDA "
            "the path solver is not bit-reproducible whatever the thread count (measured on "
            "an H200: two identical cold traces of 6 poses x 24 corridor_lab tags differed "
            "in 93 of 144 gains, by up to 3e-4 dB); select 'llvm' before tracing")
    import drjit as dr

    default = _state.setdefault("default_threads", int(dr.thread_count()))
    dr.set_thread_count(1 if enabled else default)
    _state["deterministic"] = bool(enabled)
    return int(dr.thread_count())


def backend_info() -> dict:
    """What the run manifest records about the ray-tracing backend.

    Returns
    -------
    dict
        ``variant`` (None until :func:`select_variant` ran), ``libllvm_path``,
        ``mitsuba_version``, ``drjit_version``, ``sionna_rt_version`` (None when the
        package is not importable or not yet imported).
    """
    from importlib import metadata

    def _ver(dist: str) -> str | None:
        try:
            return metadata.version(dist)
        except metadata.PackageNotFoundError:
            return None

    return {
        "variant": _state.get("variant"),
        "deterministic": bool(_state.get("deterministic", False)),
        "libllvm_path": _state.get("libllvm") or os.environ.get("DRJIT_LIBLLVM_PATH"),
        "mitsuba_version": _ver("mitsuba"),
        "drjit_version": _ver("drjit"),
        "sionna_rt_version": _ver("sionna-rt"),
    }
