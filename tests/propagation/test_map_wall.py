"""A wall extracted from a ROS map is one radio surface: a link through it loses the ITU-R
P.2040 single-slab value (as a generated corridor's wall does, test_radio_geometry.py)."""

import numpy as np
import pytest

import scenes
from propagation import TraceOptions, free_space_gain_db, slab_transmission_db, trace_links
from tests.scenes.maphelpers import OCC, building, paint, write_map

pytestmark = pytest.mark.filterwarnings("ignore::scenes.materials.FrequencyRangeWarning")

F = 865e6


@pytest.fixture(scope="module")
def two_rooms(tmp_path_factory):
    """Inside x in [0.7, 6.7], y in [0.7, 4.7]; a 0.2 m wall x in [3.6, 3.8] splits it in two
    rooms (joined to the outer wall: one obstacle, made brick by a point override)."""
    folder = tmp_path_factory.mktemp("rooms")
    g = building(width_m=6.0, length_m=4.0, wall_m=0.2, pad_m=0.5)
    paint(g, 3.6, 0.5, 3.8, 5.0, OCC)
    write_map(folder, g, name="rooms")
    (folder / "rooms.toml").write_text(
        '[map]\npath = "rooms.yaml"\nheight_m = 3.0\n'
        '[[map.override]]\npoint_m = [3.7, 2.7]\nmaterial = "brick"\n'
        '[tags]\nlayout = "none"\n')
    return scenes.load(folder / "rooms.toml")


def test_link_through_an_extracted_brick_wall_crosses_one_slab(two_rooms):
    brick = [s for s in two_rooms.radio_surfaces if s.material == "brick"]
    assert brick and all(s.kind == "wall" for s in brick)
    t = brick[0].thickness_m
    # brick's construction thickness (the material library's), not the drawn 0.2 m band
    # (scenes.mapspec.MapSpec.solid_wall_thickness_m)
    assert t == pytest.approx(0.12)
    tx = np.array([[2.0, 2.7, 1.5, 0.0]])
    rx = np.array([[5.5, 2.7, 1.5]])
    got = trace_links(two_rooms, tx, rx, TraceOptions(method="direct", max_depth=1, samples_per_src=10_000, reader_polarization="V",
                                                      reader_pattern="iso", tag_pattern="iso"))
    # max_depth = 1: every reflected path would need a second interaction (the crossing), so
    # the straight ray through the wall is the only path (as in test_radio_geometry.py)
    assert got.n_paths[0, 0] == 1
    fs = free_space_gain_db(3.5, F)
    closed = float(slab_transmission_db(*scenes.material("brick", F), t, F, 0.0, "TE"))
    # 0.5 dB: a single unobstructed ray differs from the closed form only by Sionna's float32
    # arithmetic; one crossing and two (a closed box) differ by several dB
    assert got.gain_db[0, 0] - fs == pytest.approx(closed, abs=0.5)
    assert abs(got.gain_db[0, 0] - fs - 2 * closed) > 3.0
