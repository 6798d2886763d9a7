"""The tracer's memory budget: what one antenna position costs in a ``PathSolver`` call,
whether one position fits the budget, and the default budget (a quarter of the memory
available). Used by :func:`propagation.pathsolve.trace_paths` to cut its chunks and by the
config checks before a run starts."""

from __future__ import annotations

__all__ = ["bytes_per_source", "memory_shortfall"]


def bytes_per_source(samples_per_src: int, max_depth: int) -> int:
    """Estimated peak memory of one source in a ``PathSolver`` call, bytes.

    Measured on the LLVM backend (sionna-rt 2.2) with ``max_num_paths_per_src = samples *
    (depth + 1)``: 40 sources x 1e5 rays took 2.0 GB at depth 3 and 4.1 GB at depth 5;
    17 sources x 3e5 rays at depth 6 took 8.7 GB. The estimate ``samples * (300 + 300 *
    depth)`` bounds these with a margin.
    """
    return int(samples_per_src * (300 + 300 * max(1, max_depth)))


def memory_shortfall(method: str, max_depth: int, samples_per_src: int, shared_samples_per_src: int,
                     budget_bytes: int, budget_key: str = "memory_budget_bytes",
                     prefix: str = "") -> str | None:
    """Why one antenna position cannot be traced within ``budget_bytes``, or None.

    The tracer chunks sources to fit its memory budget, but one source is the smallest
    chunk: a depth or ray count whose single source exceeds the budget would be traced
    anyway and could take all the memory (``max_depth = 1000`` once took 20.5 GB). The
    message gives the memory one position would need (:func:`bytes_per_source`; with
    ``"shared"`` the candidate buffer of a sharing position is held twice) and the keys
    to change (named with ``prefix``, e.g. ``"tracing."``).
    """
    need = bytes_per_source(samples_per_src, max_depth)
    what = f"{prefix}samples_per_src = {samples_per_src:,}"
    if method == "shared" and 2 * bytes_per_source(shared_samples_per_src, max_depth) > need:
        need = 2 * bytes_per_source(shared_samples_per_src, max_depth)
        what = f"{prefix}shared_samples_per_src = {shared_samples_per_src:,}"
    if need <= budget_bytes:
        return None
    mib = 2.0**20
    return (f"{what} at {prefix}max_depth = {max_depth} needs about {need / mib:,.0f} MiB to trace "
            f"one antenna position, more than {prefix}{budget_key} ({budget_bytes / mib:,.0f} MiB): "
            f"lower the rays or the depth, or raise {prefix}{budget_key} if the machine has the memory")


def _default_budget() -> int:
    try:
        with open("/proc/meminfo") as fh:
            for line in fh:
                if line.startswith("MemAvailable:"):
                    return int(int(line.split()[1]) * 1024 * 0.25)
    except OSError:
        pass
    return 4 * 1024**3
