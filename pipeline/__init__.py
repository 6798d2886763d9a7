"""Pipeline: robot and localisation, reader acquisition, evaluation, figures and orchestration.

The study itself: ``pipeline.load_config(path)`` -> :class:`StudyConfig`,
``pipeline.run_full_study(config, run_dir)`` -> :class:`StudyResult` (one study or its
replicates, :mod:`pipeline.apps.studyrun`; cached, resumable stages: the engine
:mod:`pipeline.engine.study`, ``run_study(config, run_dir, stages)``, runs the stage list of
:mod:`pipeline.stages`); sweeps in :mod:`pipeline.apps.sweep`; the ``rfidstudy`` command line
in :mod:`pipeline.apps.cli`.
"""

from pipeline.config import ConfigError, StudyConfig, load_config
from pipeline.engine.study import StageError, StudyResult, run_study

__all__ = ["ConfigError", "StageError", "StudyConfig", "StudyResult", "load_config",
           "run_full_study", "run_study"]


def __getattr__(name: str):
    # the stages are loaded on first use: importing the engine (or anything in pipeline)
    # does not import the stage package (pipeline.apps.studyrun imports it)
    if name == "run_full_study":
        from pipeline.apps.studyrun import run_full_study  # lazy: start-up time

        return run_full_study
    raise AttributeError(f"module 'pipeline' has no attribute {name!r}")
