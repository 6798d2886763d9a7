"""One trace at the carrier serves every channel: against a direct trace at the channel."""

import numpy as np
import pytest

import scenes

# Low ray count and depth: the test compares two evaluations of the same sampled paths.
# Direct tracing (Sionna's PathSolver): the channel sum, not the tracer, is under test.
TRACE = {"method": "direct", "max_depth": 2, "samples_per_src": 3000, "seed": 5}


@pytest.fixture(scope="module")
def scene():
    return scenes.corridor(length_m=6.0, width_m=2.4, height_m=2.5,
                           tags=[{"id": "a", "position_m": (3.0, 2.4, 1.0)},
                                 {"id": "b", "position_m": (4.5, 0.0, 0.8)},
                                 {"id": "c", "position_m": (5.2, 2.4, 1.4)}], name="channel_test")


def test_channel_sum_matches_direct_trace_at_the_channel(scene):
    import propagation
    from propagation.backend import CUDA_VARIANT, ensure_variant

    if ensure_variant() == CUDA_VARIANT:
        pytest.skip("bit-reproducible traces need the CPU variant: set_deterministic refuses CUDA")
    poses = np.array([[1.0, 1.2, 0.6, 0.0, 0.0, 0.0], [2.0, 1.0, 0.9, 0.4, 0.0, 0.0]])
    propagation.set_deterministic(True)  # fresh traces bit-reproducible: same rays, same paths
    try:
        direct = propagation.trace_links(scene, poses, scene.tags.positions_m, frequency_hz=867.5e6,
                                         tag_normals=scene.tags.normals, options=propagation.TraceOptions(**TRACE))
        hopped = propagation.trace_links(scene, poses, scene.tags.positions_m, frequency_hz=865e6,
                                         channel_hz=867.5e6, channel_gradient=True,
                                         tag_normals=scene.tags.normals, options=propagation.TraceOptions(**TRACE))
        carrier = propagation.trace_links(scene, poses, scene.tags.positions_m, frequency_hz=865e6,
                                          tag_normals=scene.tags.normals, options=propagation.TraceOptions(**TRACE))
    finally:
        propagation.set_deterministic(False)
    # Ray sampling with the same seed is identical, but the solver keeps one weak path
    # fewer or more on some links at another frequency (measured: 3 of these 6 links).
    assert np.abs(direct.n_paths - hopped.n_paths).max() <= 1
    # Tolerance: the direct trace re-evaluates the materials at 867.5 MHz; P.2040's
    # permittivities are frequency-independent for these materials and the conductivities
    # scale as f^d (d < 1), +0.3 % over 2.5 MHz, which moves reflection and transmission
    # coefficients by well under 0.1 %; the free-space loss in Sionna's path amplitudes is
    # lambda / (4 pi d) at the traced carrier, -0.29 % (0.025 dB) at 867.5 MHz; and the one
    # weak path. Measured: |h| differences up to 0.3 % of the largest |h|, gains 0.04 dB;
    # 1 % of the largest |h| and 0.1 dB bound them.
    np.testing.assert_allclose(np.abs(hopped.h - direct.h), 0.0, atol=0.01 * np.abs(direct.h).max())
    np.testing.assert_allclose(hopped.gain_db, direct.gain_db, atol=0.1)
    # ... while the channel's coherent sum is not the carrier's (the phases moved)
    assert np.abs(hopped.h - carrier.h).max() > 0.05 * np.abs(carrier.h).max()
    assert hopped.dh_dpos.shape == (2, 3, 3)
