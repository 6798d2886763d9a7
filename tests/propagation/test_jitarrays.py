"""Arrays handed to Dr.Jit: aligned, and the tracer's kernels do not change with the call."""

from __future__ import annotations

import numpy as np
import pytest

from propagation.jitarrays import ALIGNMENT_BYTES, aligned_copy
from tests.helpers.kernels import launched_kernels


@pytest.mark.parametrize("dtype", [np.float32, np.uint32, np.float64])
def test_aligned_copy_is_aligned_and_equal(dtype):
    rng = np.random.default_rng(0)
    for shape in [(1,), (7,), (3, 5), (0,)]:
        for _ in range(8):  # several allocations: NumPy's own start at various offsets
            values = rng.uniform(0, 100, shape)
            out = aligned_copy(values, dtype)
            assert out.size == 0 or out.ctypes.data % ALIGNMENT_BYTES == 0
            assert out.flags.c_contiguous and out.dtype == dtype and out.shape == shape
            np.testing.assert_array_equal(out, values.astype(dtype))


def _kernels(fn, min_ops: int = 0) -> set:
    """Hashes of the kernels of at least ``min_ops`` operations launched by ``fn()``."""
    return {e["hash"] for e in launched_kernels(fn, min_ops)}


def _endpoint_kernels(rts, endpoints_of) -> set:
    import drjit as dr

    def run():
        for devices, array in ((rts.transmitters.values(), rts.tx_array),
                               (rts.receivers.values(), rts.rx_array)):
            dr.eval(*(e for e in endpoints_of(devices, array) if e is not None))
    return _kernels(run)


def test_device_positions_are_not_compiled_into_kernels(corridor_scene):
    # Sionna's API takes positions as numbers (Dr.Jit literals) and its endpoint arrays
    # scatter each device with its index as a literal: a kernel per set of positions and
    # per device count (~80 compiled per lone trace of a cold study). Placed as arrays and
    # gathered at once, other positions and other counts run the same kernels.
    from propagation.sionna_scene import load_sionna_scene, place_devices

    rts = load_sionna_scene(corridor_scene, 865e6)
    rng = np.random.default_rng(4)
    ours, sionnas = [], []
    for n_src, n_tgt in ((6, 9), (3, 14), (8, 5)):
        place_devices(rts, rng.uniform(0.5, 2.0, (n_src, 3)), rng.uniform(0.5, 2.0, (n_tgt, 3)))
        ours.append(_endpoint_kernels(rts, lambda d, a: rts._endpoints(d, a, True, True)))
        sionnas.append(_endpoint_kernels(
            rts, lambda d, a: type(rts)._endpoints(rts, d, a, True, True)))
    assert ours[1] == ours[0] and ours[2] == ours[0]
    assert sionnas[1] != sionnas[0]  # control: Sionna's own method compiles per count


def test_endpoints_at_once_equal_sionnas(corridor_scene):
    import sionna.rt as rt

    from propagation.sionna_scene import load_sionna_scene, place_devices

    rts = load_sionna_scene(corridor_scene, 865e6)
    rng = np.random.default_rng(5)
    place_devices(rts, rng.uniform(0.5, 2.0, (5, 3)), rng.uniform(0.5, 2.0, (7, 3)))
    tx = list(rts.transmitters.values())
    tx[2].orientation = [0.3, -0.2, 0.1]  # set as numbers, as Sionna's API does
    tx[3].velocity = [1.0, 2.0, 3.0]
    rts.tx_array = rt.PlanarArray(num_rows=1, num_cols=1, pattern="tr38901", polarization="V")
    for devices, array in ((rts.transmitters.values(), rts.tx_array),
                           (rts.receivers.values(), rts.rx_array),
                           (rts.transmitters.values(),  # two antennas: Sionna's method
                            rt.PlanarArray(num_rows=1, num_cols=2, pattern="iso", polarization="V"))):
        for synthetic in (True, False):
            for velocities in (True, False):
                got = rts._endpoints(devices, array, synthetic, velocities)
                want = type(rts)._endpoints(rts, devices, array, synthetic, velocities)
                for g, w in zip(got, want, strict=True):
                    assert (g is None) == (w is None)
                    if g is not None:
                        np.testing.assert_array_equal(np.asarray(g), np.asarray(w))


def test_another_position_runs_the_same_solver_kernels(corridor_scene):
    # NumPy memory mapped into Dr.Jit as it was allocated (16-byte aligned) changed the
    # loads of Sionna's shooting and field kernels (thousands of operations, ~1 s to
    # compile each on 2 cores) from call to call; aligned arrays keep them the same.
    from propagation.pathsolve import _trace_chunk
    from propagation.sionna_scene import load_sionna_scene

    rts = load_sionna_scene(corridor_scene, 865e6)
    tags = corridor_scene.tags.positions_m[:5]
    calls = [_kernels(lambda x=x: _trace_chunk(rts, np.array([[x, 1.1, 0.9]]), tags, 3, 2000, 7),
                      min_ops=2000)
             for x in (3.0, 3.4, 7.1, 11.9, 5.5, 8.8)]
    assert calls[0], "no large kernel seen: the test would pass vacuously"
    for later in calls[1:]:
        assert later == calls[0]


def test_padded_target_counts():
    from propagation.pathsolve import padded_target_count

    assert [padded_target_count(n) for n in (0, 1, 24, 32)] == [0, 1, 24, 32]
    assert [padded_target_count(n) for n in (33, 40, 41, 65, 73, 97, 129, 155)] == \
        [40, 40, 48, 80, 80, 112, 160, 160]
    for n in range(1, 2000):
        m = padded_target_count(n)
        assert n <= m <= max(32, 1.25 * n)  # at most a quarter more
    # four counts per doubling above 32, so few kernels to compile
    assert {padded_target_count(n) for n in range(65, 129)} == {80, 96, 112, 128}


def test_padding_receivers_leave_the_tags_paths_alone(corridor_scene):
    # 33 tags are traced with 7 padding receivers (40); the same tags traced in calls of
    # 17 and 16 (not padded) get the same paths: the shooting is per target, the same
    # rays (same seed) on one Dr.Jit thread (bit-reproducible).
    from propagation.backend import CUDA_VARIANT, ensure_variant, set_deterministic
    from propagation.pathsolve import _trace_chunk
    from propagation.sionna_scene import load_sionna_scene

    if ensure_variant() == CUDA_VARIANT:
        pytest.skip("bit-reproducible traces need the CPU variant: set_deterministic refuses CUDA")
    rts = load_sionna_scene(corridor_scene, 865e6)
    rng = np.random.default_rng(3)
    tags = np.column_stack([rng.uniform(1, 24, 33), rng.uniform(0.2, 2.2, 33), rng.uniform(0.3, 2.7, 33)])
    src = np.array([[4.0, 1.2, 1.0], [9.0, 0.8, 1.5]])
    set_deterministic(True)
    try:
        padded = _trace_chunk(rts, src, tags, 3, 3000, 11)
        parts = [_trace_chunk(rts, src, tags[:17], 3, 3000, 11), _trace_chunk(rts, src, tags[17:], 3, 3000, 11)]
    finally:
        set_deterministic(False)
    n_paths = 0
    for s in range(len(src)):
        assert np.array_equal(padded[s].tag_positions_m, tags)
        for t in range(len(tags)):
            part, tt = (parts[0], t) if t < 17 else (parts[1], t - 17)
            a = padded[s].tau_s[padded[s].offsets[t]:padded[s].offsets[t + 1]]
            b = part[s].tau_s[part[s].offsets[tt]:part[s].offsets[tt + 1]]
            np.testing.assert_array_equal(np.sort(a), np.sort(b))
            n_paths += len(a)
    assert n_paths > 100
