"""Each physical layer crossed once: traced slab transmission against ITU-R P.2040, and the
consumers of the two geometries (tracing: radio surfaces; geometric checks: solids)."""

import dataclasses

import numpy as np
import pytest

import scenes
from propagation import (
    TraceOptions,
    free_space_gain_db,
    slab_coefficients,
    slab_transmission_db,
    trace_links,
)
from propagation.constants import SPEED_OF_LIGHT
from propagation.pathcache import settings_key

# the material library warns (by design) that P.2040 fits are extrapolated below 1 GHz
pytestmark = pytest.mark.filterwarnings("ignore::scenes.materials.FrequencyRangeWarning")

F = 865e6


def test_slab_closed_form():
    eps, sigma = scenes.material("brick", F)
    # the brief's numbers: 0.12 m brick -3.7 dB, 0.2 m concrete -7.5 dB at normal incidence
    assert slab_transmission_db(eps, sigma, 0.12, F) == pytest.approx(-3.743, abs=1e-3)
    assert slab_transmission_db(*scenes.material("concrete", F), 0.2, F) == pytest.approx(-7.494, abs=1e-3)
    # TE = TM at normal incidence; they differ at 40 degrees
    assert slab_transmission_db(eps, sigma, 0.12, F, 0.0, "TM") == pytest.approx(
        slab_transmission_db(eps, sigma, 0.12, F, 0.0, "TE"), abs=1e-12)
    assert abs(slab_transmission_db(eps, sigma, 0.12, F, 0.7, "TM")
               - slab_transmission_db(eps, sigma, 0.12, F, 0.7, "TE")) > 0.5
    # a vanishing slab transmits everything; a lossless half-wave slab too (Fabry-Perot)
    assert slab_transmission_db(eps, sigma, 1e-9, F) == pytest.approx(0.0, abs=1e-6)
    lam = SPEED_OF_LIGHT / F
    assert slab_transmission_db(4.0, 0.0, lam / 4, F) == pytest.approx(0.0, abs=1e-9)  # n d = lambda/2
    # energy: |R|^2 + |T|^2 = 1 without loss, < 1 with it
    r, t = slab_coefficients(0.3, 4.0, 0.0, 0.1, F)
    assert abs(r) ** 2 + abs(t) ** 2 == pytest.approx(1.0, abs=1e-12)
    r, t = slab_coefficients(0.3, eps, sigma, 0.12, F)
    assert abs(r) ** 2 + abs(t) ** 2 < 0.95


@pytest.fixture(scope="module")
def brick_box():
    """A 4 m x 2.4 m x 3 m room with 0.12 m brick walls, a 0.2 m concrete floor."""
    return scenes.corridor(length_m=4.0, width_m=2.4, height_m=3.0, wall_material="brick",
                           name="brick_box")


# (receiver, material, thickness, incidence angle): the reader stands inside the room at
# (2, 1.2, 1.5); the receiver is outside it, behind the brick wall y = 0 (straight across,
# and 34 deg off the normal in the horizontal plane, where a vertical E field is TE) or
# below the concrete floor z = 0. Each direct ray crosses exactly one wall (or the floor)
# and nothing else: the other walls, floor and ceiling reflect, but every reflected path
# needs a further crossing to reach the receiver, so max_depth = 1 (one interaction)
# leaves the through-wall ray alone, and the gain is Friis times the slab's |T|^2.
CASES = {
    "brick wall, normal": ((2.0, -1.0, 1.5), "brick", 0.12, 0.0),
    "brick wall, 34 deg TE": ((3.5, -1.0, 1.5), "brick", 0.12, np.arctan2(1.5, 2.2)),
    "concrete floor, normal": ((2.0, 1.2, -1.0), "concrete", 0.2, 0.0),
}


@pytest.mark.parametrize("case", list(CASES))
def test_one_wall_transmits_once(brick_box, case):
    rx, mat, thickness_m, theta = CASES[case]
    tx = np.array([[2.0, 1.2, 1.5, 0.0]])
    rx = np.array([rx])
    iso = TraceOptions(method="direct", samples_per_src=10_000, reader_pattern="iso", tag_pattern="iso",
                       reader_polarization="V")
    fs = free_space_gain_db(np.linalg.norm(rx[0] - tx[0, :3]), F)
    closed = float(slab_transmission_db(*scenes.material(mat, F), thickness_m, F, theta, "TE"))
    new = trace_links(brick_box, tx, rx, iso.replace(max_depth=1))
    assert new.n_paths[0, 0] == 1  # the straight ray (LinkSet.los flags it: its delay is d / c)
    # 0.5 dB (brief); with a single unobstructed ray the only differences are Sionna's
    # float32 arithmetic (measured: 1e-5 dB), so 0.5 dB is a loose bound that still
    # separates one crossing from two by several dB
    assert new.gain_db[0, 0] - fs == pytest.approx(closed, abs=0.5)
    # the old closed box: two faces, each a slab of the library thickness (here equal to
    # the wall's), so the wall counts twice and two interactions are needed to cross it
    old_scene = dataclasses.replace(brick_box, radio_surfaces=None)
    old = trace_links(old_scene, tx, rx, iso.replace(max_depth=2))
    assert old.n_paths[0, 0] == 1
    assert old.gain_db[0, 0] - fs == pytest.approx(2 * closed, abs=0.5)
    assert abs(old.gain_db[0, 0] - fs - closed) > 3.0  # the test tells the two apart


def test_cache_never_mixes_closed_boxes_and_radio_surfaces(brick_box, tmp_path):
    old_scene = dataclasses.replace(brick_box, radio_surfaces=None)
    assert old_scene.content_hash() != brick_box.content_hash()
    settings = {"frequency_hz": F, "max_depth": 2}
    assert settings_key(old_scene.content_hash(), settings) != settings_key(brick_box.content_hash(), settings)
    tx, rx = np.array([[2.0, 1.2, 1.5, 0.0]]), np.array([[2.0, -1.0, 1.5]])
    kw = dict(options=TraceOptions(method="direct", max_depth=2, samples_per_src=2000, reader_pattern="iso",
                                   tag_pattern="iso"),
              cache_dir=tmp_path)
    first = trace_links(old_scene, tx, rx, **kw)
    second = trace_links(brick_box, tx, rx, **kw)
    assert second.n_traced_sources == 1  # not served from the closed-box entry
    assert second.gain_db[0, 0] > first.gain_db[0, 0] + 3.0
    assert trace_links(brick_box, tx, rx, **kw).n_traced_sources == 0  # its own entry


def test_antenna_check_uses_solids(brick_box):
    # inside the wall's thickness (y = -0.06): no radio surface there, but a solid
    with pytest.raises(ValueError, match="inside solid geometry"):
        trace_links(brick_box, np.array([[2.0, -0.06, 1.5, 0.0]]), np.array([[2.0, 1.2, 1.5]]), TraceOptions(method="direct", max_depth=0, samples_per_src=100))


def test_wall_measurement_surface_sits_in_front_of_the_traced_faces():
    from propagation.fields import wall_surface_mesh

    lab = scenes.load("corridor_lab")
    surf = wall_surface_mesh(lab, max_edge_m=0.5, offset_m=0.01)
    c = surf.triangles_center
    # along the brick wall the measurement cells lie 1 cm in front of its traced surface
    brick = [s for s in lab.radio_surfaces if s.material == "brick"]
    assert {round(float(v), 9) for s in brick for v in s.mesh.vertices[:, 1]} == {0.0}
    near_brick = c[np.abs(c[:, 1] - 0.01) < 1e-9]
    assert len(near_brick) > 50
    assert np.all(surf.face_normals[np.abs(c[:, 1] - 0.01) < 1e-9][:, 1] > 0.99)
