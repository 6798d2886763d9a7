"""Every file of a run directory, named once: what each stage writes.

The stages write these files and declare them (``Stage(outputs=...)``, checked by the
engine: a stage that writes a file its declaration does not match fails, naming it);
the figures, the report, replicates, sweeps, placement and the benchmarks read them by
these names. A name with ``{...}`` is a family: :func:`pattern` gives its glob.

==================  ===========================================================
stage               files
==================  ===========================================================
scene               :data:`SCENE_SUMMARY`, :data:`SCENE_TAGS`, :data:`FLOORPLAN`
tour                :data:`TRACK` (train, eval), :data:`MAP_ERROR`, :data:`LOCALISATION`
reads               :data:`READS`, :data:`POSES` (prefix ``""`` training, ``"eval_"``
                    held out)
truth_traces        :data:`SITE_TRUTH`, :data:`FREE_SPACE_POINTS`, :data:`FIELD`
training_sets       :data:`TRAINING_SET`
models              :data:`MODEL` (every model's JSON), :data:`TRAINING_HISTORY`
truth               :data:`DETECTION_GRID`, :data:`DETECTION_GRID_EVAL`, :data:`RHO_POINTS`
downstream          :data:`DOWNSTREAM_SCORES`, :data:`TAG_ERRORS`, :data:`ROBOT_ERROR`,
                    :data:`ROBOT_STEPS`
evaluation          :data:`METRICS`, :data:`FIG7_ERRORS`, :data:`SITE_ERRORS`,
                    :data:`EVALUATION_TABLE`
figures             :data:`FIGURE`
report              :data:`REPORT`
recording           :data:`READS`, :data:`POSES`, :data:`TRACK`, :data:`RECORDING_IMPORT`
sim_vs_real         :data:`SIM_VS_REAL`
calibration         :data:`CALIBRATION`, :data:`CALIBRATED_CONFIG`
recorded_eval       :data:`METRICS`, :data:`EVALUATION_TABLE`
==================  ===========================================================

The engine's own files (``manifest.json``, ``config.toml``, ``run.log``, ``stages/``)
are :mod:`pipeline.runpaths`'s and :mod:`pipeline.engine.runstore`'s.
"""

from __future__ import annotations

import re

__all__ = [
    "BASELINES", "BASELINES_TRUEPOSE", "EVAL_POSES", "EVAL_READS", "EVAL_TRACK", "SENSOR_MODEL",
    "SENSOR_MODEL_TRUEPOSE", "TRAIN_POSES", "TRAIN_READS", "TRAIN_TRACK",
    "CALIBRATED_CONFIG", "CALIBRATION", "LEGACY_FLOORPLAN", "LEGACY_SCENE_TAGS", "REPLICATES_INDEX", "DETECTION_GRID", "DETECTION_GRID_EVAL",
    "DOWNSTREAM_SCORES", "EVALUATION_TABLE", "FIELD", "FIG7_ERRORS", "FIGURE", "FLOORPLAN",
    "FREE_SPACE_POINTS", "LOCALISATION", "MAP_ERROR", "METRICS", "MODEL", "POSES", "READS",
    "RECORDING_IMPORT", "REPORT", "RHO_POINTS", "ROBOT_ERROR", "ROBOT_STEPS", "SCENE_SUMMARY",
    "SCENE_TAGS", "SIM_VS_REAL", "SITE_ERRORS", "SITE_TRUTH", "STAGE_OUTPUTS", "TAG_ERRORS",
    "TRACK", "TRAINING_HISTORY", "TRAINING_SET", "pattern",
]

SCENE_SUMMARY = "scene/scene.json"
SCENE_TAGS = "scene/tags.parquet"
FLOORPLAN = "scene/floorplan.npz"

#: A tour's pose track (``tour``: ``train`` or ``eval``): true, odometry and MCL poses.
TRACK = "tour/{tour}_track.npz"
TRAIN_TRACK, EVAL_TRACK = TRACK.format(tour="train"), TRACK.format(tour="eval")
MAP_ERROR = "tour/map_error.npz"
LOCALISATION = "tour/localisation.json"

#: A read log and its poses (``prefix``: ``""`` the training tour, ``"eval_"`` held out).
READS = "{prefix}reads.parquet"
POSES = "{prefix}poses.parquet"
TRAIN_READS, EVAL_READS = READS.format(prefix=""), READS.format(prefix="eval_")
TRAIN_POSES, EVAL_POSES = POSES.format(prefix=""), POSES.format(prefix="eval_")

SITE_TRUTH = "truth/site_truth.npz"
FREE_SPACE_POINTS = "truth/free_space_points_{i:02d}.npz"
FIELD = "fields/field_{i:02d}.npz"

#: A training set (``kind``: ``ssm`` or ``tdm``; ``pose``: ``est`` or ``true``).
TRAINING_SET = "training/{kind}_{pose}.parquet"

#: A fitted model's JSON (``name``: ``sensor``, ``ssm``, ``tdm``, their ``_truepose``
#: twins, ``baselines``, a registered competitor or ablation).
MODEL = "models/{name}.json"
SENSOR_MODEL, SENSOR_MODEL_TRUEPOSE = MODEL.format(name="sensor"), MODEL.format(name="sensor_truepose")
BASELINES, BASELINES_TRUEPOSE = MODEL.format(name="baselines"), MODEL.format(name="baselines_truepose")
TRAINING_HISTORY = "models/training_history.json"

DETECTION_GRID = "truth/detection_grid.npz"
DETECTION_GRID_EVAL = "truth/detection_grid_eval.npz"
RHO_POINTS = "truth/rho_points_{i:02d}.npz"

DOWNSTREAM_SCORES = "downstream/scores.json"
TAG_ERRORS = "downstream/tag_errors.parquet"
ROBOT_ERROR = "downstream/robot_error.parquet"
ROBOT_STEPS = "downstream/robot_steps.parquet"

METRICS = "metrics.json"
FIG7_ERRORS = "truth/fig7_errors.parquet"
SITE_ERRORS = "truth/site_errors.parquet"
#: The evaluation's unit tables (:data:`pipeline.evaluation.units.TABLES`).
EVALUATION_TABLE = "evaluation/{table}.parquet"

#: A figure (``name`` with its suffix: ``fig7.png``).
FIGURE = "figures/{name}"
REPORT = "report.html"

RECORDING_IMPORT = "recording/import.json"
#: The simulation against a recording: ``attempts.parquet``, ``links.parquet``, ``summary.json``.
SIM_VS_REAL = "sim_vs_real/{name}"
CALIBRATION = "calibration.json"
CALIBRATED_CONFIG = "calibrated.toml"

#: A replicated study's index of its replicates (:mod:`pipeline.apps.replicates`).
REPLICATES_INDEX = "replicates/index.json"

#: Where run directories of older versions kept the floor plan and the tags (still read).
LEGACY_FLOORPLAN = "fields/floorplan.npz"
LEGACY_SCENE_TAGS = "truth/tags.parquet"


def pattern(name: str) -> str:
    """The glob of a file family (``"tour/{tour}_track.npz"`` -> ``"tour/*_track.npz"``);
    a plain name is its own glob."""
    return re.sub(r"\{[^}]*\}", "*", name)


def _globs(*names: str) -> tuple[str, ...]:
    return tuple(pattern(n) for n in names)


#: What each stage of the study may write (globs of the names above), by stage name:
#: the stages' declarations (``Stage.outputs``) and their test read it.
STAGE_OUTPUTS: dict[str, tuple[str, ...]] = {
    "scene": _globs(SCENE_SUMMARY, SCENE_TAGS, FLOORPLAN),
    "tour": _globs(TRACK, MAP_ERROR, LOCALISATION),
    "reads": _globs(READS, POSES),
    "truth_traces": _globs(SITE_TRUTH, FREE_SPACE_POINTS, FIELD),
    "training_sets": _globs(TRAINING_SET),
    "models": _globs(MODEL),
    "truth": _globs(DETECTION_GRID, DETECTION_GRID_EVAL, RHO_POINTS),
    "downstream": _globs(DOWNSTREAM_SCORES, TAG_ERRORS, ROBOT_ERROR, ROBOT_STEPS),
    "evaluation": _globs(METRICS, FIG7_ERRORS, SITE_ERRORS, EVALUATION_TABLE),
    "figures": _globs(FIGURE),
    "report": _globs(REPORT),
    "recording": _globs(READS, POSES, TRACK, RECORDING_IMPORT),
    "sim_vs_real": _globs(SIM_VS_REAL),
    "calibration": _globs(CALIBRATION, CALIBRATED_CONFIG),
    "recorded_eval": _globs(METRICS, EVALUATION_TABLE),
}
