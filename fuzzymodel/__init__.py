"""Fuzzy C-Means, ANFIS hybrid learning and the RFID sensor model.

Depends on NumPy only (scikit-fuzzy serves as a cross-check in the tests).
"""

from .anfis import ANFIS, PremiseGradient, TrainingHistory, update_step_size
from .clustering import FCMResult, fcm
from .errors import FuzzyModelError, FuzzyModelFileError
from .initfis import Premise, fcm_premise, grid_premise
from .membership import (
    MF_PARAM_NAMES,
    gaussmf,
    gaussmf_grad,
    gbellmf,
    gbellmf_grad,
    log_membership,
    log_membership_grad,
    membership,
    membership_grad,
)
from .sensor import SensorModel, denormalise_rssi, normalise_rssi, wrap_angle

__all__ = [
    "ANFIS",
    "FCMResult",
    "FuzzyModelError",
    "FuzzyModelFileError",
    "MF_PARAM_NAMES",
    "Premise",
    "PremiseGradient",
    "SensorModel",
    "TrainingHistory",
    "denormalise_rssi",
    "fcm",
    "fcm_premise",
    "gaussmf",
    "gaussmf_grad",
    "gbellmf",
    "gbellmf_grad",
    "grid_premise",
    "log_membership",
    "log_membership_grad",
    "membership",
    "membership_grad",
    "normalise_rssi",
    "update_step_size",
    "wrap_angle",
]
