"""The sensor-model interface every metric runs on (ANFIS model and baselines alike).

``fuzzymodel.SensorModel`` satisfies it; so does
:class:`pipeline.evaluation.baselines.BaselineSensorModel`.
"""

from __future__ import annotations

from typing import Protocol, runtime_checkable

import numpy as np

__all__ = ["SensorLike", "check_sensor"]


@runtime_checkable
class SensorLike(Protocol):
    """A sensor model over (d [m], alpha [rad]); all methods broadcast their inputs.

    Attributes
    ----------
    rssi_range_dbm : tuple of float
        (lo, hi) [dBm] behind the normalisation ``fs = (rssi - lo) / (hi - lo)``.
    """

    rssi_range_dbm: tuple[float, float]

    def fs(self, d, alpha) -> np.ndarray:
        """Normalised RSSI in [0, 1]."""

    def fs_dbm(self, d, alpha) -> np.ndarray:
        """Expected RSSI [dBm]."""

    def fT(self, d, alpha) -> np.ndarray:  # noqa: N802 - the chapter's name
        """Detection probability in [0, 1]."""

    def rho(self, d, alpha) -> np.ndarray:
        """Sensor likelihood fs * fT in [0, 1]."""


def check_sensor(sensor, name: str = "sensor") -> SensorLike:
    """Return `sensor` if it has fs, fs_dbm, fT, rho and rssi_range_dbm; else raise TypeError."""
    missing = [m for m in ("fs", "fs_dbm", "fT", "rho", "rssi_range_dbm") if not hasattr(sensor, m)]
    if missing:
        raise TypeError(
            f"{name} ({type(sensor).__name__}) lacks {missing}; expected a SensorModel-like object"
        )
    return sensor
