"""Fixtures of the propagation tests: the backend and the small scenes of tests.helpers.scenes."""

import os

import pytest

from tests.helpers.scenes import make_corridor, make_far_floor_scene, make_floor_scene


@pytest.fixture(scope="session", autouse=True)
def _backend():
    """Pick the Mitsuba variant once (LLVM on these machines)."""
    from propagation import select_variant

    select_variant(os.environ.get("RFIDSTUDY_VARIANT", "auto"))


@pytest.fixture(scope="session")
def floor_scene():
    return make_floor_scene()


@pytest.fixture(scope="session")
def far_floor_scene():
    return make_far_floor_scene()


@pytest.fixture(scope="session")
def corridor_scene():
    return make_corridor()
