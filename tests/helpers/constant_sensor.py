"""A sensor model with constant outputs, whose scores are known in closed form."""

from __future__ import annotations

import numpy as np


class ConstantSensor:
    """fs_dbm and fT constant: a model whose scores are known in closed form."""

    rssi_range_dbm = (-80.0, -30.0)

    def __init__(self, rssi_dbm, p):
        self.r, self.p = rssi_dbm, p

    def fs_dbm(self, d, a):
        return np.full(np.shape(d), self.r)

    def fs(self, d, a):
        return np.full(np.shape(d), (self.r + 80.0) / 50.0)

    def fT(self, d, a):  # noqa: N802
        return np.full(np.shape(d), self.p)

    def rho(self, d, a):
        return self.fs(d, a) * self.fT(d, a)
