"""ROS map_server maps: reading (modes, negate, thresholds), unknown cells, bad maps, and the
walls extracted from a map with known rectangles (precision and recall of wall points)."""

import numpy as np
import pytest
from PIL import Image
from shapely.geometry import LineString, MultiLineString, Polygon

import scenes
from scenes.mapextract import extract_obstacles
from scenes.rosmap import FREE, OBSTACLE, OUTSIDE, UNKNOWN, RosMapError, read_map, resolve_unknown
from tests.scenes.maphelpers import OCC, RES, blank, building, paint, write_map
from tests.scenes.maphelpers import UNKNOWN as GREY

# Truth rectangles (metres) with edges off the 5 cm grid (x.02, x.97): a rasterised edge then
# sits up to half a cell from the truth, as in a real map.
RACK = (3.02, 2.01, 7.03, 2.62)
THICK = (2.02, 4.51, 5.97, 4.79)


def _truth_map(tmp_path, **keys):
    g = building(width_m=9.0, length_m=6.0, wall_m=0.2, pad_m=0.5)  # inside x, y in [0.7, 9.7/6.7]
    for r in (RACK, THICK):
        paint(g, *r, OCC)
    return write_map(tmp_path, g, **keys)


def _outline_points(geom, step_m: float) -> np.ndarray:
    """Points every ``step_m`` along the boundary lines of a shapely geometry."""
    lines = geom.boundary
    lines = list(lines.geoms) if isinstance(lines, MultiLineString) else [lines]
    pts = []
    for ln in lines:
        n = max(2, int(np.ceil(ln.length / step_m)))
        pts += [ln.interpolate(t, normalized=True).coords[0] for t in np.linspace(0, 1, n)]
    return np.array(pts)


def _distance(points: np.ndarray, geoms) -> np.ndarray:
    bnd = [g.boundary for g in geoms]
    return np.array([min(b.distance(LineString([p, p])) for b in bnd) for p in points])


def test_walls_of_known_rectangles_within_one_cell(tmp_path):
    rm = read_map(_truth_map(tmp_path))
    obstacles = extract_obstacles(rm)
    pad = 0.5
    outer = Polygon([(pad, pad), (pad + 9.4, pad), (pad + 9.4, pad + 6.4), (pad, pad + 6.4)],
                    [[(0.7, 0.7), (9.7, 0.7), (9.7, 6.7), (0.7, 6.7)]])
    truth = [outer] + [Polygon([(r[0], r[1]), (r[2], r[1]), (r[2], r[3]), (r[0], r[3])]) for r in (RACK, THICK)]
    found = [o.polygon for o in obstacles]
    assert len(found) == 3
    got = np.vstack([_outline_points(p, RES / 2) for p in found])
    want = np.vstack([_outline_points(p, RES / 2) for p in truth])
    # within one cell: the outline lies on cell edges (a truth edge off the grid is up to half
    # a cell away) and simplification moves it by at most tolerance_m = half a cell
    precision = np.mean(_distance(got, truth) <= RES + 1e-9)
    recall = np.mean(_distance(want, found) <= RES + 1e-9)
    assert precision == 1.0 and recall == 1.0
    # and the test can fail: the same points against rectangles moved by two cells do not match
    shifted = [Polygon(np.asarray(t.exterior.coords) + [2 * RES, 0]) for t in truth[1:]]
    assert np.mean(_distance(_outline_points(found[1], RES / 2), shifted) <= RES) < 0.9


def test_negate_and_scale_give_the_same_walls(tmp_path):
    base = read_map(_truth_map(tmp_path / "a"))
    g = np.flipud(np.asarray(Image.open(tmp_path / "a" / "map.pgm")))
    inv = 255 - g  # white = occupied, read with negate: 1
    neg = read_map(write_map(tmp_path / "b", inv, negate=1))
    assert np.array_equal(neg.cell_class, base.cell_class)
    assert np.array_equal(neg.occupancy, base.occupancy)
    scale = read_map(_truth_map(tmp_path / "c", mode="scale"))
    assert np.array_equal(scale.cell_class, base.cell_class)
    # map_saver's unknown grey 205: p = 50/255 = 0.196 just above free_thresh 0.196; scale mode
    # publishes 1 + 98 (p - free) / (occ - free) there (ROS map_server), trinary -1
    grey = base.cell_class == UNKNOWN
    p = 50 / 255
    assert np.all(scale.occupancy[grey] == round(1 + 98 * (p - 0.196) / (0.65 - 0.196)))
    assert np.all(base.occupancy[grey] == -1)
    a = [o.polygon for o in extract_obstacles(base)]
    b = [o.polygon for o in extract_obstacles(scale)]
    assert all(x.symmetric_difference(y).area < 1e-9 for x, y in zip(a, b, strict=True))


def test_raw_mode_reads_values_as_occupancy(tmp_path):
    g = blank(2.0, 2.0, 0)
    paint(g, 0.0, 0.0, 1.0, 2.0, 100)
    paint(g, 1.0, 1.0, 2.0, 2.0, 255)
    rm = read_map(write_map(tmp_path, g, mode="raw"))
    assert set(np.unique(rm.occupancy).tolist()) == {-1, 0, 100}
    assert np.all(rm.cell_class[rm.occupancy == 100] == OBSTACLE)
    assert np.all(rm.cell_class[rm.occupancy == 0] == FREE)


def test_unknown_cells_outside_free_or_solid(tmp_path):
    g = building(width_m=4.0, length_m=4.0)
    paint(g, 1.5, 1.5, 1.8, 1.8, GREY)  # an unexplored patch in the room
    paint(g, 3.0, 3.0, 4.0, 4.0, OCC)  # a block with an unseen inside
    paint(g, 3.3, 3.3, 3.7, 3.7, GREY)
    rm = read_map(write_map(tmp_path, g))
    cls = resolve_unknown(rm.cell_class)

    def at(x, y):
        return cls[int(y / RES), int(x / RES)]

    assert at(0.1, 0.1) == OUTSIDE  # the grey margin around the building
    assert at(1.65, 1.65) == FREE
    assert at(3.5, 3.5) == OBSTACLE
    assert not np.any(cls == UNKNOWN)


def _bad(tmp_path, **keys):
    return write_map(tmp_path, building(2.0, 2.0), **keys)


BAD = {
    "missing image": (dict(image="nope.pgm"), "'image'"),
    "zero resolution": (dict(resolution=0.0), "'resolution'"),
    "negative resolution": (dict(resolution=-0.05), "'resolution'"),
    "unknown key": (dict(frame="map"), "'frame'"),
    "bad mode": (dict(mode="ternary"), "'mode'"),
    "rotated origin": (dict(origin="[0.0, 0.0, 0.5]"), "'origin'"),
    "thresholds": (dict(free_thresh=0.7), "'free_thresh'"),
    "negate 2": (dict(negate=2), "'negate'"),
    "finer than a millimetre": (dict(resolution="0.0001"), "MIN_RESOLUTION_M"),
    "origin beyond any building": (dict(origin="[1e300, 0.0, 0.0]"), "within 1e6 m"),
}


@pytest.mark.parametrize("case", list(BAD))
def test_bad_maps_name_file_and_key(tmp_path, case):
    keys, key = BAD[case]
    path = _bad(tmp_path, **keys)
    with pytest.raises(RosMapError) as err:
        scenes.load(path)
    msg = str(err.value)
    assert "\n" not in msg and str(path) in msg and key in msg


def test_numbers_read_as_ros_reads_them_and_errors_quote_a_prefix(tmp_path):
    """YAML 1.1 reads ``5e-2`` (no dot) as a string; ROS's map_server (yaml-cpp
    ``as<double>``) reads a number: so do we. An error quotes at most a short prefix."""
    path = write_map(tmp_path, building(2.0, 2.0), resolution="5e-2")
    assert read_map(path).resolution_m == pytest.approx(0.05)
    long = "x" * 5000
    bad = write_map(tmp_path / "b", building(2.0, 2.0), resolution=f"'{long}'")
    with pytest.raises(RosMapError) as err:
        read_map(bad)
    assert "'resolution'" in str(err.value) and len(str(err.value)) < 300


def test_an_image_too_large_is_refused_before_decoding(tmp_path, monkeypatch):
    """The pixel count is read from the header: a map image above MAX_PIXELS is refused,
    named, before its pixels are decoded (a 20000 x 20000 image took gigabytes)."""
    import scenes.rosmap as rosmap

    path = write_map(tmp_path, building(2.0, 2.0))
    n = read_map(path).shape[0] * read_map(path).shape[1]
    monkeypatch.setattr(rosmap, "MAX_PIXELS", n - 1)  # the bound, not a giant file, is under test
    with pytest.raises(RosMapError, match=r"more than .* \(MAX_PIXELS\)"):
        read_map(path)


def test_an_image_the_yaml_describes_wrongly_is_refused(tmp_path):
    # a resolution in the wrong unit: the padded 2 m building's 68-pixel image at
    # 100 m/cell is 6.8 km across
    with pytest.raises(RosMapError, match=r"key 'resolution': 100.0 m/cell .* metres per cell"):
        read_map(_bad(tmp_path / "a", resolution=100.0))
    # mode raw over a grey-level map (free 254, unknown 205)
    with pytest.raises(RosMapError, match=r"key 'mode': 'raw' .* grey-level map"):
        read_map(_bad(tmp_path / "b", mode="raw"))
    # a raw occupancy image (0 free, 100 occupied, 255 unknown) read as trinary
    g = blank(2.0, 2.0, 0)
    paint(g, 0.0, 0.0, 0.2, 2.0, 100)
    paint(g, 1.5, 1.5, 2.0, 2.0, 255)
    with pytest.raises(RosMapError, match=r"key 'mode': .* use mode 'raw'"):
        read_map(write_map(tmp_path / "c", g, mode="trinary"))
    assert read_map(write_map(tmp_path / "d", g, mode="raw")).occupancy.max() == 100
    # the same raw map saved negated (255 - occupancy) with negate: 1 is no mismatch
    neg = read_map(write_map(tmp_path / "e", 255 - g, mode="raw", negate=1))
    assert np.array_equal(neg.occupancy, read_map(tmp_path / "d" / "map.yaml").occupancy)


def test_no_free_space_and_garbage_image(tmp_path):
    path = write_map(tmp_path / "a", blank(2.0, 2.0, OCC))
    with pytest.raises(RosMapError, match=r"map\.yaml: key 'image': .*no free cell"):
        read_map(path)
    (tmp_path / "b").mkdir()
    (tmp_path / "b" / "g.pgm").write_bytes(b"not an image")
    (tmp_path / "b" / "g.yaml").write_text("image: g.pgm\nresolution: 0.05\norigin: [0, 0, 0]\n")
    with pytest.raises(RosMapError, match=r"g\.yaml: key 'image': cannot read"):
        read_map(tmp_path / "b" / "g.yaml")
    with pytest.raises(FileNotFoundError, match="nothere.yaml"):
        scenes.load(tmp_path / "nothere.yaml")


def test_png_and_pgm_read_alike(tmp_path):
    g = building(3.0, 2.0)
    a = read_map(write_map(tmp_path, g, name="a"))
    b = read_map(write_map(tmp_path, g, name="b", suffix=".png"))
    assert np.array_equal(a.occupancy, b.occupancy)
    assert a.digest() == b.digest()


def test_yaml_aliases_and_oversized_yaml_are_refused_before_expanding(tmp_path):
    """A "billion laughs" nest of aliases, under any key, and a YAML far larger than a
    map_server file: one line each, before anything is expanded (9.5 GB before)."""
    path = write_map(tmp_path, building(2.0, 2.0))
    text = path.read_text()
    laughs = "".join(f"l{i}: &l{i} [" + ", ".join([f"*l{i - 1}"] * 9 if i else ['"x"'] * 9) + "]\n"
                     for i in range(9))
    for name, body in (("list.yaml", text + laughs),
                       ("origin.yaml", text.replace("origin: [0.0, 0.0, 0.0]",
                                                    "o: &o 0.0\norigin: [*o, *o, 0.0]"))):
        (tmp_path / name).write_text(body)
        with pytest.raises(RosMapError, match="YAML alias") as err:
            read_map(tmp_path / name)
        assert "\n" not in str(err.value) and len(str(err.value)) < 300
    (tmp_path / "big.yaml").write_text(text + "#" * 100_000 + "\n")
    with pytest.raises(RosMapError, match="MAX_YAML_BYTES"):
        read_map(tmp_path / "big.yaml")


def test_a_decompression_bomb_is_a_map_error_not_a_traceback(tmp_path):
    """A PNG whose header declares 20000 x 20000 pixels (beyond Pillow's own limit):
    refused by name before a pixel is decoded (a DecompressionBombError before)."""
    import struct
    import zlib

    def chunk(kind: bytes, data: bytes) -> bytes:
        return struct.pack(">I", len(data)) + kind + data + struct.pack(">I", zlib.crc32(kind + data))

    png = (b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", struct.pack(">IIBBBBB", 20000, 20000, 8, 0, 0, 0, 0))
           + chunk(b"IDAT", zlib.compress(b"\x00" * 100)) + chunk(b"IEND", b""))
    path = write_map(tmp_path, building(2.0, 2.0), name="bomb", image_name="bomb.png")
    (tmp_path / "bomb.png").write_bytes(png)  # the map's image replaced by the bomb
    with pytest.raises(RosMapError, match="MAX_PIXELS") as err:
        read_map(path)
    assert "\n" not in str(err.value)
