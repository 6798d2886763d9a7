"""Checks of a study against this process, run before the run directory is made.

:func:`check_before_run` is what ``rfidstudy run`` checks once the config is read: the
file behind the scene its source checks, an occupancy-grid map
(:func:`scenes.catalog.check_source`), and the
tracer's memory budget against the address-space limit (``ulimit -v``) the process
runs under (:func:`check_address_space`). Under a limit below the budget the tracer
dies with a segmentation fault (exit 139) and no message, so the check comes first.
"""

from __future__ import annotations

from pipeline.config import ConfigError
from scenes.catalog import check_source

__all__ = ["STUDY_ADDRESS_SPACE_MIB", "address_space_limit", "check_address_space", "check_before_run"]

#: Address space a study maps beside the tracer's budget [MiB]: the interpreter, NumPy,
#: Dr.Jit's LLVM backend with its threads, the robot's particle filters. Measured on
#: configs/tiny.toml (2 cores): its peak is 3.1 GiB with any ``memory_budget_mb`` from 256
#: to 4096; under a limit of 3.0 GiB it stops with a MemoryError (budget 256 MiB), under
#: 2.3 GiB the tracer segfaults (budget 1024 MiB).
STUDY_ADDRESS_SPACE_MIB = 3072


def address_space_limit() -> int | None:
    """This process's soft address-space limit (``RLIMIT_AS``, ``ulimit -v``) [bytes].

    Returns
    -------
    int or None
        None where there is none (unlimited) or the platform has no such limit.
    """
    try:
        import resource
    except ImportError:  # not a POSIX system
        return None
    soft, _ = resource.getrlimit(resource.RLIMIT_AS)
    return None if soft == resource.RLIM_INFINITY or soft < 0 else int(soft)


def check_address_space(budget_mb: float, limit_bytes: int | None = None) -> None:
    """Stop a study whose tracer budget cannot fit the process's address-space limit.

    Parameters
    ----------
    budget_mb : float
        ``tracing.memory_budget_mb`` [MiB].
    limit_bytes : int, optional
        The limit [bytes]; default :func:`address_space_limit` (None: no limit).

    Raises
    ------
    pipeline.config.ConfigError
        One line naming ``tracing.memory_budget_mb``, its value, the limit and the
        largest budget that fits (or that none does: the limit must be raised), when
        ``budget_mb`` + :data:`STUDY_ADDRESS_SPACE_MIB` exceeds the limit.
    """
    limit = address_space_limit() if limit_bytes is None else limit_bytes
    if limit is None:
        return
    limit_mib = limit / 2**20
    need_mib = budget_mb + STUDY_ADDRESS_SPACE_MIB
    if need_mib <= limit_mib:
        return
    fits = int(limit_mib - STUDY_ADDRESS_SPACE_MIB)
    what = (f"lower tracing.memory_budget_mb to at most {fits:,} or raise the limit" if fits >= 64 else
            f"raise the limit to at least {need_mib:,.0f} MiB (no tracing.memory_budget_mb fits under it)")
    raise ConfigError(f"tracing.memory_budget_mb = {budget_mb:,.0f} MiB plus the "
                      f"{STUDY_ADDRESS_SPACE_MIB:,} MiB a study maps beside it exceed this process's "
                      f"address-space limit (ulimit -v) of {limit_mib:,.0f} MiB: {what}")


def check_before_run(cfg) -> None:
    """What ``rfidstudy run`` checks before it makes the run directory.

    Parameters
    ----------
    cfg : pipeline.config.StudyConfig
        The resolved study config.

    Raises
    ------
    pipeline.config.ConfigError
        The budget against the address-space limit (:func:`check_address_space`).
    scenes.rosmap.RosMapError, scenes.spec.SpecError, FileNotFoundError
        A bad file behind ``cfg.scene`` (an occupancy-grid map).
    """
    check_address_space(cfg.tracing.memory_budget_mb)

    check_source(cfg.scene)
