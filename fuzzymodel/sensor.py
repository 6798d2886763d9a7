"""The RFID sensor model of Cicirelli, Milella & Di Paola (2011).

Two Takagi-Sugeno systems over (d, alpha): the signal-strength model
``fs(d, alpha)``, RSSI normalised to [0, 1] with a fixed dBm range stored in
the model, and the tag-detection model ``fT(d, alpha)``, the probability of a
read, clipped to [0, 1]. Their product ``rho = fs * fT`` is the likelihood the
chapter uses for tag localisation.

d is the antenna-to-tag distance [m]; alpha the bearing of the tag in the
antenna frame [rad], wrapped to (-pi, pi] before evaluation.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from .anfis import ANFIS
from .errors import FuzzyModelError, FuzzyModelFileError
from .persistence import (
    anfis_kwargs_from_dict,
    anfis_to_dict,
    package_version,
    read_json,
    require_keys,
    write_json,
)

__all__ = ["SENSOR_FORMAT", "SensorModel", "denormalise_rssi", "normalise_rssi", "wrap_angle"]

#: Format tag of a saved sensor model.
SENSOR_FORMAT = "rfidstudy.fuzzymodel.sensor/1"


def _check_range(range_dbm) -> tuple[float, float]:
    try:
        lo, hi = (float(v) for v in range_dbm)
    except (TypeError, ValueError) as exc:
        raise FuzzyModelError(f"rssi range_dbm must be (lo, hi), got {range_dbm!r}") from exc
    if not (np.isfinite(lo) and np.isfinite(hi) and lo < hi):
        raise FuzzyModelError(f"rssi range_dbm must be finite with lo < hi, got ({lo}, {hi})")
    return lo, hi


def normalise_rssi(rssi_dbm, range_dbm, clip: bool = True) -> np.ndarray:
    """Map RSSI [dBm] linearly onto [0, 1]: ``(rssi_dbm - lo) / (hi - lo)``.

    Parameters
    ----------
    rssi_dbm : array_like
        RSSI in dBm, any shape.
    range_dbm : (float, float)
        ``(lo, hi)`` in dBm, lo < hi; lo maps to 0, hi to 1.
    clip : bool
        Clip the result to [0, 1].

    Returns
    -------
    numpy.ndarray of float64, same shape as `rssi_dbm`
    """
    lo, hi = _check_range(range_dbm)
    out = (np.asarray(rssi_dbm, dtype=np.float64) - lo) / (hi - lo)
    return np.clip(out, 0.0, 1.0) if clip else out


def denormalise_rssi(fs, range_dbm) -> np.ndarray:
    """Inverse of :func:`normalise_rssi`: ``lo + fs * (hi - lo)`` in dBm."""
    lo, hi = _check_range(range_dbm)
    return lo + np.asarray(fs, dtype=np.float64) * (hi - lo)


def wrap_angle(angle_rad) -> np.ndarray:
    """Wrap angles [rad] to (-pi, pi].

    Parameters
    ----------
    angle_rad : array_like of float
        Any shape.

    Returns
    -------
    numpy.ndarray of float64
        A new array of the same shape (a NumPy scalar for a scalar input). Angles in
        range come back as they are, so an angle's result never depends on the other
        angles of the call; NaN stays NaN.
    """
    a = np.asarray(angle_rad, dtype=np.float64)
    # most callers pass angles in range already: two reductions cost a tenth of np.mod
    if a.ndim and a.size and a.min() > -np.pi and a.max() <= np.pi:
        return a.copy()
    out = np.array(a, dtype=np.float64, copy=True)
    bad = ~((out > -np.pi) & (out <= np.pi))  # NaN included: np.mod keeps it NaN
    wrapped = np.pi - np.mod(np.pi - out[bad], 2.0 * np.pi)
    # just above pi, np.mod rounds up to 2 pi and the formula gives -pi: outside (-pi, pi]
    wrapped[wrapped <= -np.pi] = np.pi
    out[bad] = wrapped
    return out[()] if out.ndim == 0 else out


class SensorModel:
    """RFID sensor model ``rho(d, alpha) = fs(d, alpha) * fT(d, alpha)``.

    Parameters
    ----------
    ssm : ANFIS
        Signal-strength model with inputs (d [m], alpha [rad]) trained on RSSI
        normalised by :func:`normalise_rssi` with `rssi_range_dbm`.
    tdm : ANFIS
        Tag-detection model with inputs (d [m], alpha [rad]) trained on the
        detection ratio n+ / (n+ + n-).
    rssi_range_dbm : (float, float)
        The fixed dBm range behind the normalisation of `ssm`'s target.
    """

    def __init__(self, ssm: ANFIS, tdm: ANFIS, rssi_range_dbm=(-80.0, -30.0)):
        for name, model in (("ssm", ssm), ("tdm", tdm)):
            if not isinstance(model, ANFIS):
                raise FuzzyModelError(f"{name} must be an ANFIS, got {type(model).__name__}")
            if model.n_inputs != 2:
                raise FuzzyModelError(f"{name} must have 2 inputs (d, alpha), has {model.n_inputs}")
        self.ssm = ssm
        self.tdm = tdm
        self.rssi_range_dbm = _check_range(rssi_range_dbm)

    @staticmethod
    def _eval(model: ANFIS, d, alpha) -> np.ndarray:
        d, a = np.broadcast_arrays(np.asarray(d, dtype=np.float64), wrap_angle(alpha))
        X = np.column_stack([d.ravel(), a.ravel()])
        return model.predict(X).reshape(d.shape)

    def fs(self, d, alpha) -> np.ndarray:
        """Normalised RSSI in [0, 1]; `d` [m] and `alpha` [rad] broadcast together."""
        return np.clip(self._eval(self.ssm, d, alpha), 0.0, 1.0)

    def fs_dbm(self, d, alpha) -> np.ndarray:
        """Expected RSSI [dBm]: :meth:`fs` mapped back through the stored range."""
        return denormalise_rssi(self.fs(d, alpha), self.rssi_range_dbm)

    def fT(self, d, alpha) -> np.ndarray:  # noqa: N802 - the chapter's name
        """Detection probability in [0, 1]; broadcasting as :meth:`fs`."""
        return np.clip(self._eval(self.tdm, d, alpha), 0.0, 1.0)

    def rho(self, d, alpha) -> np.ndarray:
        """Sensor likelihood ``fs * fT`` in [0, 1]; broadcasting as :meth:`fs`."""
        return self.fs(d, alpha) * self.fT(d, alpha)

    def save(self, path) -> Path:
        """Write both models and the RSSI range to one JSON file (atomic)."""
        return write_json(path, {
            "format": SENSOR_FORMAT,
            "description": "RFID sensor model rho(d, alpha) = fs * fT (Cicirelli et al. 2011)",
            "rssi_range_dbm": list(self.rssi_range_dbm),
            "package_version": package_version(),
            "ssm": anfis_to_dict(self.ssm),
            "tdm": anfis_to_dict(self.tdm),
        })

    @classmethod
    def load(cls, path) -> SensorModel:
        """Read a file written by :meth:`save`; errors name the file and key."""
        path = Path(path)
        d = read_json(path)
        require_keys(d, {"format", "rssi_range_dbm", "ssm", "tdm"},
                     {"description", "package_version"}, str(path))
        if d["format"] != SENSOR_FORMAT:
            raise FuzzyModelFileError(f"{path}: format {d['format']!r}, expected {SENSOR_FORMAT!r}")
        ssm = ANFIS(**anfis_kwargs_from_dict(d["ssm"], f"{path}: ssm"))
        tdm = ANFIS(**anfis_kwargs_from_dict(d["tdm"], f"{path}: tdm"))
        return cls(ssm, tdm, d["rssi_range_dbm"])
