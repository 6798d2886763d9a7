"""Traced geometry kept, gains recomputed for other wall materials (material calibration).

A wall's permittivity and conductivity change what each path carries, not where it runs
(Sionna's thin-slab model: a refraction does not bend the ray). :func:`freeze_paths`
traces antenna positions to tags once with Sionna's own path-solver stages, keeping each
call's valid paths (:mod:`propagation.sionna_refield`); :func:`refield` recomputes their
transfer matrices with some radio materials' values changed (Sionna's field calculator
on the kept geometry: no ray is shot again), and :func:`refield_gains_db` turns them into
link gains exactly as :func:`propagation.trace_links` does (:func:`link_channels`, the
antenna patterns applied in NumPy).

The tracer is the direct one (``PathSolver``'s stages, ``samples_per_src`` rays per
position, no chain sharing or image-method completion): a re-trace at other materials
would sample other reflection / refraction choices (Sionna's shoot-and-bounce draws them
in proportion to their energy) and so other paths, where a calibration needs the
*same* paths at every trial value. Radio materials are named as the export names them,
``uhf-<material>-t<thickness>`` (:func:`scenes.export.material_bsdf_id`): one per
construction (material and slab thickness).
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass

import numpy as np

from propagation.backend import ensure_variant
from propagation.channels import link_channels
from propagation.pathcache import SourcePaths
from propagation.pathsolve import (
    MAX_SOURCES_PER_CALL,
    TraceOptions,
    padded_target_count,
    padding_point,
)
from propagation.raybudget import bytes_per_source
from propagation.sionna_paths import to_source_paths
from propagation.sionna_refield import field_chunk, freeze_chunk, path_materials, set_material
from propagation.sionna_scene import clear_devices, load_sionna_scene, place_devices

__all__ = ["FrozenPaths", "freeze_paths", "material_shares", "refield", "refield_gains_db"]


@dataclass
class FrozenPaths:
    """Paths from antenna positions to tags whose geometry is kept (:func:`freeze_paths`).

    Attributes
    ----------
    positions_m : numpy.ndarray
        Antenna positions, (n, 3), float64, m.
    tag_positions_m : numpy.ndarray
        Tag positions, (m, 3), float64, m.
    need : numpy.ndarray
        (n, m) bool: the links kept.
    materials : dict
        Radio material name -> (relative permittivity, conductivity [S/m]) as traced.
    rt_scene : sionna.rt.Scene
        The loaded scene the chunks belong to (its materials are restored after each
        :func:`refield`).
    chunks : list
        Per solver call ``(FrozenChunk, position rows, tag columns)``.
    """

    positions_m: np.ndarray
    tag_positions_m: np.ndarray
    need: np.ndarray
    materials: dict
    rt_scene: object
    chunks: list


def freeze_paths(scene, positions_m, tag_positions_m, need=None, *, frequency_hz: float,
                 options: TraceOptions | None = None) -> FrozenPaths:
    """Trace ``positions_m`` (n, 3) to ``tag_positions_m`` (m, 3) [m] and keep the paths'
    geometry (module doc).

    Parameters
    ----------
    scene : scenes.Scene
    need : array_like of bool, optional
        (n, m): the links wanted (default all); a call traces the union of its positions'
        tags.
    frequency_hz : float
        Carrier [Hz]: the materials as traced are evaluated there.
    options : TraceOptions, optional
        ``max_depth``, ``samples_per_src``, ``seed``, ``refraction`` and the memory budget
        are used (the direct tracer's; see the module doc).
    """
    opt = TraceOptions() if options is None else options
    pos = np.asarray(positions_m, np.float64).reshape(-1, 3)
    tags = np.asarray(tag_positions_m, np.float64).reshape(-1, 3)
    need = np.ones((len(pos), len(tags)), bool) if need is None else np.asarray(need, bool)
    ensure_variant()
    rt_scene = load_sionna_scene(scene, frequency_hz, public_api=True)
    materials = {name: (float(m.relative_permittivity[0]), float(m.conductivity[0]))
                 for name, m in rt_scene.radio_materials.items()}
    budget = int(opt.memory_budget_bytes or 2 * 1024**3)
    per_call = max(1, min(MAX_SOURCES_PER_CALL,
                          budget // bytes_per_source(opt.samples_per_src, opt.max_depth, len(tags))))
    chunks = []
    rows_all = np.flatnonzero(need.any(axis=1))
    for c0 in range(0, len(rows_all), per_call):
        rows = rows_all[c0:c0 + per_call]
        cols = np.flatnonzero(need[rows].any(axis=0))
        n_pad = padded_target_count(len(cols)) - len(cols)
        place_devices(rt_scene, pos[rows], np.vstack([tags[cols], np.tile(padding_point(rt_scene), (n_pad, 1))]))
        chunk = freeze_chunk(rt_scene, n_targets=len(cols), max_depth=opt.max_depth,
                             samples_per_src=opt.samples_per_src, seed=opt.seed, refraction=opt.refraction)
        chunks.append((chunk, rows, cols))
    # the arrays stay: the field calculator applies the iso VH arrays the chunks were made with
    clear_devices(rt_scene)
    return FrozenPaths(pos, tags, need, materials, rt_scene, chunks)


def _with_materials(frozen: FrozenPaths, materials: Mapping | None, work):
    unknown = sorted(set(materials or {}) - set(frozen.materials))
    if unknown:
        raise KeyError(f"refield: no radio material {unknown} in the scene "
                       f"(it has {sorted(frozen.materials)})")
    try:
        for name, (eps, sigma) in (materials or {}).items():
            set_material(frozen.rt_scene, name, eps, sigma)
        return work()
    finally:  # the loaded scene is shared (propagation.sionna_scene caches it)
        for name in materials or {}:
            set_material(frozen.rt_scene, name, *frozen.materials[name])


def refield(frozen: FrozenPaths, materials: Mapping | None = None) -> list:
    """Per antenna position its :class:`~propagation.pathcache.SourcePaths` to the tags it
    needs, with ``materials`` ({radio material name: (relative permittivity, conductivity
    [S/m])}) in place of the traced values (None: as traced)."""
    def work():
        out = [SourcePaths.empty(p) for p in frozen.positions_m]
        for chunk, rows, cols in frozen.chunks:
            got = field_chunk(frozen.rt_scene, chunk)
            for r, sp in zip(rows, to_source_paths(got, frozen.positions_m[rows],
                                                   frozen.tag_positions_m[cols],
                                                   frozen.need[np.ix_(rows, cols)]), strict=True):
                out[r] = sp
        return out

    return _with_materials(frozen, materials, work)


def refield_gains_db(frozen: FrozenPaths, materials: Mapping | None, pos_index, tag_index, poses,
                     *, frequency_hz, options: TraceOptions, tag_axes) -> np.ndarray:
    """One-way gain [dB] of links (``pos_index`` into the positions, ``tag_index`` into the
    tags; (L,) each) with antenna poses ``poses`` (L, 6) and channel ``frequency_hz`` (scalar
    or (L,)), as :func:`propagation.trace_links` computes it from the re-fielded paths;
    -inf where no path was kept. ``tag_axes`` (m, 3): :func:`propagation.tracing.tag_dipole_axes`."""
    paths = refield(frozen, materials)
    ch = link_channels(paths, np.asarray(pos_index, np.int64), np.asarray(tag_index, np.int64),
                       np.asarray(poses, np.float64), frozen.tag_positions_m, frequency_hz,
                       options.reader_pattern, options.reader_polarization, options.tag_pattern,
                       np.asarray(tag_axes, np.float64))
    with np.errstate(divide="ignore"):
        return 10.0 * np.log10(ch.h.real ** 2 + ch.h.imag ** 2)


def material_shares(frozen: FrozenPaths) -> dict[str, float]:
    """Per radio material, the share of the kept paths' power (sum of ``|T|^2`` over paths,
    isotropic antennas) carried by paths that meet it (reflect off or pass through);
    shares of different materials overlap (a path meets several)."""
    num: dict[str, float] = dict.fromkeys(frozen.materials, 0.0)
    total = 0.0
    for chunk, _, _ in frozen.chunks:
        got = field_chunk(frozen.rt_scene, chunk)
        if not got["a"]:
            continue
        power = np.sum(np.abs(got["a"][0]) ** 2, axis=(1, 2))
        hits, names = path_materials(frozen.rt_scene, chunk)
        total += float(power.sum())
        for j, name in enumerate(names):
            num[name] += float(power[hits[:, j]].sum())
    return {k: (v / total if total > 0 else 0.0) for k, v in num.items()}
