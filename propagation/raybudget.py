"""The tracer's memory budget: what one antenna position costs in a ``PathSolver`` call,
whether one position fits the budget, and the default budget (a quarter of the memory
available). Used by :func:`propagation.pathsolve.trace_paths` to cut its chunks and by the
config checks before a run starts."""

from __future__ import annotations

import numpy as np

__all__ = ["TARGETS_PER_CAP", "bytes_per_source", "candidate_cap_limit", "cap_on_grid", "first_candidate_cap",
           "memory_shortfall"]


#: Targets per base candidate cap (:func:`first_candidate_cap`'s ``targets_per_cap``).
TARGETS_PER_CAP = 64


def bytes_per_source(samples_per_src: int, max_depth: int, n_targets: int = 1) -> int:
    """Estimated peak memory of one source in a ``PathSolver`` call, bytes.

    Measured on the LLVM backend (sionna-rt 2.2) with ``max_num_paths_per_src = samples *
    (depth + 1)``: 40 sources x 1e5 rays took 2.0 GB at depth 3 and 4.1 GB at depth 5;
    17 sources x 3e5 rays at depth 6 took 8.7 GB. The estimate ``samples * (300 + 300 *
    depth)`` bounds these with a margin. The candidate buffer is the cap, which grows by one
    base cap per :data:`TARGETS_PER_CAP` targets of the call (:func:`first_candidate_cap`),
    so the estimate is multiplied by ``ceil(n_targets / 64)``: without it a call with
    1,476 tags (a real warehouse map at the default settings) took 23 GB where 1 GB was
    planned, and the kernel killed the run.
    """
    per_cap = int(samples_per_src * (300 + 300 * max(1, max_depth)))
    return per_cap * max(1, -(-int(n_targets) // TARGETS_PER_CAP))


def candidate_cap_limit(n_sources: int, max_depth: int) -> int:
    """The largest candidate cap per source a shooting call of ``n_sources`` can take:
    Sionna indexes its candidate buffer (cap x sources rows, depth + 1 steps) in uint32."""
    return (2**31 - 1) // max(1, int(n_sources) * (int(max_depth) + 1))


def cap_on_grid(count: int, table: int, limit: int) -> int:
    """A candidate cap >= ``count`` on a quarter-octave grid (at most 25 % more: the cap
    is a literal of Sionna's shooting kernel, so every new value compiles it again), never
    across Sionna's smallest table of chain hashes ``table`` (a cap up to it keeps the
    table, hence the candidates, as they are) nor past ``limit`` where ``count`` is not."""
    c = max(1, int(count))
    step = 1 << max(0, c.bit_length() - 3)
    grid = -(-c // step) * step
    if c <= table:
        grid = min(grid, table)
    return max(c, min(grid, limit))


def first_candidate_cap(samples_per_src: int, max_depth: int, n_targets: int,
                        needed_per_target: float, table: int, limit: int,
                        targets_per_cap: int = 64, headroom: float = 1.5) -> int:
    """The first candidate cap per source of a shooting call
    (:func:`propagation.sionna_internals.shoot_candidates`).

    ``PathSolver``'s ``samples_per_src * (max_depth + 1)``, once more per
    ``targets_per_cap`` targets; at least ``n_targets`` (lines of sight are stored
    uncapped); and ``headroom`` x what earlier calls needed per target x ``n_targets``,
    kept on the grid within the hash table the base cap gives and within ``limit``
    (:func:`cap_on_grid`), so it changes neither the candidates nor whether a call runs.
    """
    base = int(samples_per_src) * (int(max_depth) + 1) * max(1, -(-int(n_targets) // targets_per_cap))
    learned = int(np.ceil(headroom * float(needed_per_target) * int(n_targets)))
    keep = max(base, table)  # the hash table the base cap gives
    grown = min(cap_on_grid(learned, keep, limit), keep, limit) if learned > base else 0
    return max(base, grown, int(n_targets))


def memory_shortfall(method: str, max_depth: int, samples_per_src: int, shared_samples_per_src: int,
                     budget_bytes: int, budget_key: str = "memory_budget_bytes",
                     prefix: str = "", n_targets: int = 1) -> str | None:
    """Why one antenna position cannot be traced within ``budget_bytes``, or None.

    The tracer chunks sources to fit its memory budget, but one source is the smallest
    chunk: a depth or ray count whose single source exceeds the budget would be traced
    anyway and could take all the memory (``max_depth = 1000`` once took 20.5 GB). The
    message gives the memory one position would need (:func:`bytes_per_source`; with
    ``"shared"`` the candidate buffer of a sharing position is held twice; ``n_targets``
    tags in the call) and the keys to change (named with ``prefix``, e.g. ``"tracing."``).
    """
    need = bytes_per_source(samples_per_src, max_depth, n_targets)
    what = f"{prefix}samples_per_src = {samples_per_src:,}"
    if method == "shared" and 2 * bytes_per_source(shared_samples_per_src, max_depth, n_targets) > need:
        need = 2 * bytes_per_source(shared_samples_per_src, max_depth, n_targets)
        what = f"{prefix}shared_samples_per_src = {shared_samples_per_src:,}"
    if n_targets > TARGETS_PER_CAP:
        what += f" with {n_targets:,} tags"
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
