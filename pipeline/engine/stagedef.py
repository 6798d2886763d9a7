"""What a stage is, the context it runs in, and when it must run: the stage engine's
definitions shared by the runner (:mod:`pipeline.engine.study`) and the side process
(:mod:`pipeline.engine.stageproc`), which import this module and not each other's names.
"""

from __future__ import annotations

import fnmatch
from collections.abc import Callable, Iterable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from pipeline.config import StudyConfig, config_to_dict, is_config_key
from pipeline.engine.runstore import RunStore, json_hash, regular_file

__all__ = [
    "Stage",
    "StageContext",
    "StageError",
    "StageInputError",
    "check_outputs",
    "config_slice",
    "undeclared_outputs",
    "record_or_reason",
    "stage_inputs_hash",
]


class StageError(RuntimeError):
    """A stage failed; earlier stages' outputs are intact and the run is resumable.

    Attributes
    ----------
    stage : str or None
        The stage that failed (None where the failure belongs to no one stage).
    kind : str or None
        The failure's exception type name (``"FuzzyModelError"``): with ``stage``, what
        makes two failures "of the same kind" (:mod:`pipeline.apps.placement.runner`).
    """

    def __init__(self, message: str, *, stage: str | None = None, kind: str | None = None):
        super().__init__(message)
        self.stage, self.kind = stage, kind


class StageInputError(StageError):
    """A stage's input file is missing or unreadable; the message names the file."""


def _get(cfg_dict: dict, dotted: str):
    cur: Any = cfg_dict
    for part in dotted.split("."):
        if not isinstance(cur, dict) or part not in cur:
            return None
        cur = cur[part]
    return cur


def config_slice(cfg: StudyConfig, keys: Sequence[str]) -> dict:
    """Values of the dotted ``keys`` of ``cfg`` (what a stage's cache key depends on)."""
    d = config_to_dict(cfg)
    return {k: _get(d, k) for k in keys}


@dataclass(frozen=True)
class Stage:
    """One step of the study.

    Attributes
    ----------
    name : str
        Stage name (also the record file name).
    func : callable
        ``func(ctx: StageContext) -> dict | None``; writes outputs with ``ctx.out(rel)``
        and returns a small JSON-able summary.
    config_keys : tuple of str
        Dotted config keys (``"training.epochs"``, or a whole section ``"robot"``)
        whose values enter the inputs hash.
    upstream : tuple of str
        Stages whose outputs this stage reads.
    version : int or str
        Bump to invalidate cached results when the stage's code changes meaning (a str
        also folds in what the code reads, e.g.
        :func:`pipeline.sensormodels.registry.stage_version`).
    description : str
        One line shown in progress output.
    always : bool
        Run even when the record matches (cheap stages whose outputs depend on files
        outside the config, such as the scene); downstream stages still skip when the
        outputs come out identical.
    outputs : tuple of str or None
        Globs (relative to the run directory, ``*`` within one path component) of every
        file the stage may write (:data:`pipeline.runfiles.STAGE_OUTPUTS` for the study's
        stages); a file it writes that none matches fails the stage, naming the file
        (:func:`undeclared_outputs`). ``None``: not declared, not checked.
    own_process : bool
        The stage may run in a spawned process of its own, beside the stages before it
        from the first one that runs once its upstream stages are done (one such process
        at a time; it is waited for where it stands in the order) when both must run
        (:mod:`pipeline.engine.stageproc`): ``func`` must be a module-level function that needs
        nothing from ``memo``.
    """

    name: str
    func: Callable[[StageContext], dict | None]
    config_keys: tuple[str, ...] = ()
    upstream: tuple[str, ...] = ()
    version: int | str = 1
    description: str = ""
    always: bool = False
    own_process: bool = False
    outputs: tuple[str, ...] | None = None

    def __post_init__(self):
        # a misspelt key would hash as None and never re-run the stage when the real key
        # changes: a silent stale cache, so it is refused where the stage is defined

        unknown = [k for k in self.config_keys if not is_config_key(k)]
        if unknown:
            raise ValueError(f"stage {self.name!r} depends on unknown config key(s) {unknown}; "
                             "see configs/reference.toml for the keys")


class StageContext:
    """What a running stage sees: config, run directory, staging area, progress, memo.

    Attributes
    ----------
    config : StudyConfig
        The resolved study config.
    store : RunStore
        The run directory.
    stage : str
        Name of the running stage.
    memo : dict
        In-memory objects shared by stages of one run (a loaded scene), never on disk.
    """

    def __init__(self, config: StudyConfig, store: RunStore, stage: str, staged: Path,
                 progress, memo: dict):
        self.config = config
        self.store = store
        self.stage = stage
        self._staged = staged
        self._progress = progress
        self.memo = memo

    @property
    def staging_dir(self) -> Path:
        """Root of this stage's staging area (mirrors the run directory)."""
        return self._staged

    def out(self, rel: str) -> Path:
        """Path to write output ``rel`` to (inside the staging area; parents created)."""
        p = self._staged / rel
        p.parent.mkdir(parents=True, exist_ok=True)
        return p

    def input(self, rel: str) -> Path:
        """Path of an upstream output in the run directory; error naming it if missing."""
        p = self.store.path(rel)
        if not p.exists():
            raise StageInputError(f"stage {self.stage!r}: input file {p} is missing")
        return p

    def progress(self, description: str, total: float | None = None) -> Callable[..., None]:
        """A progress callback ``update(completed=None, total=None, advance=None)``.

        Draws a rich progress bar when the study runs with progress on; a no-op otherwise.
        """
        if self._progress is None:
            return lambda *a, **k: None
        task = self._progress.add_task(f"{self.stage}: {description}", total=total)

        def update(completed=None, total=None, advance=None):
            kw = {}
            if completed is not None:
                kw["completed"] = completed
            if total is not None:
                kw["total"] = total
            if advance is not None:
                kw["advance"] = advance
            self._progress.update(task, **kw)

        return update

    def track(self, iterable: Iterable, total: int | None = None, description: str = "") -> Iterable:
        """Iterate with a progress bar."""
        if total is None and hasattr(iterable, "__len__"):
            total = len(iterable)  # type: ignore[arg-type]
        update = self.progress(description, total)
        for item in iterable:
            yield item
            update(advance=1)


def undeclared_outputs(st: Stage, staged: Path) -> list[str]:
    """The files under ``staged`` (relative, POSIX) that none of ``st.outputs`` matches
    (``*`` within one path component); empty when the stage declares no outputs."""
    if st.outputs is None:
        return []
    bad = []
    for f in sorted(p for p in Path(staged).rglob("*") if regular_file(p)):  # what commit moves
        rel = f.relative_to(staged).as_posix()
        depth = rel.count("/")
        if not any(g.count("/") == depth and fnmatch.fnmatchcase(rel, g) for g in st.outputs):
            bad.append(rel)
    return bad


def check_outputs(st: Stage, staged: Path) -> None:
    """Raise ValueError naming the files ``st`` wrote but does not declare."""
    bad = undeclared_outputs(st, staged)
    if bad:
        shown = ", ".join(bad[:5]) + (f" and {len(bad) - 5} more" if len(bad) > 5 else "")
        raise ValueError(f"wrote {shown}, which its declared outputs {list(st.outputs)} do "
                         "not name (Stage.outputs; the study's in pipeline/runfiles.py)")


def stage_inputs_hash(st: Stage, config: StudyConfig, digests: dict[str, str]) -> str:
    """SHA-256 of what the stage's outputs depend on (module doc)."""
    return json_hash({"stage": st.name, "version": st.version,
                      "config": config_slice(config, st.config_keys),
                      "upstream": {u: digests[u] for u in st.upstream}})


def record_or_reason(st: Stage, store: RunStore, force, digest: str):
    """The stage's valid record and "", or None and why it must run."""
    if st.name in force:
        return None, "forced"
    if st.always:
        return None, "always runs"
    return store.check_record(st.name, digest)
