"""The sensor-model interface every metric runs on (ANFIS model and baselines alike).

``fuzzymodel.SensorModel`` satisfies it; so does
:class:`pipeline.evaluation.baselines.BaselineSensorModel`.
"""

from __future__ import annotations

from typing import Protocol, runtime_checkable

import numpy as np

__all__ = ["SensorLike", "check_sensor", "detection_probability", "uses_tag_height"]


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


def uses_tag_height(sensor) -> bool:
    """Whether `sensor` has ``fT_at_height(d, alpha, dz)``: a detection probability that
    depends on the tag's height above the antenna ``dz`` [m] beyond the 3-D range d (Vorst
    & Zell's ground-plane table, :mod:`pipeline.sensormodels.vorst2008`)."""
    return callable(getattr(sensor, "fT_at_height", None))


def detection_probability(sensor, d, alpha, dz=None) -> np.ndarray:
    """``fT`` of `sensor` at (d [m], alpha [rad]), at the tag height above the antenna
    ``dz`` [m] (broadcast with d) where the caller knows it and the model uses it
    (:func:`uses_tag_height`); every other model, or ``dz`` None: ``sensor.fT(d, alpha)``.

    The one entry point for callers that know the height (the localisers' candidates and
    tags, the held-out links): a model that ignores the height sees exactly ``fT``.
    """
    if dz is not None and uses_tag_height(sensor):
        return sensor.fT_at_height(d, alpha, dz)
    return sensor.fT(d, alpha)
