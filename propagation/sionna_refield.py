"""Sionna's path-solver stages split where the materials enter: geometry kept, fields recomputed.

``PathSolver`` runs three stages: the shoot-and-bounce candidate generator, the image
method (exact specular / refraction chains, their validity) and the field calculator
(each interaction's coefficient from the hit shape's radio material, the transfer
matrices). Only the last reads the materials. :func:`freeze_chunk` runs the first two
exactly as ``PathSolver.__call__`` does (sionna-rt 2.2.0: Sionna's own, unedited
``SBCandidateGenerator``; ``shrink``, ``detach_geometry``, ``ImageMethod``), the field
calculator once, and drops the invalid paths; :func:`field_chunk` runs the field
calculator again on the kept buffer with the scene's materials as they are now. At the
traced materials the result is ``PathSolver``'s, path for path
(``tests/propagation/test_refield.py``).

Like :mod:`propagation.sionna_internals` (whose keyword-only wrappers this module uses),
it touches Sionna's non-public ``PathsBuffer`` and stages, so every entry point calls
:func:`~propagation.sionna_versions.check_versions` first; the two modules are the only
ones that may (``tests/propagation/test_sionna_internals.py`` scans for strays).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from propagation.sionna_internals import (
    collect_paths,
    field_calculator,
    image_method,
    shape_pointers,
)
from propagation.sionna_versions import check_versions

__all__ = ["FrozenChunk", "field_chunk", "freeze_chunk", "path_materials", "set_material"]


@dataclass
class FrozenChunk:
    """One solver call's valid paths, their geometry fixed (Sionna objects, opaque).

    Attributes
    ----------
    buffer : PathsBuffer
        The valid paths after the image method.
    endpoints : tuple
        ``(src_positions, tgt_positions, src_orientations, tgt_orientations)`` as Sionna
        built them for the call (mitsuba arrays).
    samples_per_src : int
        Rays per source of the call (the field calculator's argument).
    n_targets : int
        Real targets; higher target indices are padding receivers, whose paths are dropped.
    """

    buffer: object
    endpoints: tuple
    samples_per_src: int
    n_targets: int


def freeze_chunk(rt_scene, *, n_targets: int, max_depth: int, samples_per_src: int, seed: int,
                 refraction: bool = True) -> FrozenChunk:
    """``PathSolver``'s candidate generator and image method on the scene's placed devices
    (:func:`propagation.sionna_scene.place_devices`), the field calculator once, the
    invalid paths dropped. Arguments as ``PathSolver``'s (synthetic arrays, line of sight
    and specular reflection on, no diffuse reflection or diffraction); ``n_targets`` the
    receivers that are tags (the rest are padding)."""
    import drjit as dr
    from sionna.rt.path_solvers.sb_candidate_generator import SBCandidateGenerator

    check_versions()
    src_pos, src_or, _, _ = rt_scene.sources(True, True)
    tgt_pos, tgt_or, _, _ = rt_scene.targets(True, True)
    dr.make_opaque(src_pos, tgt_pos, src_or, tgt_or)
    buf = SBCandidateGenerator()(
        mi_scene=rt_scene.mi_scene, src_positions=src_pos, tgt_positions=tgt_pos,
        samples_per_src=int(samples_per_src),
        max_num_paths_per_src=int(samples_per_src) * (int(max_depth) + 1),
        max_depth=int(max_depth), los=True, specular_reflection=True, diffuse_reflection=False,
        refraction=bool(refraction), diffraction=False, edge_diffraction=False, seed=int(seed))
    buf.schedule()
    dr.eval()
    buf.shrink()
    buf.detach_geometry()
    buf = image_method(rt_scene.mi_scene, buf, diffraction=False, diffraction_lit_region=True,
                       src_positions=src_pos, tgt_positions=tgt_pos)
    chunk = FrozenChunk(buf, (src_pos, tgt_pos, src_or, tgt_or), int(samples_per_src), int(n_targets))
    _fields(rt_scene, chunk)
    buf.discard_invalid()
    return chunk


def _fields(rt_scene, chunk: FrozenChunk) -> None:
    src_pos, tgt_pos, src_or, tgt_or = chunk.endpoints
    field_calculator(chunk.buffer, wavelength=rt_scene.wavelength, samples_per_src=chunk.samples_per_src,
                     diffraction=False, src_positions=src_pos, tgt_positions=tgt_pos,
                     src_orientations=src_or, tgt_orientations=tgt_or,
                     src_antenna_patterns=rt_scene.tx_array.antenna_pattern.patterns,
                     tgt_antenna_patterns=rt_scene.rx_array.antenna_pattern.patterns)


def field_chunk(rt_scene, chunk: FrozenChunk) -> dict:
    """The kept paths' fields with the scene's current materials: ``collect_paths``'s
    dict (``a``, ``src``, ``tgt``, ``tau``, ``k_tx``, ``k_rx``), padding dropped. The
    antenna arrays must be the ones the chunk was frozen with."""
    check_versions()
    _fields(rt_scene, chunk)
    # every field of the buffer evaluated with the transfer matrices: the calculator also
    # updates others (validity) lazily, and a chain of such updates across trials makes
    # each trial's kernel new (a compile, ~1.3 s) where an evaluated buffer reuses it
    chunk.buffer.schedule()
    out: dict = {k: [] for k in ("a", "src", "tgt", "tau", "k_tx", "k_rx")}
    collect_paths(chunk.buffer, out)
    if out["tgt"]:
        keep = out["tgt"][0] < chunk.n_targets
        out = {k: [v[0][keep]] for k, v in out.items()}
    return out


def path_materials(rt_scene, chunk: FrozenChunk) -> tuple[np.ndarray, list[str]]:
    """Which radio material each kept path meets: ``(hits, names)`` with ``hits`` (P, k)
    bool (path p reflects off or passes through a shape of material ``names[j]``), rows in
    the order of :func:`field_chunk`'s paths (padding dropped alike)."""
    check_versions()
    buf = chunk.buffer
    shapes = list(rt_scene.mi_scene.shapes())
    ptr = shape_pointers(rt_scene.mi_scene)
    names = sorted({s.bsdf().name for s in shapes})
    col = {p: names.index(s.bsdf().name) for p, s in zip(ptr.tolist(), shapes, strict=True)}
    size = buf.buffer_size
    hits = np.zeros((size, len(names)), bool)
    if size:
        sh = np.asarray(buf._shapes.numpy(), np.int64).reshape(size, -1)
        kind = np.asarray(buf._interaction_types.numpy(), np.int64).reshape(size, -1)
        for p, j in col.items():
            hits[:, j] = np.any((sh == p) & (kind != 0), axis=1)
        hits = hits[buf.target_indices.numpy() < chunk.n_targets]
    return hits, names


def set_material(rt_scene, name: str, relative_permittivity: float, conductivity_s_per_m: float) -> None:
    """Set radio material ``name``'s permittivity and conductivity, as kernel inputs (opaque:
    a new value reuses the compiled field calculator)."""
    import drjit as dr
    import mitsuba as mi

    mat = rt_scene.radio_materials[name]
    mat.relative_permittivity = mi.Float(float(relative_permittivity))
    mat.conductivity = mi.Float(float(conductivity_s_per_m))
    dr.make_opaque(mat.relative_permittivity, mat.conductivity)
