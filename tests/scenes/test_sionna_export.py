"""The Mitsuba XML export loads in Sionna RT with one object per (material, thickness)."""

import os

import numpy as np
import pytest

import scenes


def _sionna():
    pytest.importorskip("sionna.rt")
    try:  # the project's one place that picks a variant
        from propagation.backend import select_variant

        select_variant("auto")
    except ImportError:  # propagation not there yet: do by hand what it does
        os.environ.setdefault("DRJIT_LIBLLVM_PATH", "/usr/lib/x86_64-linux-gnu/libLLVM-19.so")
        import mitsuba

        mitsuba.set_variant("llvm_ad_mono_polarized")
    import sionna.rt

    return sionna.rt


@pytest.mark.filterwarnings("ignore::scenes.FrequencyRangeWarning")
def test_export_loads_in_sionna(tmp_path):
    rt = _sionna()
    scene = scenes.corridor(
        length_m=6.0, width_m=2.0, height_m=2.5,
        doors=[{"position_m": (3.0, 0.0), "closed": True}],
        glass_panels=[{"position_m": (2.0, 2.0), "width_m": 1.0, "sill_m": 1.0, "height_m": 1.0}],
        cabinets=[{"center_m": (5.0, 1.7), "size_m": (0.8, 0.5, 1.8)}],
    )
    xml = scene.export_mitsuba(tmp_path / "mini", 865e6)
    rt_scene = rt.load_scene(str(xml), merge_shapes=False)
    # one object per (material, thickness) of the radio surfaces, named <material>-t<thickness>
    groups = {g.token: g for g in scenes.radio_groups(scene)}
    assert set(rt_scene.objects) == set(groups)
    assert {g.material for g in groups.values()} == set(scene.materials)
    for name, obj in rt_scene.objects.items():
        g = groups[name]
        eps, sigma = scenes.material(g.material, 865e6)
        rm = obj.radio_material
        # float32 inside Mitsuba: 1e-6 relative is float32 rounding
        assert float(rm.relative_permittivity[0]) == pytest.approx(eps, rel=1e-6)
        assert float(rm.conductivity[0]) == pytest.approx(sigma, rel=1e-6)
        assert float(rm.thickness[0]) == pytest.approx(g.thickness_m, rel=1e-6)
        n_faces = obj.mi_mesh.face_count()
        assert n_faces == len(g.mesh.faces)
    # thicknesses: the spec's wall (glass panel, solid), floor and ceiling; the leaf's; the
    # library's for plasterboard stud leaves and the cabinet's shell
    assert set(groups) == {"glass-t0p120", "concrete-t0p200", "ceiling_board-t0p050", "wood-t0p040",
                           "plasterboard-t0p0125", "metal-t0p002"}
    bbox = rt_scene.mi_scene.bbox()
    np.testing.assert_allclose([bbox.min[0], bbox.max[0]], scene.bounds_m[:, 0], atol=1e-5)
