"""Fixtures of the whole suite.

``tiny_study``: one real tiny study per test session (``configs/tiny.toml``: corridor_lab,
5 m of route, low ray counts, 3 epochs; real MCL, real Sionna traces, real Parquet, real
ANFIS, real figures) with a propagation cache of its own, run as a user runs it: the
``rfidstudy run`` command in a process of its own, its console kept
(tests/pipeline/test_cli_study.py reads it). The study tests read its run directory; a
test that changes a run works on a copy (:func:`copy_run`), and one that counts the
cache's files on a copy of the cache (:func:`link_copy`): the run directory and the cache
are shared by every test of the session.

Under pytest-xdist the workers share it too: the first worker that asks builds it in the
session's temporary folder (the parent of the workers' own), under a file lock; the
others wait for it and read it (the study is minutes of CPU on a 2-core machine). Nothing
writes into the run directory after it is built; the cache takes more traces (oracle,
recorded studies), which several processes may do at once (propagation.pathcache).
"""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
from dataclasses import dataclass
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]


#: The command line's entry point, as the ``rfidstudy`` script runs it.
CLI_MAIN = "from pipeline.apps.cli import app; app(prog_name='rfidstudy')"


@dataclass(frozen=True)
class TinyStudy:
    """The session's tiny study: its config, the run directory, the command's console."""

    config: object
    """The resolved :class:`pipeline.config.StudyConfig` (its cache under ``base``)."""
    base: Path
    """Folder holding ``run/`` and ``cache/`` (the study's own propagation cache)."""

    @property
    def run(self) -> Path:
        """The run directory (read it; copy it before changing anything)."""
        return self.base / "run"

    @property
    def console(self) -> list[str]:
        """What the command printed (stdout, then stderr), line by line, 80 columns wide."""
        return (self.base / "console.txt").read_text().splitlines()


def session_folder(tmp_path_factory) -> Path:
    """The test session's temporary folder, shared by its xdist workers (the parent of
    each worker's own basetemp), else the basetemp itself."""
    base = tmp_path_factory.getbasetemp()
    return base.parent if os.environ.get("PYTEST_XDIST_WORKER") else base


@pytest.fixture(scope="session")
def tiny_study(tmp_path_factory) -> TinyStudy:
    from filelock import FileLock

    from pipeline.config import load_config, replace_path

    shared = session_folder(tmp_path_factory)
    base = shared / "tiny"
    cfg = load_config(ROOT / "configs" / "tiny.toml")
    cfg = replace_path(cfg, "tracing.cache_dir", str(base / "cache"))
    done = base / "console.txt"  # written once the study is complete
    with FileLock(str(shared / "tiny.lock")):
        if not done.is_file():  # the first worker here: build it (or resume a failed build)
            proc = subprocess.run(
                [sys.executable, "-c", CLI_MAIN, "run", "configs/tiny.toml",
                 "--out", str(base / "run"),
                 "--set", f"tracing.cache_dir='{base / 'cache'}'"],
                cwd=ROOT, env=dict(os.environ, COLUMNS="80"), capture_output=True, text=True,
                timeout=900)
            if proc.returncode != 0:
                pytest.fail(f"the tiny study failed (exit {proc.returncode}):\n"
                            f"{proc.stderr[-3000:]}")
            done.write_text(proc.stdout + proc.stderr)
    return TinyStudy(cfg, base)


def copy_run(study: TinyStudy, dest: Path, **kw) -> Path:
    """A copy of the tiny study's run directory at ``dest`` (``shutil.copytree`` keywords)."""
    shutil.copytree(study.run, dest, **kw)
    return dest


def link_copy(src: Path, dest: Path) -> Path:
    """``src`` copied to ``dest`` as hard links (a propagation cache: its files are written
    once under new names and never changed, so the copy costs no bytes and later writes
    into either folder do not show in the other)."""
    shutil.copytree(src, dest, copy_function=os.link)
    return dest


def draw_only(monkeypatch, *names: str) -> None:
    """The figures stage (and ``rfidstudy figures``) draws only ``names``: every figure
    of the tiny study is drawn by its own figures stage, every figure of a fake run by
    tests/pipeline/figures; a test of what re-runs needs the stage, not its twelve
    figures (about 20 s of CPU)."""
    import pipeline.figures.drawall as drawall

    monkeypatch.setattr(drawall, "FIGURES", {k: drawall.FIGURES[k] for k in names})
