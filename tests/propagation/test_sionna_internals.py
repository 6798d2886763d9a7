"""propagation.sionna_internals: the version guard, the hash-checked edits of Sionna's
code (the candidate generator with an opaque target count gives Sionna's candidates with
one kernel), and no Sionna internals anywhere else in the project's packages."""

from __future__ import annotations

import ast
import re
from pathlib import Path

import numpy as np
import pytest

from tests.helpers.kernels import launched_kernels

ROOT = Path(__file__).resolve().parents[2]


def _shooting_kernels(fn) -> list:
    """Hashes of the shooting kernels (>= 3,000 operations) launched by ``fn()``, in order."""
    return [e["hash"] for e in launched_kernels(fn, 3000)]


def _two_sources_and_targets(corridor_scene, n_targets: int, seed: int):
    """corridor_lab's Sionna scene, two antenna positions and ``n_targets`` random tag
    positions in the corridor (``seed``); skips on CUDA (bit-reproducible traces need the
    CPU variant: set_deterministic refuses CUDA)."""
    from propagation.backend import CUDA_VARIANT, ensure_variant
    from propagation.sionna_scene import load_sionna_scene

    if ensure_variant() == CUDA_VARIANT:
        pytest.skip("bit-reproducible traces need the CPU variant: set_deterministic refuses CUDA")
    rng = np.random.default_rng(seed)
    src = np.array([[3.0, 1.1, 0.9], [6.5, 0.7, 1.4]])
    tgt = np.column_stack([rng.uniform(1, 10, n_targets), rng.uniform(0.2, 2.2, n_targets),
                           rng.uniform(0.3, 2.7, n_targets)])
    return load_sionna_scene(corridor_scene, 865e6), src, tgt


def _candidates(generator, rts, src, tgt, samples: int = 2000, depth: int = 3, seed: int = 5,
                cap: int | None = None):
    """The candidate buffer of one shooting call, as NumPy arrays; ``cap``: its
    ``max_num_paths_per_src`` (default ``PathSolver``'s, ``samples * (depth + 1)``)."""
    import drjit as dr

    from propagation.sionna_paths import points
    from propagation.sionna_scene import clear_devices, place_devices

    place_devices(rts)
    cand = generator(rts.mi_scene, points(src), points(tgt), samples_per_src=samples,
                     max_num_paths_per_src=cap or samples * (depth + 1), max_depth=depth, los=True,
                     specular_reflection=True, diffuse_reflection=False, refraction=True,
                     diffraction=False, edge_diffraction=False, seed=seed)
    cand.schedule()
    dr.eval()
    cand.shrink()
    out = {"src": cand.source_indices.numpy().copy(), "tgt": cand.target_indices.numpy().copy(),
           "valid": cand.valid.numpy().copy(),
           "keys": np.concatenate([x.numpy().astype(np.int64)
                                   for x in (cand.interaction_types, cand.shapes, cand.primitives)], axis=1)}
    clear_devices(rts)
    return out


def test_opaque_count_gives_sionnas_candidates(corridor_scene):
    # the rewritten loop is Sionna's but for the count's type: on one Dr.Jit thread (bit-
    # reproducible) every candidate, its source, target, validity and chain, is Sionna's
    from sionna.rt.path_solvers.sb_candidate_generator import SBCandidateGenerator

    from propagation.backend import set_deterministic
    from propagation.sionna_internals import candidate_generator

    rts, src, tgt = _two_sources_and_targets(corridor_scene, 11, seed=8)
    set_deterministic(True)
    try:
        ours = _candidates(candidate_generator(), rts, src, tgt)
        theirs = _candidates(SBCandidateGenerator(), rts, src, tgt)
    finally:
        set_deterministic(False)
    assert len(ours["src"]) > 100 and ours["valid"].any()
    for k in ours:
        np.testing.assert_array_equal(ours[k], theirs[k], err_msg=k)


def test_one_shooting_kernel_for_any_target_count(corridor_scene):
    # Sionna's loop compiles its shooting kernel per target count (the count is a literal);
    # ours runs the same kernel for 5, 9 and 14 targets
    from sionna.rt.path_solvers.sb_candidate_generator import SBCandidateGenerator

    from propagation.sionna_internals import candidate_generator
    from propagation.sionna_scene import load_sionna_scene

    rts = load_sionna_scene(corridor_scene, 865e6)
    rng = np.random.default_rng(9)
    src = np.array([[4.0, 1.2, 1.0]])
    runs = {"ours": [], "sionna": []}
    for n_tgt in (5, 9, 14):
        tgt = np.column_stack([rng.uniform(1, 10, n_tgt), rng.uniform(0.2, 2.2, n_tgt),
                               rng.uniform(0.3, 2.7, n_tgt)])
        for name, gen in (("ours", candidate_generator), ("sionna", SBCandidateGenerator)):
            runs[name].append(_shooting_kernels(
                lambda g=gen, t=tgt: _candidates(g(), rts, src, t, samples=500)))
    assert all(len(k) == 1 for k in runs["ours"] + runs["sionna"]), runs
    assert runs["ours"][0] == runs["ours"][1] == runs["ours"][2]
    assert len({k[0] for k in runs["sionna"]}) == 3  # control: Sionna's compiles per count


def test_edits_refuse_other_source(monkeypatch):
    # another Sionna whose loop or endpoint builder is not the source the edit was written
    # for: an error naming it, never a silent loop
    import sionna.rt.scene as scene_module
    from sionna.rt.path_solvers import sb_candidate_generator as sbm

    import propagation.sionna_internals as si

    with pytest.raises(si.SionnaVersionError, match="not the one this project edits"):
        si._checked_source(sbm, "SBCandidateGenerator", "_shoot_and_bounce_loop", "0" * 64)
    with pytest.raises(si.SionnaVersionError, match="_endpoints"):
        si._checked_source(scene_module, "Scene", "_endpoints", "0" * 64)
    monkeypatch.setattr(si, "SHOOTING_LOOP_SHA256", "0" * 64)
    with pytest.raises(si.SionnaVersionError, match="tracing.method"):
        si._opaque_loop()


def test_untested_version_refuses_in_one_line_and_direct_still_traces(monkeypatch, far_floor_scene):
    """A sionna-rt other than the tested one stops the fast tracer with one line naming
    both versions and the way out; the public-API tracer runs on it."""
    import sionna.rt as rt

    from propagation import TESTED_VERSIONS, SionnaVersionError, TraceOptions, trace_links

    monkeypatch.setattr(rt, "__version__", "2.3.0")
    pose = np.array([[0.0, 0.0, 1.0, 0.0]])
    tags = np.array([[2.0, 0.0, 1.0]])
    with pytest.raises(SionnaVersionError) as err:
        trace_links(far_floor_scene, pose, tags, TraceOptions(max_depth=0, samples_per_src=100))
    msg = str(err.value)
    assert "\n" not in msg
    assert "sionna-rt 2.3.0" in msg and f"sionna-rt {TESTED_VERSIONS['sionna-rt']}" in msg
    assert 'tracing.method = "direct"' in msg and "constraints.txt" in msg
    direct = trace_links(far_floor_scene, pose, tags,
                         TraceOptions(method="direct", max_depth=0, samples_per_src=100))
    assert np.isfinite(direct.gain_db).all()


def test_tested_versions_are_the_pinned_ones():
    # one declaration (sionna_internals.TESTED_VERSIONS), the pins of constraints.txt, the
    # minor-version bound of pyproject.toml
    from propagation import TESTED_VERSIONS

    pins = dict(re.findall(r"^([A-Za-z0-9_.-]+)==(\S+)", (ROOT / "constraints.txt").read_text(), re.M))
    for name, version in TESTED_VERSIONS.items():
        assert pins.get(name) == version, name
    major, minor = TESTED_VERSIONS["sionna-rt"].split(".")[:2]
    assert f'"sionna-rt>={major}.{minor},<{major}.{int(minor) + 1}"' in (ROOT / "pyproject.toml").read_text()


#: What only propagation/sionna_internals.py may name: Sionna's non-public classes, the
#: patched scene method, edited source, and PathsBuffer's private and non-public members.
_INTERNAL_NAMES = {"PathsBuffer", "SBCandidateGenerator", "ImageMethod", "FieldCalculator",
                   "INVALID_SHAPE", "INVALID_PRIMITIVE", "exec", "getsource", "ShapePtr"}
_INTERNAL_ATTRS = {"_endpoints", "_shoot_and_bounce_loop", "_src_indices", "_tgt_indices",
                   "_k_tx_x", "_k_tx_y", "_k_tx_z", "_k_rx_x", "_k_rx_y", "_k_rx_z",
                   "_interaction_types", "_vertices_x", "_vertices_y", "_vertices_z", "_shapes",
                   "_primitives", "_probs", "_valid", "_paths_counter", "discard_invalid",
                   "detach_geometry", "buffer_size", "source_indices", "target_indices", "shrink",
                   "gather", "patterns"} | _INTERNAL_NAMES
#: Sionna modules other code may import from: the package and its documented constants.
_PUBLIC_SIONNA = {"sionna.rt", "sionna.rt.constants"}


def _internal_uses(tree) -> list[tuple[int, str]]:
    """(line, what) of every use of a Sionna internal in a parsed module: imports of
    non-public Sionna modules or names, attributes and names above, and strings naming
    ``sionna.rt.path_solvers`` (a dynamic import). Docstrings and comments are prose."""
    out = []
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            out += [(node.lineno, a.name) for a in node.names
                    if a.name.startswith("sionna") and a.name not in _PUBLIC_SIONNA]
        elif isinstance(node, ast.ImportFrom):
            mod = node.module or ""
            if mod.startswith("sionna") and mod not in _PUBLIC_SIONNA:
                out.append((node.lineno, mod))
            out += [(node.lineno, a.name) for a in node.names if a.name in _INTERNAL_NAMES]
        elif isinstance(node, ast.Attribute) and node.attr in _INTERNAL_ATTRS:
            out.append((node.lineno, "." + node.attr))
        elif isinstance(node, ast.Name) and node.id in _INTERNAL_NAMES:
            out.append((node.lineno, node.id))
        elif (isinstance(node, ast.Constant) and isinstance(node.value, str)
              and "sionna.rt.path_solvers" in node.value and "\n" not in node.value):
            out.append((node.lineno, node.value))
    return out


def test_the_scan_sees_the_compat_module_uses():
    # control: the scan finds what the compat module does (else it proves nothing)
    text = (ROOT / "propagation" / "sionna_internals.py").read_text(encoding="utf-8")
    found = {what for _, what in _internal_uses(ast.parse(text))}
    assert {"sionna.rt.path_solvers.image_method", "._src_indices", "._endpoints", "exec",
            "PathsBuffer", ".discard_invalid"} <= found


def test_no_sionna_internals_outside_the_compat_module():
    """Scan every source file of scenes/, propagation/ and pipeline/ (tests excluded):
    zero lines outside the compat modules (propagation/sionna_internals.py and its sibling
    sionna_refield.py, both behind the version guard) touch Sionna's internals."""
    compat = {ROOT / "propagation" / "sionna_internals.py", ROOT / "propagation" / "sionna_refield.py"}
    files = [p for d in ("scenes", "propagation", "pipeline") for p in sorted((ROOT / d).rglob("*.py"))]
    assert compat <= set(files) and len(files) > 50
    hits = [f"{path.relative_to(ROOT)}:{line}: {what}" for path in files if path not in compat
            for line, what in _internal_uses(ast.parse(path.read_text(encoding="utf-8")))]
    assert not hits, "Sionna internals outside propagation/sionna_internals.py: " + ", ".join(hits)


def test_the_study_refuses_an_untested_version_before_the_tour(monkeypatch):
    # the check reads the package metadata: an untested sionna-rt stops the study at its
    # checks (after the scene), naming both versions, before any tour or tracing
    import importlib.metadata as md
    from types import SimpleNamespace

    from pipeline.config import ConfigError, StudyConfig, replace_path
    from pipeline.stages.checks import check_tracer_versions

    real = md.version
    monkeypatch.setattr(md, "version", lambda pkg: "2.3.0" if pkg == "sionna-rt" else real(pkg))
    ctx = SimpleNamespace(config=StudyConfig())
    with pytest.raises(ConfigError, match=r"sionna-rt 2\.3\.0.*tracing\.method = \"direct\""):
        check_tracer_versions(ctx)
    check_tracer_versions(SimpleNamespace(config=replace_path(StudyConfig(), "tracing.method",
                                                                 "direct")))


# 32: a first cap above every count (one shot); 10**9: PathSolver's cap first, shot again
@pytest.mark.parametrize("targets_per_cap", [32, 10**9])
def test_shoot_candidates_keeps_what_sionnas_cap_would_drop(corridor_scene, monkeypatch, targets_per_cap):
    # Sionna stores a chain once per target it sees and drops a source's candidates beyond
    # max_num_paths_per_src silently: with 300 targets, 200 rays at depth 2 (cap 600)
    # overflow. shoot_candidates shoots again at the count Sionna's counter reports: its
    # candidates are those of a cap far above the count (at most 1e6, so the same table
    # of chain hashes: equal). A second call starts from the count the first needed.
    import propagation.sionna_internals as internals
    from propagation.backend import set_deterministic
    from propagation.sionna_internals import candidate_generator, shoot_candidates
    from propagation.sionna_paths import points
    from propagation.sionna_scene import clear_devices, place_devices

    rts, src, tgt = _two_sources_and_targets(corridor_scene, 300, seed=3)
    set_deterministic(True)
    try:
        capped = _candidates(candidate_generator(), rts, src, tgt, samples=200, depth=2)
        ref = _candidates(candidate_generator(), rts, src, tgt, samples=200, depth=2, cap=600 * 1000)
        monkeypatch.setattr(internals, "_TARGETS_PER_CAP", targets_per_cap)
        monkeypatch.setattr(internals, "_NEEDED_PER_TARGET", {})  # nothing learned yet
        caps = []
        generator = internals.candidate_generator

        class Counted:  # the generator, its caps recorded
            def __init__(self):
                self.gen = generator()

            def __call__(self, *a, **k):
                caps.append(k["max_num_paths_per_src"])
                return self.gen(*a, **k)

            @property
            def paths_per_source(self):
                return self.gen.paths_per_source

        monkeypatch.setattr(internals, "candidate_generator", Counted)
        place_devices(rts)
        calls = [shoot_candidates(rts.mi_scene, points(src), points(tgt), samples_per_src=200,
                                  max_depth=2, refraction=True, seed=5) for _ in range(2)]
        clear_devices(rts)
    finally:
        set_deterministic(False)
    needed = np.bincount(ref["src"]).max()
    assert np.bincount(capped["src"]).max() == 600  # Sionna's cap reached: rows dropped
    assert needed > 2 * 600  # a cap far above the count keeps far more
    if targets_per_cap == 32:  # 6,000 (10 x 600) holds every count: one shot per call (the
        assert caps == [6000, 6000]  # learned 1.5 x count stays below it)
    else:  # PathSolver's 600; again at the count (on the grid: <= 25 % more); the second
        # call starts from 1.5 x the count the first needed, and shoots once
        assert len(caps) == 3 and caps[0] == 600
        assert needed <= caps[1] <= 1.25 * needed
        assert 1.5 * needed <= caps[2] <= 1.25 * 1.5 * needed + 1
    for ours in calls:
        for k, v in (("src", ours.source), ("tgt", ours.target), ("valid", ours.valid), ("keys", ours.keys)):
            np.testing.assert_array_equal(v, ref[k], err_msg=k)


def test_a_learned_first_cap_leaves_the_candidates_as_they_are(corridor_scene, monkeypatch):
    # Sionna's table of chain hashes has max(cap, MIN_SPEC_COUNT_SIZE) slots per source, and
    # a larger table finds other chains (fewer hash collisions). Shrunk to 1,000 slots here,
    # a first cap learned from a huge earlier need must stay within the table the call's
    # own base cap gives: the candidates equal those of a call that learned nothing.
    from sionna.rt.path_solvers.sb_candidate_generator import SBCandidateGenerator

    import propagation.sionna_internals as internals
    from propagation.backend import set_deterministic
    from propagation.sionna_internals import shoot_candidates
    from propagation.sionna_paths import points
    from propagation.sionna_scene import clear_devices, place_devices

    rts, src, tgt = _two_sources_and_targets(corridor_scene, 300, seed=3)
    monkeypatch.setattr(SBCandidateGenerator, "MIN_SPEC_COUNT_SIZE", 1000)
    monkeypatch.setattr(internals, "_TARGETS_PER_CAP", 10**9)
    key = None
    out = []
    set_deterministic(True)
    try:
        place_devices(rts)
        for learned in (None, 1000.0):  # nothing learned; then 1.5 x 1000 per target
            table = {}
            if learned is not None:
                table[key] = learned
            monkeypatch.setattr(internals, "_NEEDED_PER_TARGET", table)
            out.append(shoot_candidates(rts.mi_scene, points(src), points(tgt), samples_per_src=200,
                                        max_depth=2, refraction=True, seed=5))
            key = next(iter(table))  # the key the first call stored its need under
        clear_devices(rts)
    finally:
        set_deterministic(False)
    assert np.bincount(out[0].source).max() > 1000  # counts past the shrunk table: it matters
    for k in ("source", "target", "valid", "keys"):
        np.testing.assert_array_equal(getattr(out[1], k), getattr(out[0], k), err_msg=k)
