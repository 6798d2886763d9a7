"""The study's sensor models, one registry: what each is called, predicts, is fitted and
loaded with, and where it is scored.

:data:`SENSOR_MODELS` holds one :class:`ModelInfo` per model: the chapter's FCM + ANFIS,
the baselines, the chapter's competitors, the ablations and the localisers only the
downstream stage builds. Every consumer iterates it instead of naming models:

* fitting: :func:`pipeline.sensormodels.fit_competitors` fits every ``"competitor"``
  entry, the models stage every ``"ablation"`` (``fit`` with ``fit_options``);
* loading and scoring: :func:`load_models` reads a run's models for one study context
  (:data:`CONTEXTS`), :func:`model_names` says which of them to score for RSSI and
  detection (``kind``); the evaluation, recorded-evaluation and downstream stages use both;
* display: :func:`model_label`, :data:`MODELS` and :func:`table_order` give the figures
  (:mod:`pipeline.figures.headline`), the report and ``scripts/readme_tables.py`` their
  labels and row order.

A new competitor is its module (a :class:`~pipeline.sensormodels._common.CompetitorModel`
subclass and a fit function of the :data:`CompetitorFit` form) and one line here.

Two orders. The tables and figures list the models in registry order. The stages fit,
load and score them in *study order* (:func:`model_names`): by ``role``, in the order of
:data:`ROLES`, then registry order; so a new entry, wherever its line, is fitted and
scored after every earlier model of its role, and it changes no earlier model's numbers
(the competitors share one random stream, drawn in study order).

A competitor whose paper was not available in full is labelled "reconstructed": its
module docstring says what is reproduced and what is our choice.

:func:`merge_identical_detection` finds detection models that predict exactly the same
probabilities: on the default study Joho et al. (2009)'s detection part (reads /
attempts per polar cell, nearest-cell fill) is the Hähnel et al. (2004) grid count, bit
for bit; scored twice, it would be one loser counted as two. Such a model is scored
once, under the first name in study order, and the merge is recorded in ``metrics.json``.
"""

from __future__ import annotations

import functools
import hashlib
import json
from collections.abc import Callable, Iterable, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from types import MappingProxyType
from typing import Any

import numpy as np

from fuzzymodel import SensorModel
from pipeline import runfiles
from pipeline.evaluation.baselines import BaselineSensorModel
from pipeline.sensormodels.ablations import fit_ablation
from pipeline.sensormodels.joho2009 import Joho2009Model, fit_joho2009
from pipeline.sensormodels.liu2006 import Liu2006Model, fit_liu2006
from pipeline.sensormodels.vorst2008 import Vorst2008Model, fit_vorst2008

__all__ = [
    "CONTEXTS",
    "KINDS",
    "MODELS",
    "ROLES",
    "SENSOR_MODELS",
    "CompetitorFit",
    "ModelInfo",
    "load_models",
    "merge_identical_detection",
    "model_info",
    "model_label",
    "model_names",
    "stage_version",
    "table_order",
]

#: What a model predicts: both RSSI and detection, RSSI only, detection only.
KINDS = ("both", "rssi", "detection")
#: What a model is, in study order (fitted, loaded and scored in this order).
ROLES = ("chapter", "baseline", "competitor", "ablation", "localiser")
#: Where models are scored: the simulated study's held-out evaluation (stage
#: ``evaluation``), a recorded study's (stage ``recorded_eval``), and localisation
#: (stage ``downstream``).
CONTEXTS = ("heldout", "recorded", "downstream")

#: A competitor's fit: ``fit(attempts, rssi_range_dbm, *, d_max_m, grid, rng, **options)``
#: -> a :class:`~pipeline.sensormodels._common.CompetitorModel`, from the training tour's
#: :class:`~pipeline.sensormodels._common.Attempts` within ``d_max_m``, the fuzzy model's
#: RSSI range, the study's polar :class:`~pipeline.evaluation.cells.CellGrid` and the
#: competitors' random stream; a fit ignores what it does not use.
CompetitorFit = Callable[..., Any]


@dataclass(frozen=True)
class ModelInfo:
    """One sensor model of a study (a line of :data:`SENSOR_MODELS`)."""

    key: str
    """Its name in ``metrics.json``, the unit tables and ``models/``."""
    label: str
    """Display name in figures, reports and the README's tables."""
    kind: str = "both"
    """What it is scored on (:data:`KINDS`): ``"both"`` (RSSI and detection), ``"rssi"`` or
    ``"detection"``; a ``"detection"`` model that also predicts RSSI localises with its
    detection alone (the downstream stage wraps it)."""
    role: str = "competitor"
    """What it is (:data:`ROLES`): the chapter's model, a baseline, a competitor, an
    ablation, or a localiser the downstream stage builds itself (label only). A
    competitor is fitted by :func:`pipeline.sensormodels.fit_competitors`, an ablation by
    the models stage; the chapter's model and the baselines by the models stage's own
    code."""
    reconstructed: bool = False
    """A competitor rebuilt from an incomplete source (the label says so)."""
    model_class: type | None = None
    """The class its file loads with (``model_class.load(path)``); None: no file."""
    file: str | None = None
    """Its file in the run directory; default ``models/<key>.json`` where it has a
    ``model_class``."""
    fit: Callable[..., Any] | None = None
    """How it is fitted: a competitor's :data:`CompetitorFit`; an ablation's
    ``fit(ssm_set, tdm_set, rng, *, epochs, n_clusters, fcm_exponent, check_fraction,
    max_samples, step_size, **options)`` -> ``fuzzymodel.SensorModel``; None for the
    models fitted by the models stage's own code and for the localisers."""
    fit_options: Mapping[str, Any] = field(default_factory=dict)
    """Keyword arguments the study passes to ``fit`` (read-only)."""
    scored_in: tuple[str, ...] = CONTEXTS
    """The contexts (:data:`CONTEXTS`) whose stages load and score it; ``()``: none (a
    localiser)."""

    def __post_init__(self) -> None:
        if self.kind not in KINDS:
            raise ValueError(f"{self.key}: kind {self.kind!r} not one of {KINDS}")
        if self.role not in ROLES:
            raise ValueError(f"{self.key}: role {self.role!r} not one of {ROLES}")
        if not set(self.scored_in) <= set(CONTEXTS):
            raise ValueError(f"{self.key}: scored_in {self.scored_in} not within {CONTEXTS}")
        if self.scored_in and self.model_class is None:
            raise ValueError(f"{self.key}: a scored model needs a model_class to load it")
        if self.role in ("competitor", "ablation") and self.fit is None:
            raise ValueError(f"{self.key}: a {self.role} needs a fit function")
        if self.file is None and self.model_class is not None:
            object.__setattr__(self, "file", runfiles.MODEL.format(name=self.key))
        object.__setattr__(self, "fit_options", MappingProxyType(dict(self.fit_options)))
        object.__setattr__(self, "scored_in", tuple(self.scored_in))

    @property
    def predicts_rssi(self) -> bool:
        """Scored on RSSI (``kind`` ``"both"`` or ``"rssi"``)."""
        return self.kind != "detection"

    @property
    def predicts_detection(self) -> bool:
        """Scored on detection (``kind`` ``"both"`` or ``"detection"``)."""
        return self.kind != "rssi"


# the published fits, in the CompetitorFit form
def _fit_joho2009(attempts, rssi_range_dbm, *, d_max_m, grid, rng, **options):
    return fit_joho2009(attempts, rssi_range_dbm, grid, **options)


def _fit_liu2006(attempts, rssi_range_dbm, *, d_max_m, grid, rng, **options):
    return fit_liu2006(attempts, rssi_range_dbm, d_max_m=d_max_m, **options)


def _fit_vorst2008(attempts, rssi_range_dbm, *, d_max_m, grid, rng, **options):
    return fit_vorst2008(attempts, rssi_range_dbm, rng, d_max_m=d_max_m, **options)


_ANFIS = "anfis"
_SENSOR, _BASE = runfiles.SENSOR_MODEL, runfiles.BASELINES

#: The study's models, in the order the tables and figures list them.
SENSOR_MODELS: tuple[ModelInfo, ...] = (
    ModelInfo(_ANFIS, "FCM + ANFIS, MCL poses (the chapter's)", role="chapter",
              model_class=SensorModel, file=_SENSOR),
    ModelInfo("anfis_truepose", "FCM + ANFIS, true poses", role="chapter",
              model_class=SensorModel, file=runfiles.SENSOR_MODEL_TRUEPOSE,
              scored_in=("heldout",)),
    ModelInfo("fcm_only", "FIS from FCM, no ANFIS", role="ablation", model_class=SensorModel,
              fit=functools.partial(fit_ablation, "fcm_only")),
    ModelInfo("anfis_gridinit", "ANFIS from a grid partition", role="ablation",
              model_class=SensorModel, fit=functools.partial(fit_ablation, "anfis_gridinit")),
    ModelInfo("joho2009", "after Joho et al. 2009 (reconstructed)", "both", reconstructed=True,
              model_class=Joho2009Model, fit=_fit_joho2009),
    ModelInfo("log_distance", "log-distance + pattern", "rssi", role="baseline",
              model_class=BaselineSensorModel, file=_BASE),
    ModelInfo("grid_count", "grid count after Hähnel et al. 2004 (reconstructed)", "detection",
              role="baseline", reconstructed=True, model_class=BaselineSensorModel, file=_BASE),
    ModelInfo("liu2006", "sector read region, project's own", "detection",
              model_class=Liu2006Model, fit=_fit_liu2006),
    ModelInfo("vorst2008", "after Vorst & Zell 2008 (reconstructed)", "detection",
              reconstructed=True, model_class=Vorst2008Model, fit=_fit_vorst2008),
    ModelInfo("phase", "reader phase alone", "detection", role="localiser", scored_in=()),
    ModelInfo("phase_anfis", "reader phase x ANFIS", role="localiser", scored_in=()),
    ModelInfo("oracle", "ray-traced oracle", role="localiser", scored_in=()),
)

#: key -> :class:`ModelInfo`, in registry (table) order.
MODELS: dict[str, ModelInfo] = {m.key: m for m in SENSOR_MODELS}


def _registry() -> tuple[ModelInfo, ...]:
    # read at call time, so that a registry patched in a test is the one used
    return SENSOR_MODELS


def model_info(key: str) -> ModelInfo:
    """The registry's entry of a model; KeyError naming the known keys if none."""
    info = next((m for m in _registry() if m.key == key), None)
    if info is None:
        raise KeyError(f"no sensor model {key!r} in the registry; known: "
                       f"{[m.key for m in _registry()]}")
    return info


def model_label(key: str) -> str:
    """Display name of a model (its key where it has none)."""
    info = next((m for m in _registry() if m.key == key), None)
    return info.label if info else key


def model_names(*, role: str | None = None, scored_in: str | None = None,
                predicts: str | None = None) -> tuple[str, ...]:
    """Keys of the registry's models in study order (module doc), filtered.

    Parameters
    ----------
    role : str, optional
        Only this role (:data:`ROLES`).
    scored_in : str, optional
        Only models scored in this context (:data:`CONTEXTS`).
    predicts : {"rssi", "detection"}, optional
        Only models scored on this quantity (``kind``).

    Returns
    -------
    tuple of str
    """
    if predicts not in (None, "rssi", "detection"):
        raise ValueError(f"predicts must be 'rssi' or 'detection', got {predicts!r}")
    if role is not None and role not in ROLES:
        raise ValueError(f"role {role!r} not one of {ROLES}")
    if scored_in is not None and scored_in not in CONTEXTS:
        raise ValueError(f"scored_in {scored_in!r} not one of {CONTEXTS}")
    rank = {r: i for i, r in enumerate(ROLES)}
    out = sorted(_registry(), key=lambda m: rank[m.role])  # stable: registry order within
    return tuple(m.key for m in out
                 if (role is None or m.role == role)
                 and (scored_in is None or scored_in in m.scored_in)
                 and (predicts != "rssi" or m.predicts_rssi)
                 and (predicts != "detection" or m.predicts_detection))


def table_order(names: Iterable[str]) -> list[str]:
    """`names` in registry order, those the registry lacks after them as given."""
    names = list(dict.fromkeys(names))
    keys = [m.key for m in _registry()]
    return [k for k in keys if k in names] + [n for n in names if n not in keys]


def load_models(path_of: Callable[[str], Path], scored_in: str) -> dict:
    """Every model a context scores, loaded from a run directory, in study order.

    Parameters
    ----------
    path_of : callable
        Run-relative path -> file (a stage's ``ctx.input``, which names a missing one).
    scored_in : str
        The context (:data:`CONTEXTS`).

    Returns
    -------
    dict[str, SensorLike]
        Key -> model; models sharing a file (the baselines) share one object.

    Raises
    ------
    ValueError
        A model scored on RSSI whose loaded object says it predicts none.
    """
    loaded: dict[str, Any] = {}
    out = {}
    for key in model_names(scored_in=scored_in):
        info = model_info(key)
        if info.file not in loaded:
            loaded[info.file] = info.model_class.load(path_of(info.file))
        model = out[key] = loaded[info.file]
        if info.predicts_rssi and not getattr(model, "predicts_rssi", True):
            raise ValueError(f"{key}: registered as kind {info.kind!r}, but its model "
                             f"({type(model).__name__}) predicts no RSSI")
    return out


def _qualname(obj) -> str | None:
    """``module.qualname`` of a class or function (a partial's: of its function, with its
    arguments); None for None."""
    if obj is None:
        return None
    if isinstance(obj, functools.partial):
        return f"{_qualname(obj.func)}{obj.args!r}{sorted(obj.keywords.items())!r}"
    return f"{obj.__module__}.{obj.__qualname__}"


def stage_version(version: int) -> str:
    """A stage's ``version`` (:class:`pipeline.engine.stagedef.Stage`) that also changes with what
    the registry makes the stage fit, load or score.

    ``"<version>+<digest>"``: the digest covers each entry's key, kind, role, class, file,
    fit and its options and contexts, in study order (not the labels: the figures and
    the report draw those). A model added, dropped or refitted otherwise re-runs the
    stages that fit and score the models; a cached run never lacks a registered model.
    """
    entries = [[m.key, m.kind, m.role, _qualname(m.model_class), m.file, _qualname(m.fit),
                sorted((k, repr(v)) for k, v in m.fit_options.items()), list(m.scored_in)]
               for m in (model_info(k) for k in model_names())]
    digest = hashlib.sha256(json.dumps(entries).encode()).hexdigest()[:12]
    return f"{int(version)}+{digest}"


def merge_identical_detection(sensors: dict, names: Iterable[str], d_m, alpha_rad
                              ) -> tuple[tuple[str, ...], dict[str, str]]:
    """Drop detection models whose predictions equal an earlier one's everywhere probed.

    Parameters
    ----------
    sensors : dict[str, SensorLike]
        Models by name (each with ``fT(d, alpha)``).
    names : iterable of str
        The detection models to score, in order (the first of identical ones stays).
    d_m, alpha_rad : array_like, float64, (n,)
        Where to compare them: the held-out links' distances [m] and bearings [rad],
        and any grid of cells the scores use.

    Returns
    -------
    kept : tuple of str
    merged : dict[str, str]
        Each dropped model -> the model it is identical to.
    """
    d = np.asarray(d_m, np.float64)
    a = np.asarray(alpha_rad, np.float64)
    kept: list[str] = []
    preds: dict[str, np.ndarray] = {}
    merged: dict[str, str] = {}
    for n in names:
        p = np.asarray(sensors[n].fT(d, a), np.float64)
        twin = next((k for k in kept if np.array_equal(preds[k], p, equal_nan=True)), None)
        if twin is not None and d.size:
            merged[n] = twin
            continue
        kept.append(n)
        preds[n] = p
    return tuple(kept), merged
