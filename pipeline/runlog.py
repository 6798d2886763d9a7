"""What a run knows around its stages: the run directory's history and the stages' environment.

- :func:`describe_previous_run`: what the previous run in a run directory left (killed,
  interrupted, failed) and how its config differs from this one (logged, and recorded in
  the :class:`pipeline.study.StudyResult`);
- :func:`config_changes`: the dotted keys whose values differ between two configs;
- :func:`reproducible_outputs`: ``SOURCE_DATE_EPOCH=0`` while a stage runs (no dates in
  PDF metadata), so identical inputs give identical bytes;
- :func:`final_paths_in_logs`: log lines naming a file in the staging area name its
  final place instead.
"""

from __future__ import annotations

import contextlib
import json
import logging
import os
import tomllib
from pathlib import Path

from pipeline.config import StudyConfig, config_to_dict
from pipeline.runstore import MANIFEST, RunStore, regular_file

__all__ = ["config_changes", "describe_previous_run", "final_paths_in_logs",
           "reproducible_outputs"]

log = logging.getLogger("pipeline.study")


@contextlib.contextmanager
def reproducible_outputs():
    """``SOURCE_DATE_EPOCH=0`` while a stage runs, unless set (dates in PDF metadata)."""
    if "SOURCE_DATE_EPOCH" in os.environ:
        yield
        return
    os.environ["SOURCE_DATE_EPOCH"] = "0"
    try:
        yield
    finally:
        os.environ.pop("SOURCE_DATE_EPOCH", None)


class _FinalPaths(logging.Filter):
    """Log lines naming a file in the staging area name its final place instead."""

    def __init__(self, staged: Path, root: Path):
        super().__init__()
        self._from, self._to = str(staged), str(root)

    def _fix(self, v):
        if isinstance(v, (str, Path)) and self._from in str(v):
            return str(v).replace(self._from, self._to)
        return v

    def filter(self, record: logging.LogRecord) -> bool:
        if isinstance(record.msg, str):
            record.msg = self._fix(record.msg)
        if isinstance(record.args, tuple):
            record.args = tuple(self._fix(a) for a in record.args)
        return True


@contextlib.contextmanager
def final_paths_in_logs(staged: Path, root: Path):
    """Within the block, log handlers rewrite ``staged`` paths to ``root`` (see module doc)."""
    filt = _FinalPaths(staged, root)
    handlers = list(logging.getLogger().handlers)
    for h in handlers:
        h.addFilter(filt)
    try:
        yield
    finally:
        for h in handlers:
            h.removeFilter(filt)


def _flatten(obj, prefix: str = "") -> dict:
    out = {}
    if isinstance(obj, dict):
        for k, v in obj.items():
            out.update(_flatten(v, f"{prefix}.{k}" if prefix else str(k)))
    elif isinstance(obj, (list, tuple)) and obj and all(isinstance(v, dict) for v in obj):
        for i, v in enumerate(obj):
            out.update(_flatten(v, f"{prefix}[{i}]"))
    else:
        out[prefix] = list(obj) if isinstance(obj, tuple) else obj
    return out


def config_changes(old: dict, new: dict) -> dict[str, tuple]:
    """Dotted keys whose values differ between two config dicts: key -> (old, new).

    A key missing on one side shows as ``None`` there.
    """
    a, b = _flatten(old), _flatten(new)
    return {k: (a.get(k), b.get(k)) for k in sorted(set(a) | set(b)) if a.get(k) != b.get(k)}


def describe_previous_run(store: RunStore, config: StudyConfig, result) -> None:
    """Name what the previous run in this directory left, and how its config differs."""
    man_path = store.path(MANIFEST)
    if regular_file(man_path):
        try:
            if man_path.stat().st_size > 64 << 20:
                raise ValueError("larger than 64 MiB")
            man = json.loads(man_path.read_text(encoding="utf-8"))
        except (OSError, ValueError, RecursionError):
            man = None
            log.warning("%s is unreadable; the stage records decide what re-runs", man_path)
        if isinstance(man, dict):
            status = man.get("status")
            failure = man.get("failure") if isinstance(man.get("failure"), dict) else {}
            stage = man.get("stage") or failure.get("stage")
            stage = stage if isinstance(stage, str) else None
            at = f" during stage {stage}" if stage else ""
            if status == "running":
                result.previous = f"the previous run stopped{at}"
                log.warning("%s (killed?); resuming", result.previous)
            elif status == "interrupted":
                result.previous = f"the previous run was interrupted{at}"
                log.info("%s; resuming", result.previous)
            elif status == "failed":
                result.previous = f"the previous run failed{' at stage ' + stage if stage else ''}"
                log.info("%s; resuming", result.previous)
    cfg_path = store.path("config.toml")
    if regular_file(cfg_path):
        try:
            if cfg_path.stat().st_size > 16 << 20:
                return
            old = tomllib.loads(cfg_path.read_text(encoding="utf-8"))
        except (OSError, ValueError, RecursionError):
            return
        diff = config_changes(old, config_to_dict(config))
        if diff:
            result.changed_keys = list(diff)
            shown = "; ".join(f"{k}: {a!r} -> {b!r}" for k, (a, b) in list(diff.items())[:8])
            more = f" (and {len(diff) - 8} more)" if len(diff) > 8 else ""
            log.info("%s holds a run of another config (%s%s); the stages that depend on "
                     "these keys re-run", store.root, shown, more)
