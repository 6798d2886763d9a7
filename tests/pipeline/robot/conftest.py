"""Test scenes for the robot package: the tests' synthetic corridor (with cabinets, so the
laser sees features along it) and closed rooms (tests.helpers.scenes)."""

import pytest

from tests.helpers.scenes import box_corridor, box_room


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
