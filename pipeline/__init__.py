"""Pipeline: robot and localisation, reader acquisition, evaluation, figures and orchestration.

The study itself: ``pipeline.load_config(path)`` -> :class:`StudyConfig`,
``pipeline.run_study(config, run_dir)`` -> :class:`StudyResult` (cached, resumable
stages, see :mod:`pipeline.study` and :mod:`pipeline.stages`); sweeps in
:mod:`pipeline.sweep`; the ``rfidstudy`` command line in :mod:`pipeline.cli`.
"""

from pipeline.config import ConfigError, StudyConfig, load_config
from pipeline.study import StageError, StudyResult, run_study

__all__ = ["ConfigError", "StageError", "StudyConfig", "StudyResult", "load_config", "run_study"]
