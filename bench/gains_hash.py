"""A sha256 of the study tracer's gains on a fixed set of links, traced deterministically.

Traces 9 antenna poses x 16 tags of ``corridor_lab`` with the default study's tracing
options (:func:`pipeline.studyscene.trace_options` of a default
:class:`pipeline.config.StudyConfig`), on one Dr.Jit thread
(:func:`propagation.set_deterministic`) and without a path cache, and prints the sha256
of the gains (float64, C order) with the wall time. Six poses lie within the sharing
radius of each other and three stand alone, so both halves of the sharing tracer run.
A refactoring that must not change the truth leaves the hash unchanged.

Usage::

    .venv/bin/python bench/gains_hash.py [--set tracing.min_samples_per_position=0 ...]

(``--set``: config overrides, as ``rfidstudy run --set``; e.g. the minimum ray budget off
gives the hash of the tracer without it, whose six shared poses draw from fewer rays.)
"""

from __future__ import annotations

import dataclasses
import hashlib
import time

import numpy as np

import propagation
import scenes
from pipeline.config import StudyConfig
from pipeline.studyscene import trace_options


def fixed_links(scene) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Poses (9, 4) [m, rad], tag positions (16, 3) [m] and tag normals (16, 3)."""
    near = [[5.0 + 0.3 * k, 1.2, 1.0, 0.5 * k - 1.0] for k in range(6)]  # within 1 m: shared
    alone = [[12.0, 0.9, 0.8, 0.3], [18.0, 1.5, 1.2, 3.0], [22.0, 1.2, 1.0, -2.0]]
    return np.array(near + alone), scene.tags.positions_m[:16], scene.tags.normals[:16]


def main() -> None:
    import argparse

    from pipeline.apps.cli import resolve_target

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--set", action="append", default=[], metavar="KEY=VALUE")
    args = ap.parse_args()
    propagation.select_variant("llvm")
    propagation.set_deterministic(True)
    scene = scenes.load("corridor_lab")
    poses, tags, normals = fixed_links(scene)
    opts = trace_options(resolve_target(None, args.set) if args.set else StudyConfig())
    t0 = time.perf_counter()
    if dataclasses.is_dataclass(opts):
        links = propagation.trace_links(scene, poses, tags, opts, tag_normals=normals)
    else:
        links = propagation.trace_links(scene, poses, tags, tag_normals=normals, **opts)
    wall = time.perf_counter() - t0
    gain = np.ascontiguousarray(links.gain, dtype=np.float64)
    print(f"gains sha256 {hashlib.sha256(gain.tobytes()).hexdigest()[:16]} "
          f"({gain.shape[0]} poses x {gain.shape[1]} tags, {wall:.1f} s, "
          f"{links.n_solver_calls} calls)")


if __name__ == "__main__":
    main()
