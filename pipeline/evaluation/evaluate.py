"""Every metric on every model: the study's ``metrics.json``.

:func:`evaluate_model` runs the comparisons of :mod:`.fig7` and
:mod:`.comparison` on one SensorLike model; :func:`localisation_split` puts a
model trained on MCL poses beside one trained on true poses;
:func:`evaluate_all` does both for a dict of models (ANFIS, ANFIS on true poses,
baselines) and returns :class:`StudyMetrics`, whose :meth:`~StudyMetrics.to_dict`
is what the study writes as ``metrics.json`` (under the key ``"evaluation"``
or at top level, the study's choice; figures accept both).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import pandas as pd

from pipeline.evaluation.comparison import (
    DetectionComparison,
    RhoComparison,
    RssiComparison,
    detection_vs_truth,
    rho_vs_truth,
    rssi_cell_mean_floor,
    rssi_vs_truth,
)
from pipeline.evaluation.fig7 import Fig7Result, fig7_errors
from pipeline.evaluation.interface import check_sensor
from pipeline.evaluation.metrics import nan_to_none
from pipeline.evaluation.truth import TruthGrid

__all__ = [
    "EvaluationInputs",
    "LocalisationSplit",
    "ModelMetrics",
    "StudyMetrics",
    "evaluate_all",
    "evaluate_model",
    "localisation_split",
]


@dataclass(frozen=True)
class EvaluationInputs:
    """The truth and data every model is scored on.

    Attributes
    ----------
    reads : pandas.DataFrame
        reads.parquet-format table for the RSSI and detection comparisons (true
        geometry columns and gain_db); typically the training tour's reads.
    truth : TruthGrid
        :func:`~.truth.detection_truth` of `reads`.
    budget : propagation.LinkBudget
        Link budget of the simulated reader.
    eval_reads : pandas.DataFrame or None
        The held-out evaluation path's reads (Fig. 7); None skips Fig. 7.
    tags : pandas.DataFrame, mapping or TagSet, or None
        Tag positions (needed with `eval_reads`).
    rho_points : list of RhoPoints
        Fig. 6 truth around sample antenna poses (may be empty).
    pose_times_s : array_like or None
        Evaluation-pose start times (eval_poses.parquet time_s), see :func:`fig7_errors`.
    d_max_m : float
        Distance limit of the RSSI comparison [m].
    min_attempts : int
        Cells with fewer attempts are not used by the detection comparison.
    fig7_radius_m : float
        Fig. 7 neighbourhood radius [m].
    antenna_pitch_rad : float or dict
        Antenna tilt for Fig. 7 when the reads carry none.
    """

    reads: pd.DataFrame
    truth: TruthGrid
    budget: object
    eval_reads: pd.DataFrame | None = None
    tags: object = None
    rho_points: list = field(default_factory=list)
    pose_times_s: object = None
    d_max_m: float = 3.0
    min_attempts: int = 20
    fig7_radius_m: float = 0.1
    antenna_pitch_rad: object = 0.0


@dataclass(frozen=True)
class ModelMetrics:
    """All comparisons of one model with the truth.

    Attributes
    ----------
    rssi : RssiComparison
    detection : DetectionComparison
    rho : RhoComparison or None
        None without Fig. 6 points.
    fig7 : Fig7Result or None
        None without evaluation reads.
    """

    rssi: RssiComparison
    detection: DetectionComparison
    rho: RhoComparison | None
    fig7: Fig7Result | None

    def to_dict(self) -> dict:
        """JSON-able: ``{"rssi_dbm": ..., "detection": ..., "rho": ..., "fig7": ...}``."""
        return nan_to_none({
            "rssi_dbm": self.rssi.to_dict(),
            "detection": self.detection.to_dict(),
            "rho": None if self.rho is None else self.rho.to_dict(),
            "fig7": None if self.fig7 is None else self.fig7.to_dict(),
        })


def evaluate_model(sensor, inputs: EvaluationInputs) -> ModelMetrics:
    """Run every comparison on one model.

    Parameters
    ----------
    sensor : SensorLike
    inputs : EvaluationInputs

    Returns
    -------
    ModelMetrics
    """
    sensor = check_sensor(sensor)
    rssi = rssi_vs_truth(inputs.reads, sensor, inputs.budget, d_max_m=inputs.d_max_m)
    det = detection_vs_truth(inputs.reads, sensor, inputs.truth, min_attempts=inputs.min_attempts)
    rho = rho_vs_truth(inputs.rho_points, sensor) if inputs.rho_points else None
    f7 = None
    if inputs.eval_reads is not None:
        if inputs.tags is None:
            raise ValueError("EvaluationInputs: eval_reads given without tags")
        f7 = fig7_errors(inputs.eval_reads, inputs.tags, sensor, radius_m=inputs.fig7_radius_m,
                         pose_times_s=inputs.pose_times_s,
                         antenna_pitch_rad=inputs.antenna_pitch_rad, d_max_m=inputs.d_max_m)
    return ModelMetrics(rssi=rssi, detection=det, rho=rho, fig7=f7)


# headline numbers compared by the localisation split: (section, key)
_SPLIT_KEYS = (("rssi_dbm", "mae"), ("rssi_dbm", "rmse"), ("rssi_dbm", "bias"),
               ("detection", "mae"), ("detection", "rmse"), ("detection", "brier"),
               ("rho", "mae"), ("rho", "rmse"), ("rho", "correlation"))


@dataclass(frozen=True)
class LocalisationSplit:
    """Model trained on MCL-estimated poses beside one trained on true poses.

    Attributes
    ----------
    est : ModelMetrics
        Model trained on estimated (MCL) poses, as on a robot.
    true : ModelMetrics
        Model trained on true poses: the error left without localisation noise.
    difference : dict
        ``{"<section>.<key>": est - true}`` for the headline numbers (RSSI MAE,
        RMSE, bias [dB]; detection MAE, RMSE, Brier; rho MAE, RMSE, correlation;
        Fig. 7 mean and median %), the part of the error due to localisation.
    """

    est: ModelMetrics
    true: ModelMetrics
    difference: dict

    def to_dict(self) -> dict:
        """JSON-able: ``{"est": ..., "true": ..., "difference": ...}``."""
        return nan_to_none({"est": self.est.to_dict(), "true": self.true.to_dict(),
                            "difference": self.difference})


def _split_difference(est: ModelMetrics, true: ModelMetrics) -> dict:
    a, b = est.to_dict(), true.to_dict()
    out = {}
    keys = list(_SPLIT_KEYS) + [("fig7", "mean_pct"), ("fig7", "median_pct")]
    for sec, key in keys:
        sa, sb = a.get(sec), b.get(sec)
        va = None if sa is None else sa.get(key)
        vb = None if sb is None else sb.get(key)
        out[f"{sec}.{key}"] = None if va is None or vb is None else float(va) - float(vb)
    return out


def localisation_split(sensor_est, sensor_true, inputs: EvaluationInputs) -> LocalisationSplit:
    """Side-by-side metrics of models trained on MCL poses and on true poses.

    Parameters
    ----------
    sensor_est : SensorLike
        Trained on the estimated (MCL) antenna poses.
    sensor_true : SensorLike
        Trained on the true antenna poses (same reads otherwise).
    inputs : EvaluationInputs

    Returns
    -------
    LocalisationSplit
    """
    est = evaluate_model(sensor_est, inputs)
    true = evaluate_model(sensor_true, inputs)
    return LocalisationSplit(est=est, true=true, difference=_split_difference(est, true))


@dataclass(frozen=True)
class StudyMetrics:
    """Metrics of every model of a study.

    Attributes
    ----------
    models : dict of str -> ModelMetrics
        Per model name (e.g. "anfis", "anfis_truepose", "baseline").
    localisation_split : LocalisationSplit or None
        Built from the models named by `split` in :func:`evaluate_all`.
    truth : dict
        Facts about the truth used: cells with attempts, compared cells,
        attempts, reads, mean true detection probability.
    """

    models: dict
    localisation_split: LocalisationSplit | None
    truth: dict

    def to_dict(self) -> dict:
        """JSON-able nested dict of floats (NaN -> None):
        ``{"models": {name: ModelMetrics.to_dict()}, "localisation_split": {...} | None,
        "truth": {...}}``."""
        split = self.localisation_split
        return nan_to_none({
            "models": {k: v.to_dict() for k, v in self.models.items()},
            "localisation_split": None if split is None else {
                "difference": split.difference},
            "truth": self.truth,
        })


def evaluate_all(sensors: dict, inputs: EvaluationInputs,
                 split: tuple[str, str] = ("anfis", "anfis_truepose")) -> StudyMetrics:
    """Evaluate every model; add the localisation split when both `split` names are present.

    Parameters
    ----------
    sensors : dict of str -> SensorLike
        Models by name; names appear as keys in metrics.json.
    inputs : EvaluationInputs
    split : (str, str)
        Names of the model trained on MCL poses and of the one trained on true poses.

    Returns
    -------
    StudyMetrics
    """
    if not sensors:
        raise ValueError("evaluate_all: no models given")
    models = {str(k): evaluate_model(s, inputs) for k, s in sensors.items()}
    sp = None
    if split[0] in models and split[1] in models:
        est, true = models[split[0]], models[split[1]]
        sp = LocalisationSplit(est=est, true=true, difference=_split_difference(est, true))
    t = inputs.truth
    ok = t.n_attempts >= inputs.min_attempts
    truth = {
        "cells_with_attempts": int((t.n_attempts > 0).sum()),
        "cells_compared": int(ok.sum()),
        "n_attempts": int(t.n_attempts.sum()),
        "n_closed": int(t.n_closed.sum()),
        "n_reads": int(t.n_reads.sum()),
        "miss_probability": t.miss_probability,
        "grid": t.grid.to_dict(),
        "rssi_dbm_cell_mean_floor": rssi_cell_mean_floor(
            inputs.reads, t, inputs.budget, d_max_m=inputs.d_max_m,
            min_count=inputs.min_attempts).to_dict(),
        "split": list(split) if sp is not None else None,
    }
    return StudyMetrics(models=models, localisation_split=sp, truth=truth)
