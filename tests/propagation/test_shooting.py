"""The candidate generator with an opaque target count: Sionna's candidates, one kernel."""

from __future__ import annotations

import numpy as np
import pytest

from tests.helpers.kernels import launched_kernels


def _shooting_kernels(fn) -> list:
    """Hashes of the shooting kernels (>= 3,000 operations) launched by ``fn()``, in order."""
    return [e["hash"] for e in launched_kernels(fn, 3000)]


def _candidates(generator, rts, src, tgt, samples: int = 2000, depth: int = 3, seed: int = 5):
    """The candidate buffer of one shooting call, as NumPy arrays."""
    import drjit as dr

    from propagation.sionna_paths import candidate_keys, points
    from propagation.sionna_scene import clear_devices, place_devices

    place_devices(rts)
    cand = generator(rts.mi_scene, points(src), points(tgt), samples_per_src=samples,
                     max_num_paths_per_src=samples * (depth + 1), max_depth=depth, los=True,
                     specular_reflection=True, diffuse_reflection=False, refraction=True,
                     diffraction=False, edge_diffraction=False, seed=seed)
    cand.schedule()
    dr.eval()
    cand.shrink()
    out = {"src": cand.source_indices.numpy().copy(), "tgt": cand.target_indices.numpy().copy(),
           "valid": cand.valid.numpy().copy(), "keys": candidate_keys(cand)}
    clear_devices(rts)
    return out


def test_opaque_count_gives_sionnas_candidates(corridor_scene):
    # the rewritten loop is Sionna's but for the count's type: on one Dr.Jit thread (bit-
    # reproducible) every candidate, its source, target, validity and chain, is Sionna's
    from sionna.rt.path_solvers.sb_candidate_generator import SBCandidateGenerator

    from propagation.backend import CUDA_VARIANT, ensure_variant, set_deterministic
    from propagation.shooting import candidate_generator
    from propagation.sionna_scene import load_sionna_scene

    if ensure_variant() == CUDA_VARIANT:
        pytest.skip("bit-reproducible traces need the CPU variant: set_deterministic refuses CUDA")
    rts = load_sionna_scene(corridor_scene, 865e6)
    rng = np.random.default_rng(8)
    src = np.array([[3.0, 1.1, 0.9], [6.5, 0.7, 1.4]])
    tgt = np.column_stack([rng.uniform(1, 10, 11), rng.uniform(0.2, 2.2, 11), rng.uniform(0.3, 2.7, 11)])
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

    from propagation.shooting import candidate_generator
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


def test_rewrite_refuses_other_source(monkeypatch):
    # another Sionna whose loop lacks the line: an error naming it, never a silent loop
    import propagation.shooting as shooting

    monkeypatch.setattr(shooting, "TARGET_COUNT_LINE", "num_targets = something_else")
    with pytest.raises(RuntimeError, match="found 0 times"):
        shooting._opaque_loop()
