"""Run one study or its replicates: the study's entry point, above the stage engine.

:func:`run_full_study` is what the CLI (``rfidstudy run``), sweeps, benchmarks and tests
call. With ``replicates.n = 1`` it is one study, :func:`pipeline.stages.run_study_stages`
(the stage list of :mod:`pipeline.stages` on the engine :mod:`pipeline.engine.study`); with
``replicates.n > 1`` it runs the stages of :mod:`pipeline.apps.replicates` (the study run into
``replicates/<k>/`` n times, side by side by :mod:`pipeline.apps.studypool`, then pooled).

The layers point one way: this module imports :mod:`pipeline.stages` and
:mod:`pipeline.apps.replicates`; neither imports it, and the stage package imports neither
replicates nor sweeps.
"""

from __future__ import annotations

from pathlib import Path

from pipeline import stages
from pipeline.apps import replicates
from pipeline.config import StudyConfig
from pipeline.engine.study import StudyResult, run_study

__all__ = ["run_full_study"]


def run_full_study(config: StudyConfig, run_dir: str | Path, *, upto: str | None = None,
                   **kwargs) -> StudyResult:
    """Run (or resume) the whole study into ``run_dir``: :func:`pipeline.engine.study.run_study`
    with :data:`pipeline.stages.STAGES`, :data:`pipeline.stages.CHECKS` and
    :func:`pipeline.stages.manifest_info` (package versions and the Dr.Jit backend in the
    manifest; :func:`pipeline.stages.run_study_stages`); with ``replicates.n > 1`` the
    stages of :mod:`pipeline.apps.replicates` (the study run into ``replicates/<k>/`` n times,
    pooled). ``upto`` stops after that stage (:func:`pipeline.stages.stages_upto`; not
    with replicates). Keyword arguments go to ``run_study`` and override those
    (``checks=()``, ``manifest_extra=None``)."""
    if config.replicates.n <= 1:
        return stages.run_study_stages(config, run_dir, upto=upto, **kwargs)
    # N studies in replicates/<k>/, pooled (pipeline.apps.replicates)
    kwargs.setdefault("checks",
                      stages.RECORDED_CHECKS if config.recording.enabled else stages.CHECKS)
    kwargs.setdefault("manifest_extra", stages.manifest_info)
    stages.check_cable_losses(config, upto)
    if config.recording.enabled:
        raise ValueError("replicates.n > 1 with a [recording]: a recording is one tour; its "
                         "intervals are over its held-out tags (set replicates.n = 1)")
    if upto is not None:
        raise ValueError("upto is for one study; replicates run every stage")
    return run_study(config, run_dir, replicates.STAGES, **kwargs)
