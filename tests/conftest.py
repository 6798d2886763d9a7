"""Fixtures of the whole suite.

``tiny_study``: one real tiny study per test session (``configs/tiny.toml``: corridor_lab,
5 m of route, low ray counts, 3 epochs; real MCL, real Sionna traces, real Parquet, real
ANFIS, real figures) with a propagation cache of its own. The study tests read its run
directory; a test that changes a run works on a copy (:func:`copy_run`).
"""

from __future__ import annotations

import shutil
from dataclasses import dataclass
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]


@dataclass(frozen=True)
class TinyStudy:
    """The session's tiny study: its config, the run directory, the runner's result."""

    config: object
    """The resolved :class:`pipeline.config.StudyConfig` (its cache under ``base``)."""
    base: Path
    """Folder holding ``run/`` and ``cache/`` (the study's own propagation cache)."""
    result: object
    """What :func:`pipeline.apps.studyrun.run_full_study` returned for the first run."""

    @property
    def run(self) -> Path:
        """The run directory (read it; copy it before changing anything)."""
        return self.base / "run"


@pytest.fixture(scope="session")
def tiny_study(tmp_path_factory) -> TinyStudy:
    from pipeline.apps.studyrun import run_full_study
    from pipeline.config import load_config, replace_path

    base = tmp_path_factory.mktemp("tiny")
    cfg = load_config(ROOT / "configs" / "tiny.toml")
    cfg = replace_path(cfg, "tracing.cache_dir", str(base / "cache"))
    res = run_full_study(cfg, base / "run", command_line=["pytest"])
    return TinyStudy(cfg, base, res)


def copy_run(study: TinyStudy, dest: Path, **kw) -> Path:
    """A copy of the tiny study's run directory at ``dest`` (``shutil.copytree`` keywords)."""
    shutil.copytree(study.run, dest, **kw)
    return dest
