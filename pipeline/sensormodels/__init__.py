"""The chapter's competitors as SensorLike models, and ablations of its own model.

Cicirelli, Milella & Di Paola (2011) compare their FCM + ANFIS sensor model with earlier
RFID sensor models. Each competitor here is fitted on the training tour's reads
(MCL geometry, attempts within d_max) and predicts what the learned
``rho = fs * fT`` predicts (see ``pipeline.evaluation.interface.SensorLike``):

* :mod:`.joho2009` - Joho, Plagemann & Burgard (ICRA 2009): detection rate and Gaussian
  RSSI per (d, alpha) cell, one joint likelihood of a read and its RSSI.
* :mod:`.liu2006` - the project's own sector read region with two constant detection
  probabilities, fitted by maximum likelihood; detection only. Key ``liu2006`` after the
  "Liu et al. (2006)" the chapter cites for such a model, a paper not checked here, so
  not a reproduction of it.
* :mod:`.vorst2008` - Vorst & Zell (EUROS 2008): kernel-smoothed detection rates on a
  Cartesian grid of the antenna's ground plane (horizontal geometry: fitted with each
  attempt's tag height); no RSSI (fs = 1, fs_dbm = NaN, ``predicts_rssi`` False).
* :mod:`.ablations` - the chapter's model with FCM only (no ANFIS) and with a grid
  partition instead of FCM, as ``fuzzymodel.SensorModel``.

Each module's docstring says what is reproduced and what is simplified.
:mod:`.registry` lists every model of a study (:data:`~.registry.SENSOR_MODELS`: label,
kind, role, class, fit and its options, where it is scored); fitting, the stages, the
figures and the README's tables read it, so a new model is its module and one line there.
"""

from pipeline.sensormodels._common import (
    COMPETITOR_FORMAT,
    Attempts,
    CompetitorModel,
    attempts_from_reads,
    group_folds,
    read_model_file,
    tag_height_differences,
)
from pipeline.sensormodels.ablations import ABLATIONS, fit_ablation
from pipeline.sensormodels.competitors import (
    COMPETITORS,
    MODEL_CLASSES,
    fit_competitors,
    load_competitor,
)
from pipeline.sensormodels.joho2009 import JOHO2009, Joho2009Model, fit_joho2009
from pipeline.sensormodels.liu2006 import LIU2006, Liu2006Model, fit_liu2006
from pipeline.sensormodels.registry import (
    SENSOR_MODELS,
    ModelInfo,
    load_models,
    model_info,
    model_label,
    model_names,
    table_order,
)
from pipeline.sensormodels.vorst2008 import VORST2008, Vorst2008Model, fit_vorst2008

__all__ = [
    "ABLATIONS",
    "COMPETITORS",
    "COMPETITOR_FORMAT",
    "JOHO2009",
    "LIU2006",
    "MODEL_CLASSES",
    "SENSOR_MODELS",
    "VORST2008",
    "Attempts",
    "group_folds",
    "CompetitorModel",
    "Joho2009Model",
    "Liu2006Model",
    "ModelInfo",
    "Vorst2008Model",
    "attempts_from_reads",
    "fit_ablation",
    "fit_competitors",
    "fit_joho2009",
    "fit_liu2006",
    "fit_vorst2008",
    "load_competitor",
    "load_models",
    "model_info",
    "model_label",
    "model_names",
    "read_model_file",
    "table_order",
    "tag_height_differences",
]
