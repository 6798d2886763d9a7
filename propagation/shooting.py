"""Sionna's shoot-and-bounce candidate generator with one compiled kernel for any number
of targets.

Sionna RT 2.2.0's ``SBCandidateGenerator._shoot_and_bounce_loop`` tests every target
from every bounce in a symbolic loop whose condition is ``t < num_targets``, with
``num_targets = dr.shape(tgt_positions)[1]`` a Python integer: Dr.Jit bakes it into the
kernel as a literal, so every new number of targets compiles the shooting kernel anew
(7,900 operations, 0.9-1.8 s of LLVM on 2 cores). The truth's lone traces (stage
``truth_traces``), each against another number of tag sites, compiled it 7 times in a
cold default study even with the targets padded to quarter octaves
(:func:`propagation.pathsolve.padded_target_count`), 9.5 CPU-s in all.

:func:`candidate_generator` returns a generator whose loop is Sionna's own source with
that one line changed to ``dr.opaque(mi.UInt, ...)``: the count becomes a kernel input,
and one kernel serves every target count. Nothing else changes: the loop body, its
random samples (drawn per ray, not per target) and the candidates it stores are Sionna's,
so the candidates equal the unpatched generator's (a test compares them bit for bit).

The rewrite is made once, when first asked for (never at import), from the installed
Sionna's source; if that line is not found exactly once (another Sionna version), it
raises rather than run anything else.
"""

from __future__ import annotations

import ast
import inspect
import linecache
import textwrap

__all__ = ["OPAQUE_COUNT_LINE", "TARGET_COUNT_LINE", "candidate_generator"]

#: The line of Sionna's shooting loop that makes the target count a literal.
TARGET_COUNT_LINE = "num_targets = dr.shape(tgt_positions)[1]"
#: What it becomes: the same count as an opaque (kernel input) value.
OPAQUE_COUNT_LINE = "num_targets = dr.opaque(mi.UInt, dr.shape(tgt_positions)[1])"

_CLASS: list = []  # the generator class, built once


def _opaque_loop():
    """Sionna's ``_shoot_and_bounce_loop`` recompiled with :data:`OPAQUE_COUNT_LINE`."""
    from sionna.rt.path_solvers import sb_candidate_generator as sbm

    module_src = inspect.getsource(sbm)
    tree = ast.parse(module_src)
    node = next(f for c in tree.body if isinstance(c, ast.ClassDef)
                and c.name == "SBCandidateGenerator" for f in c.body
                if isinstance(f, ast.FunctionDef) and f.name == "_shoot_and_bounce_loop")
    first = min([node.lineno] + [d.lineno for d in node.decorator_list])
    lines = module_src.splitlines(keepends=True)[first - 1:node.end_lineno]
    src = textwrap.dedent("".join(lines))
    if src.count(TARGET_COUNT_LINE) != 1:
        raise RuntimeError(
            f"sionna.rt {getattr(sbm, '__file__', '')}: the shooting loop's line "
            f"{TARGET_COUNT_LINE!r} was found {src.count(TARGET_COUNT_LINE)} times, expected "
            "once; this module rewrites sionna-rt 2.2.0 (constraints.txt)")
    src = src.replace(TARGET_COUNT_LINE, OPAQUE_COUNT_LINE)
    # @dr.syntax reads the function's source back through linecache
    filename = f"<rfidstudy: {sbm.__name__}._shoot_and_bounce_loop, opaque target count>"
    linecache.cache[filename] = (len(src), None, src.splitlines(keepends=True), filename)
    local: dict = {}
    exec(compile(src, filename, "exec"), vars(sbm), local)  # noqa: S102 - Sionna's own code
    return local["_shoot_and_bounce_loop"]


def candidate_generator():
    """A new ``SBCandidateGenerator`` whose shooting kernel takes the target count as an
    input (module doc); called like Sionna's."""
    if not _CLASS:
        from sionna.rt.path_solvers.sb_candidate_generator import SBCandidateGenerator

        _CLASS.append(type("OpaqueTargetsCandidateGenerator", (SBCandidateGenerator,),
                           {"_shoot_and_bounce_loop": _opaque_loop(),
                            "__module__": __name__,
                            "__doc__": "SBCandidateGenerator, target count opaque "
                                       "(propagation.shooting)."}))
    return _CLASS[0]()
