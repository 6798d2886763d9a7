"""Tags on walls (``[tags] walls = true``): on the room-facing faces of wall obstacles,
facing free space, never in a door gap, never against another obstacle; the planned route
passes the wall faces too."""

import numpy as np
import pytest

import scenes
from scenes.rosmap import FREE
from scenes.spec import SpecError
from tests.scenes.maphelpers import OCC, RES, building, paint, write_map

# inside x in [0.75, 10.75], y in [0.75, 7.75]; an office in the top-left corner behind a
# 0.1 m partition with a 2 m door gap (x 3.0 .. 5.0); a rack in the hall
PARTITION_W = (0.75, 5.0, 3.0, 5.1)
PARTITION_E = (5.0, 5.0, 6.1, 5.1)
PARTITION_N = (6.0, 5.0, 6.1, 7.75)
DOOR_X = (3.0, 5.0)
RACK = (3.0, 2.2, 8.0, 3.0)
HEIGHTS = (0.85, 1.35)


def _write(tmp_path, walls="true", extra=""):
    g = building(width_m=10.0, length_m=7.0, wall_m=0.25, pad_m=0.5)
    for r in (PARTITION_W, PARTITION_E, PARTITION_N, RACK):
        paint(g, *r, OCC)
    write_map(tmp_path, g, name="office")
    path = tmp_path / "office.toml"
    path.write_text('name = "office"\n[map]\npath = "office.yaml"\nheight_m = 3.0\nroute_standoff_m = 1.3\n'
                    f'[tags]\nheights_m = [0.85, 1.35]\nspacing_m = 1.0\nwalls = {walls}\n{extra}')
    return path


@pytest.fixture(scope="module")
def office(tmp_path_factory):
    return scenes.load(_write(tmp_path_factory.mktemp("office")))


def _walls(sc):
    w = np.array([str(i).startswith("W") for i in sc.tags.ids])
    return sc.tags.positions_m[w], sc.tags.normals[w]


def test_wall_tags_sit_on_wall_faces_facing_free_space(office):
    pos, nrm = _walls(office)
    shelf = len(office.tags) - len(pos)
    assert shelf == 2 * 2 * 5  # the rack's two fronts, two heights, (5 - 0.4) // 1 + 1 tags
    assert len(pos) > 0 and set(np.round(pos[:, 2], 3)) == set(HEIGHTS)
    assert np.allclose(np.linalg.norm(nrm[:, :2], axis=1), 1.0) and np.allclose(nrm[:, 2], 0.0)
    # on a wall face: the point 1 cm behind the tag (5 mm offset + 5 mm) is in a wall's solid
    behind = scenes.solid_material_at(office, pos - 0.01 * nrm)
    assert set(behind) <= {"concrete", "plasterboard"} and "" not in set(behind)
    # the face is where the map's cells are: within one cell of a wall drawn in the map
    faces = np.array([0.75, 10.75])  # outer wall's inner faces in x; y: 0.75, 7.75
    on_outer = (np.isclose(pos[:, 0], faces[:, None], atol=RES).any(axis=0)
                | np.isclose(pos[:, 1], [[0.75], [7.75]], atol=RES).any(axis=0))
    on_part = (np.isclose(pos[:, 1], [[5.0], [5.1]], atol=RES).any(axis=0)
               | np.isclose(pos[:, 0], [[6.0], [6.1]], atol=RES).any(axis=0))
    assert np.all(on_outer | on_part)
    # the normal points into free space: 0.3 m along it is a free cell of the map
    rm = office.rosmap
    probe = pos[:, :2] + 0.3 * nrm[:, :2]
    col, row = np.floor((probe - rm.origin_m) / rm.resolution_m).astype(int).T
    assert np.all(rm.cell_class[row, col] == FREE)
    # no tag in the office's door gap, none on the partition's ends (the door jambs)
    in_gap = (pos[:, 0] > DOOR_X[0] - 0.1) & (pos[:, 0] < DOOR_X[1] + 0.1) & (np.abs(pos[:, 1] - 5.05) < 0.2)
    assert not np.any(in_gap)
    # both faces of the partition carry tags: the hall side (-y) and the office side (+y)
    part = np.abs(pos[:, 1] - 5.05) < 0.1
    assert set(np.round(nrm[part, 1]).astype(int)) == {-1, 1}
    # none within margin_m of another obstacle (the partitions abutting the outer wall)
    assert not np.any((pos[:, 1] > 4.8) & (pos[:, 1] < 5.3) & (pos[:, 0] < 0.8))


def test_walls_off_by_default(tmp_path):
    sc = scenes.load(_write(tmp_path, walls="false"))
    assert len(sc.tags) == 2 * 2 * 5 and not any(str(i).startswith("W") for i in sc.tags.ids)


@pytest.mark.parametrize("walls, extra, message", [
    ('"yes"', "", r"\[tags\]: key 'walls' must be"),
    ("true", 'layout = "none"\n', r"\[tags\]: key 'walls' needs layout = 'shelves'"),
])
def test_bad_walls_values_name_the_key(tmp_path, walls, extra, message):
    with pytest.raises((SpecError, ValueError), match=message) as err:
        scenes.load(_write(tmp_path, walls=walls, extra=extra))
    assert "\n" not in str(err.value) and "office.toml" in str(err.value)


def test_wall_tag_height_above_the_ceiling_names_the_key(tmp_path):
    path = _write(tmp_path)
    g = building(width_m=10.0, length_m=7.0, wall_m=0.25, pad_m=0.5)
    paint(g, *PARTITION_W, OCC)
    write_map(tmp_path, g, name="office")  # no rack: wall tag heights need not be on a beam
    path.write_text(path.read_text().replace("heights_m = [0.85, 1.35]", "heights_m = [1.0, 3.2]"))
    with pytest.raises(SpecError, match=r"\[tags\] key 'heights_m': 3.2 m is not between the floor") as err:
        scenes.load(path)
    assert "\n" not in str(err.value) and "office.toml" in str(err.value)


def test_planned_route_passes_the_wall_faces(office):
    from pipeline.robot import Robot, plan_coverage_route
    from pipeline.robot.coverage import _segment_distance

    plan = plan_coverage_route(office, Robot(), standoff_m=1.3)
    xy = office.tags.positions_m[:, :2]
    route = plan.route_m
    d = np.min([_segment_distance(xy, a, b) for a, b in zip(route[:-1], route[1:], strict=True)], axis=0)
    assert np.all(d <= 1.3 + 1e-9)
    # the partition's two sides are faces of their own; so are the office's and the hall's
    # parts of the outer wall (split where the partition meets it)
    wall_faces = [f for f in plan.faces if all(str(office.tags.ids[i]).startswith("W") for i in f.tag_index)]
    assert len(wall_faces) >= 8
