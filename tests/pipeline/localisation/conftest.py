"""Shared synthetic data of the localisation tests (closed form, no ray tracing)."""

from __future__ import annotations

import numpy as np
import pytest

from pipeline.sensormodels import fit_joho2009
from tests.helpers.localisation import SyntheticSensor, sample_attempts


@pytest.fixture(scope="session")
def sensor() -> SyntheticSensor:
    return SyntheticSensor()


@pytest.fixture(scope="session")
def joho(sensor):
    """A Joho 2009 model fitted on 20 000 synthetic attempts within 3 m."""
    att = sample_attempts(sensor, 20000, np.random.default_rng(5))
    return fit_joho2009(att.within(3.0), sensor.rssi_range_dbm)
