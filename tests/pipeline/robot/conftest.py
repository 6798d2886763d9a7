"""Test scenes for the robot package, built from trimesh boxes.

A corridor along +x from 0 to length, free space y in [0, width], walls as 0.2 m slabs
outside it, end walls, and cabinets (0.5 m deep boxes) against alternating walls so the
laser sees features along the corridor.
"""

import numpy as np
import pytest
import trimesh

from scenes import Scene, TagSet


def _box(lo, hi):
    lo, hi = np.asarray(lo, float), np.asarray(hi, float)
    b = trimesh.creation.box(extents=hi - lo)
    b.apply_translation((lo + hi) / 2)
    return b


def box_corridor(length_m=20.0, width_m=2.4, height_m=3.0, cabinets=True, name="test_corridor"):
    t = 0.2
    walls = [
        _box([-t, -t, 0], [length_m + t, 0, height_m]),
        _box([-t, width_m, 0], [length_m + t, width_m + t, height_m]),
        _box([-t, 0, 0], [0, width_m, height_m]),
        _box([length_m, 0, 0], [length_m + t, width_m, height_m]),
    ]
    floor = _box([-t, -t, -0.1], [length_m + t, width_m + t, 0])
    meshes = {
        "plasterboard": trimesh.util.concatenate(walls),
        "concrete": floor,
    }
    if cabinets:
        boxes = []
        for i, x in enumerate(np.arange(2.5, length_m - 2.0, 3.3)):
            if i % 2 == 0:
                boxes.append(_box([x, 0, 0], [x + 0.9, 0.45, 1.2]))
            else:
                boxes.append(_box([x, width_m - 0.45, 0], [x + 0.9, width_m, 1.2]))
        meshes["wood"] = trimesh.util.concatenate(boxes)
    tags = TagSet(np.array([], dtype=str), np.zeros((0, 3)), np.zeros((0, 3)))
    route = np.array([[0.0, width_m / 2], [length_m, width_m / 2]])
    return Scene(name=name, meshes=meshes, tags=tags, route_m=route)


def box_room(size_x=4.0, size_y=3.0, height=2.5):
    t = 0.2
    walls = [
        _box([-t, -t, 0], [size_x + t, 0, height]),
        _box([-t, size_y, 0], [size_x + t, size_y + t, height]),
        _box([-t, 0, 0], [0, size_y, height]),
        _box([size_x, 0, 0], [size_x + t, size_y, height]),
    ]
    tags = TagSet(np.array([], dtype=str), np.zeros((0, 3)), np.zeros((0, 3)))
    return Scene(
        name="box_room",
        meshes={"concrete": trimesh.util.concatenate(walls)},
        tags=tags,
        route_m=np.array([[0.5, size_y / 2], [size_x - 0.5, size_y / 2]]),
    )


@pytest.fixture(scope="session")
def corridor():
    return box_corridor()


@pytest.fixture(scope="session")
def room():
    return box_room()


@pytest.fixture(scope="session")
def hall():
    """A 9 m x 12 m hall: driving 1 m from its south wall, the laser (8 m) sees only that
    wall and the east wall ahead, so the south wall alone fixes the robot's lateral position."""
    return box_room(size_x=9.0, size_y=12.0)
