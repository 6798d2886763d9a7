"""Checks of the whole study, run before the first stage that traces anything
(:func:`pipeline.engine.study.run_study`'s ``checks``): a config that cannot work on its scene
fails with one line naming the key, before any tracing."""

from __future__ import annotations

import numpy as np

from pipeline.config import ConfigError
from pipeline.stages.common import load_scene
from pipeline.studyscene import resolve_cache_dir, study_route
from propagation.sionna_internals import TESTED_VERSIONS, SionnaVersionError
from scenes.geometry import in_free_space, solid_material_at

__all__ = ["CHECKS", "check_antenna_mounts", "check_cache_dir", "check_memory_budget",
           "check_tracer_versions"]


def check_antenna_mounts(ctx) -> None:
    """Every antenna mount lies in the scene's free space for a robot on the route.

    The robot stands at points every 0.5 m along the study route (both headings, as the
    tour drives up and back); each antenna's world position must be free
    (:func:`scenes.geometry.is_free`: inside the free volume, outside every solid).

    Raises
    ------
    pipeline.config.ConfigError
        Naming the key (``robot.antennas[0].z_m``), its value, the antenna and where it
        would be: above the ceiling, below the floor, or inside a solid.
    """
    cfg = ctx.config
    sc = load_scene(ctx)
    route = study_route(sc, cfg)
    lo, hi = sc.bounds_m
    if route is None or len(route) < 2:
        xy = np.array([(lo[:2] + hi[:2]) / 2.0])
        heading = np.zeros(1)
        check_xy = False
    else:
        pts, hd = [], []
        for a, b in zip(route[:-1], route[1:], strict=True):
            seg = b - a
            n = max(1, int(np.ceil(np.hypot(*seg) / 0.5)))
            t = np.linspace(0.0, 1.0, n + 1)
            pts.append(a + t[:, None] * seg)
            hd.append(np.full(n + 1, np.arctan2(seg[1], seg[0])))
        xy = np.concatenate(pts * 2)
        heading = np.concatenate(hd + [h + np.pi for h in hd])
        check_xy = True
    boxes = sc.free_space_m if getattr(sc, "free_space_m", None) is not None and len(sc.free_space_m) \
        else sc.bounds_m[None]
    z_top, z_bottom = float(np.max(boxes[:, 1, 2])), float(np.min(boxes[:, 0, 2]))
    c, s_ = np.cos(heading), np.sin(heading)
    for i, a in enumerate(cfg.robot.antennas):
        key = f"robot.antennas[{i}]"
        if a.z_m >= z_top:
            raise ConfigError(f"{key}.z_m = {a.z_m}: antenna {a.name!r} would be above the ceiling "
                              f"of scene {sc.name!r} (free space ends at z = {z_top:.3g} m)")
        if a.z_m <= z_bottom:
            raise ConfigError(f"{key}.z_m = {a.z_m}: antenna {a.name!r} would be below the floor "
                              f"of scene {sc.name!r} (free space starts at z = {z_bottom:.3g} m)")
        if not check_xy:
            continue
        world = np.column_stack([xy[:, 0] + c * a.x_m - s_ * a.y_m,
                                 xy[:, 1] + s_ * a.x_m + c * a.y_m, np.full(len(xy), a.z_m)])
        free = in_free_space(sc, world)
        mats = np.full(len(world), "", dtype=object)
        if np.any(free):
            mats[free] = solid_material_at(sc, world[free])
        bad = np.flatnonzero(~free | (mats != ""))
        if len(bad):
            j = bad[0]
            where = (f"inside {mats[j]!r} solid geometry" if free[j]
                     else "outside the scene's free space")
            raise ConfigError(
                f"{key} ({a.name!r}: x_m = {a.x_m}, y_m = {a.y_m}, z_m = {a.z_m}): with the robot "
                f"on the route at ({xy[j, 0]:.2f}, {xy[j, 1]:.2f}) m the antenna would be at "
                f"({world[j, 0]:.2f}, {world[j, 1]:.2f}, {world[j, 2]:.2f}) m, {where} of scene "
                f"{sc.name!r}")


#: The checks of the full study, run before the first stage that is not ``always``
#: (after the scene stage).
def check_tracer_versions(ctx) -> None:
    """The fast tracer (``tracing.method = "shared"``) on the tested sionna-rt, mitsuba and
    drjit only (:data:`propagation.sionna_internals.TESTED_VERSIONS`, read from the package
    metadata without importing them): an untested version stops the study here, before
    the tour, with the one line the tracer itself would give at the reads stage."""
    from importlib.metadata import PackageNotFoundError, version


    if ctx.config.tracing.method != "shared":
        return
    got = {}
    for pkg in TESTED_VERSIONS:
        try:
            got[pkg] = version(pkg)
        except PackageNotFoundError:
            got[pkg] = "not installed"
    if got != TESTED_VERSIONS:
        have = ", ".join(f"{k} {v}" for k, v in got.items())
        want = ", ".join(f"{k} {v}" for k, v in TESTED_VERSIONS.items())
        raise ConfigError(str(SionnaVersionError(
            f"tracing.method = \"shared\" uses Sionna internals tested only with {want}, but "
            f"{have} is installed: set tracing.method = \"direct\" (Sionna's public API "
            "only) or install the tested versions (constraints.txt)")))


def check_cache_dir(ctx) -> None:
    """The propagation cache (:func:`pipeline.studyscene.resolve_cache_dir`) is a
    directory this process can write, made here if missing: a file there, a place under
    /proc or a read-only one stops the study before the tour, naming where the path came
    from (``tracing.cache_dir``, ``$RFIDSTUDY_CACHE`` or the default) and the path."""
    import os


    if ctx.config.tracing.cache_dir:
        src = f"tracing.cache_dir = {ctx.config.tracing.cache_dir!r}"
    elif os.environ.get("RFIDSTUDY_CACHE"):
        src = f"$RFIDSTUDY_CACHE = {os.environ['RFIDSTUDY_CACHE']!r}"
    else:
        src = "the default propagation cache (set tracing.cache_dir or $RFIDSTUDY_CACHE)"
    try:
        path = resolve_cache_dir(ctx.config)
    except (OSError, RuntimeError) as exc:
        raise ConfigError(f"{src}: cannot be resolved: {exc}") from None
    if path.exists() and not path.is_dir():
        raise ConfigError(f"{src}: {path} is a file, not a directory (the propagation cache is a "
                          "directory of traces)")
    try:
        path.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise ConfigError(f"{src}: cannot make the propagation cache directory {path}: "
                          f"{exc.strerror or exc}") from None
    if not os.access(path, os.W_OK | os.X_OK):
        raise ConfigError(f"{src}: the propagation cache directory {path} is not writable")


def check_memory_budget(ctx) -> None:
    """``tracing.memory_budget_mb`` fits this machine's memory: the tracer fills its budget
    (up to 128 antenna positions per call), so a budget above the physical memory would be
    taken at its word and exhaust the machine instead of chunking."""
    import os

    try:
        total = os.sysconf("SC_PAGE_SIZE") * os.sysconf("SC_PHYS_PAGES")
    except (ValueError, OSError):  # not reported on this platform: nothing to check against
        return
    budget = ctx.config.tracing.memory_budget_mb * 2**20
    if total > 0 and budget > total:
        raise ConfigError(f"tracing.memory_budget_mb = {ctx.config.tracing.memory_budget_mb:g}: more "
                          f"than this machine's memory ({total / 2**20:,.0f} MiB); lower it")


CHECKS = (check_tracer_versions, check_cache_dir, check_memory_budget, check_antenna_mounts)
