"""Radio maps (rssi_field) against PathSolver, and their NPZ round trip."""

import dataclasses

import numpy as np
import pytest

from propagation import CacheWarning, RssiField, rssi_field
from propagation.fields import wall_surface_mesh
from propagation.patterns import sionna_orientation

# the material library warns (by design) that P.2040 fits are extrapolated below 1 GHz
pytestmark = pytest.mark.filterwarnings("ignore::scenes.materials.FrequencyRangeWarning")

F = 865e6


@pytest.fixture(scope="module")
def field(corridor_scene):
    return rssi_field(corridor_scene, [3.0, 1.2, 1.0, 0.3, 0.1, 0.0], cell_size_m=0.2,
                      plane_height_m=1.1, samples_per_tx=8_000_000, max_depth=2,
                      wall_samples_per_tx=2_000_000, wall_max_edge_m=0.5, reader_polarization="V")


def test_radio_map_matches_incoherent_path_power(field, corridor_scene):
    """Cell means vs PathSolver at the cell centres: NMSE <= -20 dB.

    A radio-map cell holds the Monte-Carlo mean over the cell of the *power* of every ray
    crossing it (all polarisations, isotropic receiver): the local mean, with no phase.
    The comparable PathSolver quantity is therefore the incoherent sum over paths of
    |a|^2, summed over both receive polarisations (iso VH receiver), at the cell centre;
    it varies slowly over a 0.2 m cell, while the coherent sum |sum a|^2 fades by tens of dB
    within half a wavelength and is not comparable.
    """
    import sionna.rt as rt

    from propagation.sionna_scene import load_sionna_scene

    pose = field.antenna_pose
    centres = field.plane_centers_m.reshape(-1, 3)
    gains = field.plane_gain.reshape(-1)
    # cells 1.5-15 m from the antenna, inside the corridor, away from the walls
    d = np.linalg.norm(centres - pose[:3], axis=1)
    pick = np.flatnonzero((d > 1.5) & (d < 15) & (centres[:, 1] > 0.3) & (centres[:, 1] < 2.1)
                          & (centres[:, 0] > 0.3))
    pick = pick[:: max(1, len(pick) // 40)]
    s = load_sionna_scene(corridor_scene, F)
    s.tx_array = rt.PlanarArray(num_rows=1, num_cols=1, pattern="tr38901", polarization="V")
    s.rx_array = rt.PlanarArray(num_rows=1, num_cols=1, pattern="iso", polarization="VH")
    o = sionna_orientation(pose[3], pose[4], pose[5])
    s.add(rt.Transmitter("tx", position=[float(v) for v in pose[:3]], orientation=[float(v) for v in o]))
    for k, c in enumerate(centres[pick]):
        s.add(rt.Receiver(f"rx{k}", position=[float(v) for v in c]))
    paths = rt.PathSolver()(s, max_depth=2, samples_per_src=200_000, max_num_paths_per_src=600_000)
    a_re, a_im = (x.numpy() for x in paths.a)
    p_inc = (a_re**2 + a_im**2).sum(axis=(1, 2, 3, 4))  # (n_rx,)
    ref = p_inc
    rm = gains[pick]
    nmse_db = 10 * np.log10(np.sum((rm - ref) ** 2) / np.sum(ref**2))
    # -20 dB (brief): what remains is Monte-Carlo noise (8e6 rays: ~60 rays per path per
    # 0.04 m2 cell at 10 m, +-1-3 dB per cell; 2e6 rays gave -16.5 dB) and the cell average
    assert nmse_db <= -20.0, nmse_db


def test_wall_surface_map_and_roundtrip(field, tmp_path):
    assert field.wall_gain.shape == (len(field.wall_centers_m),)
    assert len(field.wall_gain) > 100
    # wall triangles are vertical and sit in free space (inside the corridor's y-range)
    assert np.all(np.abs(field.wall_normals[:, 2]) < 0.1)
    assert np.mean(field.wall_gain > 0) > 0.5
    path = field.save(tmp_path / "f.npz")
    back = RssiField.load(path)
    np.testing.assert_array_equal(back.plane_gain, field.plane_gain)
    np.testing.assert_array_equal(back.wall_centers_m, field.wall_centers_m)
    assert back.max_depth == field.max_depth and back.reader_pattern == "tr38901"
    bad = tmp_path / "bad.npz"
    np.savez(bad, x=np.zeros(2))
    with pytest.raises(ValueError, match="bad.npz"):
        RssiField.load(bad)


def test_rssi_field_bad_pose(corridor_scene):
    with pytest.raises(ValueError, match="outside"):
        rssi_field(corridor_scene, [-3.0, 1.2, 1.0, 0.0], include_walls=False)
    with pytest.raises(ValueError, match="4 or 6"):
        rssi_field(corridor_scene, [3.0, 1.2, 1.0], include_walls=False)


def test_default_plane_bounds_and_field_cache(corridor_scene, tmp_path):
    # no plane_bounds_m: the plane spans the scene bounds (this call used to fail inside mi.Point3f)
    kw = dict(cell_size_m=0.5, samples_per_tx=100_000, max_depth=1, include_walls=False, cache_dir=tmp_path)
    f = rssi_field(corridor_scene, [3.0, 1.2, 1.0, 0.0], **kw)
    lo, hi = corridor_scene.bounds_m
    c = f.plane_centers_m.reshape(-1, 3)
    # cells of 0.5 m cover the bounds: centres within half a cell of them
    assert c[:, 0].min() < lo[0] + 0.5 and c[:, 0].max() > hi[0] - 0.5
    assert c[:, 1].min() < lo[1] + 0.5 and c[:, 1].max() > hi[1] - 0.5
    assert np.mean(f.plane_gain > 0) > 0.5
    (cached,) = tmp_path.glob("rssi_field-*.npz")
    # the second call reads the file (not rewritten) and gets the same values
    written = cached.stat().st_mtime_ns
    again = rssi_field(corridor_scene, [3.0, 1.2, 1.0, 0.0], **kw)
    np.testing.assert_array_equal(again.plane_gain, f.plane_gain)
    assert cached.stat().st_mtime_ns == written
    # a file re-saved with other values (gains x10: corridor coverage 0.203 -> 0.344 once)
    # fails the checksum saved beside it: named, and computed again
    dataclasses.replace(f, plane_gain=f.plane_gain * 10).save(cached)
    with pytest.warns(CacheWarning, match="do not match the checksum"):
        again = rssi_field(corridor_scene, [3.0, 1.2, 1.0, 0.0], **kw)
    np.testing.assert_allclose(again.plane_gain, f.plane_gain, rtol=1e-5)  # see below for 1e-5
    # another setting is another key; a damaged file is reported by name and recomputed
    other = rssi_field(corridor_scene, [3.0, 1.2, 1.0, 0.0], **{**kw, "seed": 1})
    assert len(list(tmp_path.glob("rssi_field-*.npz"))) == 2 and not np.array_equal(other.plane_gain, f.plane_gain)
    cached.write_bytes(b"junk")
    with pytest.warns(CacheWarning, match=cached.name):
        fixed = rssi_field(corridor_scene, [3.0, 1.2, 1.0, 0.0], **kw)
    # same seed, same rays; the float32 atomic accumulation order differs between runs (1e-6)
    np.testing.assert_allclose(fixed.plane_gain, f.plane_gain, rtol=1e-5)


def test_wall_surface_is_a_regular_grid(corridor_scene):
    """One grid per wall plane: cells of at most max_edge_m, area equal to the faces'."""
    surf = wall_surface_mesh(corridor_scene, max_edge_m=0.25)
    tri = surf.triangles
    edges = np.sort(np.linalg.norm(tri[:, [1, 2, 0]] - tri, axis=2), axis=1)
    assert edges[:, :2].max() <= 0.25 + 1e-9  # the right-angle legs are the cell edges
    # inner faces of the corridor: two long walls 25.2 x 3 m (the slabs run over the corners,
    # x in [-0.1, 25.1]), two end walls 2.4 x 3 m; floor and ceiling are not vertical. A grid
    # over a rectangular face covers it exactly
    assert surf.area == pytest.approx(2 * 25.2 * 3 + 2 * 2.4 * 3, rel=1e-9)
    # cells per long wall ceil(25.2 / 0.25) = 101 by 3 / 0.25 = 12; per end wall 10 by 12
    assert len(surf.faces) == 2 * (2 * 101 * 12 + 2 * 10 * 12)
    with pytest.raises(ValueError, match="wall_max_edge_m"):
        wall_surface_mesh(corridor_scene, max_edge_m=0.0)



def test_circular_reader_field_is_the_linear_panels_halved(corridor_scene):
    """A radio map's receiver takes the whole wave; a linear tag takes half of a circular
    wave (|(1, -j) / sqrt(2) . e|^2 = 1/2 for any real unit e: 3.01 dB), and a circular and a
    V panel of one pattern radiate the same power in every direction. So the circular
    reader's map is the V panel's, halved: same seed and rays, so equal up to the float32
    atomic accumulation order (1e-5, as above)."""
    kw = dict(cell_size_m=0.5, samples_per_tx=100_000, max_depth=1, include_walls=False)
    lin = rssi_field(corridor_scene, [3.0, 1.2, 1.0, 0.0], reader_polarization="V", **kw)
    circ = rssi_field(corridor_scene, [3.0, 1.2, 1.0, 0.0], **kw)  # default: RHCP
    assert circ.reader_polarization == "RHCP"
    assert np.mean(lin.plane_gain > 0) > 0.5
    np.testing.assert_allclose(circ.plane_gain, 0.5 * lin.plane_gain, rtol=1e-5)
    with pytest.raises(ValueError, match="reader_polarization"):
        rssi_field(corridor_scene, [3.0, 1.2, 1.0, 0.0], reader_polarization="X", **kw)
