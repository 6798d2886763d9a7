"""The study's stages, in order, and one study run with them (the stage engine's input).

Stages, one module each (inputs in brackets; each also depends on its upstream stages)::

    scene         load the scene, write scene/ (summary, tags, floor plan)   [scene]
    tour          guided tour + evaluation path, odometry, laser, MCL        [robot, tour, localisation]
    reads         ray-traced reader simulation -> reads/poses Parquet         [reader, tracing]
    truth_traces  truth's traces: tag sites, Fig. 6 points, RSSI fields       [evaluation, tracing]
    training_sets SSM / TDM samples (MCL and true poses)                       [training bins]
    models        FCM + ANFIS (SSM, TDM; MCL and true poses), baselines        [training fit]
    truth         detection truth grids, Fig. 6 truth from the traced points  [evaluation]
    downstream    held-out tags and the robot, localised with each model       [downstream]
    evaluation    metrics.json                                                 [evaluation]
    figures       every figure (pipeline.figures.draw_all), in its formats     [figures]
    report        report.html

Each module defines its ``STAGE`` (name, config keys, upstream stages, version) beside
the function it runs; helpers they share are in :mod:`pipeline.stages.common`. The
engine (:mod:`pipeline.engine.study`) knows nothing of them: :func:`run_study_stages` hands it
:data:`STAGES`, :data:`CHECKS` and :func:`manifest_info` for one study. This package
imports neither replicates nor sweeps: a replicated study (``replicates.n > 1``) is run
from above, by :func:`pipeline.apps.studyrun.run_full_study`; what sweeps read from a finished
run directory is :mod:`pipeline.stages.summary`.

A study with a ``[recording]`` runs :data:`RECORDED_STAGES` instead
(:mod:`pipeline.stages.recorded`): the recording stands in for the tour and the reads,
then ``sim_vs_real``, ``calibration``, ``downstream`` (the held-out tags alone) and
``recorded_eval``.

The scene stage always runs (it is cheap) so an edited scene file changes its
outputs' digest and everything downstream re-runs. ``truth_traces`` runs in a process
of its own beside ``tour`` and ``reads``, whose outputs it does not read
(``Stage.own_process``, :mod:`pipeline.engine.stageproc`; it draws the evaluation path's poses
as the tour does, :func:`pipeline.stages.tour.eval_track`, and the ``truth`` stage
checks that they are the tour's).
"""

from __future__ import annotations

import dataclasses
from pathlib import Path

from pipeline.config import ConfigError, StudyConfig
from pipeline.engine.study import Stage, StudyResult, run_study
from pipeline.stages import (
    calibration,
    downstream,
    evaluation,
    figures,
    models,
    reads,
    recorded,
    recorded_eval,
    report,
    scene,
    sim_vs_real,
    tour,
    training_sets,
    truth,
    truth_traces,
)
from pipeline.stages.checks import (
    CHECKS,
    check_antenna_mounts,
    check_cache_dir,
    check_memory_budget,
    check_tracer_versions,
)
from pipeline.stages.common import manifest_info
from pipeline.stages.figures import draw_figures, draw_scene_top_view
from pipeline.studyscene import resolve_cache_dir

__all__ = [
    "CHECKS",
    "RECORDED_STAGES",
    "STAGES",
    "check_antenna_mounts",
    "check_cable_losses",
    "draw_figures",
    "draw_scene_top_view",
    "manifest_info",
    "resolve_cache_dir",
    "run_study_stages",
    "stage_names",
    "stages_upto",
]

#: The study's stages, in order.
STAGES: tuple[Stage, ...] = (
    scene.STAGE,
    tour.STAGE,
    reads.STAGE,
    truth_traces.STAGE,
    training_sets.STAGE,
    models.STAGE,
    truth.STAGE,
    downstream.STAGE,
    evaluation.STAGE,
    figures.STAGE,
    report.STAGE,
)


#: The recorded study's stages (:mod:`pipeline.stages.recorded`): the recording stands
#: in for the tour and the reads; no truth or figures stages; ``downstream`` localises the
#: held-out tags alone, against the recording's tag layout (no robot filter, no oracle:
#: :mod:`pipeline.stages.downstream`).
RECORDED_STAGES: tuple[Stage, ...] = (
    scene.STAGE,
    recorded.STAGE,
    dataclasses.replace(training_sets.STAGE, upstream=("recording",)),
    dataclasses.replace(models.STAGE, upstream=("training_sets", "recording")),
    sim_vs_real.STAGE,
    calibration.STAGE,
    dataclasses.replace(downstream.STAGE, upstream=("scene", "recording", "models"),
                        config_keys=("seed", "downstream", "training.d_max_m", "robot"),
                        description="held-out tags localised (recording)"),
    recorded_eval.STAGE,
    dataclasses.replace(report.STAGE, upstream=("recorded_eval",)),
)

#: The recorded study's checks: its mounts are where the recording says (fixed antennas
#: are absolute), not on a planned route.
RECORDED_CHECKS = (check_tracer_versions, check_cache_dir, check_memory_budget)


def study_stages(config: StudyConfig) -> tuple[Stage, ...]:
    """:data:`RECORDED_STAGES` for a study with a ``[recording]``, else :data:`STAGES`."""
    return RECORDED_STAGES if config.recording.enabled else STAGES


def stage_names(config: StudyConfig | None = None) -> list[str]:
    """Names of the study's stages, in order (the simulated study's without a config)."""
    return [s.name for s in (STAGES if config is None else study_stages(config))]


def stages_upto(name: str | None, config: StudyConfig | None = None) -> tuple[Stage, ...]:
    """:data:`STAGES` up to and including ``name`` (all of them for None): what a caller
    needs that reads only early outputs (a placement ranked by its tours' reads needs
    no model; :mod:`pipeline.apps.placement.runner`). A side stage (``truth_traces``) after
    ``name`` is left out with the rest.

    Raises
    ------
    ValueError
        ``name`` is not a stage.
    """
    stages = STAGES if config is None else study_stages(config)
    if name is None:
        return stages
    names = [s.name for s in stages]
    if name not in names:
        raise ValueError(f"no stage {name!r}; stages are {', '.join(names)}")
    return stages[:names.index(name) + 1]


def check_cable_losses(config: StudyConfig, upto: str | None) -> None:
    """Antenna cable losses enter the reads (their gains), not the traced truth (Fig. 6
    points, tag sites, RSSI fields: a lossless antenna's), so a study that runs the truth
    stages with them would score models against a truth their reads were not drawn from:
    refused. A placement study ranked by its reads, or a recording's, may use them.

    Raises
    ------
    pipeline.config.ConfigError
        Naming the antenna and what to do.
    """
    lossy = [(i, a) for i, a in enumerate(config.robot.antennas) if a.cable_loss_db != 0.0]
    if not lossy or config.recording.enabled:
        return
    names = [s.name for s in (STAGES if config.replicates.n > 1 else stages_upto(upto, config))]
    if "truth_traces" in names or "truth" in names:
        i, a = lossy[0]
        raise ConfigError(
            f"robot.antennas[{i}].cable_loss_db = {a.cable_loss_db} ({a.name!r}): cable losses "
            "enter the reads but not the traced truth, so a full study would score its models "
            "against a truth of lossless antennas; use them in a placement study ranked by its "
            "reads (inventory objectives) or set them to 0")


def run_study_stages(config: StudyConfig, run_dir: str | Path, *, upto: str | None = None,
                     **kwargs) -> StudyResult:
    """Run (or resume) one study into ``run_dir``: :func:`pipeline.engine.study.run_study` with
    :data:`STAGES` (:data:`RECORDED_STAGES` for a recording), :data:`CHECKS` and
    :func:`manifest_info` (package versions and the Dr.Jit backend in the manifest).
    ``upto`` stops after that stage (:func:`stages_upto`). Keyword arguments go to
    ``run_study`` and override those (``checks=()``, ``manifest_extra=None``).

    Raises
    ------
    ValueError
        ``replicates.n > 1``: a replicated study is N studies, pooled
        (:func:`pipeline.apps.studyrun.run_full_study` runs it).
    """
    if config.replicates.n > 1:
        raise ValueError(f"replicates.n = {config.replicates.n}: a replicated study is run by "
                         "pipeline.apps.studyrun.run_full_study, not as one study")
    kwargs.setdefault("checks", RECORDED_CHECKS if config.recording.enabled else CHECKS)
    kwargs.setdefault("manifest_extra", manifest_info)
    check_cable_losses(config, upto)
    return run_study(config, run_dir, stages_upto(upto, config), **kwargs)
