"""A known synthetic sensor and read attempts sampled from it, shared by the model tests.

Truth: inside the cone |alpha| <= 45 deg a tag is read with probability
``0.95 - 0.25 d`` (0.925 at d = 0.1 m down to 0.2 at 3 m), outside with 0.05; a read's
RSSI is ``-40 - 20 log10(d) + N(0, 2 dB)``. Attempts have d uniform in [0.1, 3) m and
alpha uniform in (-pi, pi].
"""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest

from pipeline.sensormodels import Attempts

D_LO, D_HI = 0.1, 3.0
CONE = np.pi / 4
SIGMA_DB = 2.0
RSSI_RANGE = (-80.0, -30.0)


def p_true(d, alpha):
    """Detection probability of the synthetic sensor."""
    d, alpha = np.broadcast_arrays(np.asarray(d, float), np.asarray(alpha, float))
    return np.where(np.abs(alpha) <= CONE, 0.95 - 0.25 * d, 0.05)


def rssi_true(d):
    """Mean RSSI of a read [dBm]."""
    return -40.0 - 20.0 * np.log10(np.asarray(d, float))


def sample(n: int, seed: int, p=p_true):
    """`n` attempts drawn from the synthetic sensor (or from detection probability `p`)."""
    rng = np.random.default_rng(seed)
    d = rng.uniform(D_LO, D_HI, n)
    a = rng.uniform(-np.pi, np.pi, n)
    read = rng.random(n) < p(d, a)
    rssi = np.where(read, rssi_true(d) + rng.normal(0.0, SIGMA_DB, n), np.nan)
    return d, a, read, rssi


def as_reads(d, a, read, rssi) -> pd.DataFrame:
    """A reads.parquet-like table (MCL and true geometry equal)."""
    return pd.DataFrame({"read": read, "rssi_dbm": rssi, "d_est_m": d, "alpha_est_rad": a,
                         "d_true_m": d, "alpha_true_rad": a})


@pytest.fixture(scope="session")
def big_sample():
    """200 000 attempts: a few hundred per (0.25 m, 15 deg) cell."""
    return sample(200_000, seed=1)


@pytest.fixture(scope="session")
def big_attempts(big_sample):
    return Attempts(*big_sample)


class Synthetic:
    """The helpers above as one object (test modules take it from the ``synth`` fixture)."""

    D_LO, D_HI, CONE, SIGMA_DB, RSSI_RANGE = D_LO, D_HI, CONE, SIGMA_DB, RSSI_RANGE
    p_true = staticmethod(p_true)
    rssi_true = staticmethod(rssi_true)
    sample = staticmethod(sample)
    as_reads = staticmethod(as_reads)


@pytest.fixture(scope="session")
def synth():
    return Synthetic
