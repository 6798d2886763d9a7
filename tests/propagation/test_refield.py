"""Fields recomputed on kept geometry (propagation.refield) against Sionna's own trace and
the two-ray closed form at other permittivities."""

import numpy as np
import pytest

from propagation import TraceOptions, slab_coefficients, trace_links
from propagation.analytic import wavelength_m
from propagation.refield import freeze_paths, material_shares, refield, refield_gains_db
from propagation.tracing import tag_dipole_axes
from scenes import material

pytestmark = pytest.mark.filterwarnings("ignore::scenes.materials.FrequencyRangeWarning")

F = 865e6
FLOOR = "uhf-concrete-t0p200"
OPT = TraceOptions(method="direct", max_depth=1, samples_per_src=20000, reader_pattern="iso",
                   tag_pattern="iso", reader_polarization="V")


def _two_ray_slab_db(d, h_t, h_r, eps, sigma, thickness_m=0.2):
    """Direct plus floor-reflected ray, the floor a P.2040 slab (TM: V polarisation), [dB];
    the classic two-ray form (propagation.two_ray_gain_db) with the slab's coefficient."""
    lam = wavelength_m(F)
    r1, r2 = np.hypot(d, h_t - h_r), np.hypot(d, h_t + h_r)
    refl = slab_coefficients(np.arctan2(d, h_t + h_r), eps, sigma, thickness_m, F, "TM")[0]
    h = lam / (4 * np.pi) * (np.exp(-2j * np.pi * r1 / lam) / r1 + refl * np.exp(-2j * np.pi * r2 / lam) / r2)
    return 10 * np.log10(np.abs(h) ** 2)


def _gains(frozen, materials, tags, pose):
    n = len(tags)
    return refield_gains_db(frozen, materials, np.zeros(n, int), np.arange(n), np.tile(pose, (n, 1)),
                            frequency_hz=F, options=OPT, tag_axes=tag_dipole_axes(None, n))


def test_refield_is_the_trace_and_the_two_ray_form_at_other_permittivities(floor_scene):
    d = np.linspace(1.0, 20.0, 39)
    h_t, h_r = 0.6, 1.0
    tags = np.stack([d, 0 * d, 0 * d + h_r], axis=1)
    pose = np.array([0.0, 0.0, h_t, 0.0, 0.0, 0.0])
    frozen = freeze_paths(floor_scene, pose[None, :3], tags, frequency_hz=F, options=OPT)
    eps0, sigma0 = material("concrete", F)
    assert frozen.materials[FLOOR] == pytest.approx((eps0, sigma0), rel=1e-6)
    # as traced: trace_links' own gains (same solver stages and seed; float32 fields)
    traced = trace_links(floor_scene, pose[None, :4], tags, OPT).gain_db[0]
    np.testing.assert_allclose(_gains(frozen, None, tags, pose), traced, atol=1e-4)
    for eps, sigma in ((12.0, sigma0), (2.5, 0.3)):
        got = _gains(frozen, {FLOOR: (eps, sigma)}, tags, pose)
        ref = _two_ray_slab_db(d, h_t, h_r, eps, sigma)
        # measured within 3e-4 dB: float32 fields; 0.01 dB leaves room for other CPUs
        np.testing.assert_allclose(got, ref, atol=0.01)
        # and the change is real: the gains moved by more than the tolerance somewhere
        assert np.max(np.abs(got - traced)) > 1.0
    # the scene's materials are back as traced (the loaded scene is shared)
    np.testing.assert_allclose(_gains(frozen, None, tags, pose), traced, atol=1e-4)


def test_material_shares_name_the_floor(floor_scene):
    tags = np.array([[5.0, 0.0, 1.0], [9.0, 1.0, 1.2]])
    frozen = freeze_paths(floor_scene, np.array([[0.0, 0.0, 0.6]]), tags, frequency_hz=F, options=OPT)
    share = material_shares(frozen)
    # one direct and one floor-reflected path per tag: the reflected one carries |Gamma|^2
    # (~0.1-0.3 at these grazing angles) of the direct's power
    assert set(share) == {FLOOR}
    assert 0.02 < share[FLOOR] < 0.5
    with pytest.raises(KeyError, match="no radio material"):
        refield(frozen, {"uhf-brick-t0p120": (4.0, 0.02)})
