"""Run a study: an ordered list of cached, resumable stages writing one run directory.

Each :class:`Stage` names the config keys and upstream stages it depends on. Its
inputs hash is the SHA-256 of (stage name, stage version, the values of those config
keys, the output digests of its upstream stages). :func:`run_study` skips a stage
whose record in ``<run>/stages/`` carries the same inputs hash and whose outputs
are unchanged on disk; everything else runs, in order, writing through a staging
directory (see :mod:`pipeline.engine.runstore`). So a second run of the same config runs
nothing, a changed ANFIS epoch count re-runs model fitting and what follows, and an
interrupted run resumes at the stage that did not finish.

The run directory never lies:

- ``manifest.json`` says what state the directory is in: ``"status"`` is ``"running"``
  (with the ``"stage"`` under way; a killed run leaves it so, and the next run names
  it: "the previous run stopped during stage X; resuming"), ``"complete"``,
  ``"failed"`` or ``"interrupted"`` (Ctrl-C; :class:`StudyInterrupted`), and
  ``"files"`` lists every file of the run (config, stage outputs, stage records).
- A stage owns its outputs: what its previous record listed and this run did not write
  is removed (:meth:`pipeline.engine.runstore.RunStore.commit`).
- Stage outputs hold no wall-clock time (times are in the manifest and the records):
  the same inputs give the same bytes, so a re-run stage leaves its downstream stages
  cached. Stages run with ``SOURCE_DATE_EPOCH=0`` unless it is set, which keeps
  matplotlib's PDF creation date out of the figures.
- A directory that is not a run directory is refused (:func:`pipeline.engine.runstore.open_run_dir`),
  a run directory of another config is reported with the keys that differ, and one
  that cannot be written raises :class:`pipeline.engine.runstore.RunDirError` (one line).
- ``checks`` (for the full study: :func:`pipeline.stages.check_antenna_mounts`) run
  before the first stage that is not an ``always`` stage, so a config that cannot work
  on its scene fails before anything is traced.

The engine takes its stage list as an argument and imports no stage: the study's
stages are :data:`pipeline.stages.STAGES` (:func:`pipeline.apps.studyrun.run_full_study` runs
them); they call ``scenes``, ``propagation``, ``fuzzymodel`` and the ``pipeline``
sub-packages. What a stage is and when it must run (:class:`Stage`,
:class:`StageContext`, the inputs hash) is :mod:`pipeline.engine.stagedef`, which this runner and
the side process (:mod:`pipeline.engine.stageproc`) both import: neither imports the other's names.
"""

from __future__ import annotations

import contextlib
import logging
import sys
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path

from pipeline.config import ConfigError, StudyConfig, config_to_toml
from pipeline.engine.runlog import (
    config_changes,
    describe_previous_run,
    final_paths_in_logs,
    peak_rss_mib,
    reproducible_outputs,
    run_log,
    utc_now,
    write_manifest,
)
from pipeline.engine.runstore import (
    STAGING_DIR,
    RunDirError,
    RunStore,
    StageRecord,
    atomic_write_text,
    json_hash,
    open_run_dir,
    write_error,
)
from pipeline.engine.stagedef import (
    Stage,
    StageContext,
    StageError,
    StageInputError,
    check_outputs,
    config_slice,
    record_or_reason,
    stage_inputs_hash,
)
from pipeline.engine.stageproc import finish_side, start_side

__all__ = [
    "RunDirError",
    "Stage",
    "StageContext",
    "StageError",
    "StageInputError",
    "StudyInterrupted",
    "StudyResult",
    "config_changes",
    "config_slice",
    "peak_rss_mib",
    "run_study",
]

log = logging.getLogger(__name__)


class StudyInterrupted(KeyboardInterrupt):
    """Ctrl-C during a run; finished stages are kept and the manifest says ``interrupted``.

    Attributes
    ----------
    stage : str or None
        The stage under way (``None``: between stages).
    run_dir : pathlib.Path
    """

    def __init__(self, stage: str | None, run_dir: Path):
        self.stage = stage
        self.run_dir = run_dir
        where = f"at stage {stage}" if stage else "between stages"
        super().__init__(f"interrupted {where}; rerun the same command to resume")

    def __str__(self) -> str:
        return str(self.args[0])


@dataclass
class StudyResult:
    """Outcome of :func:`run_study`.

    Attributes
    ----------
    run_dir : pathlib.Path
        The run directory.
    ran : list of str
        Stages executed in this call.
    cached : list of str
        Stages skipped because their record matched.
    records : dict[str, StageRecord]
        The record of every stage.
    elapsed_s : float
        Wall-clock time of the call [s].
    peak_rss_mib : float
        Peak resident memory of the process [MiB].
    previous : str
        What the previous run in this directory left ("" for a fresh directory or a
        complete run; else e.g. "the previous run stopped during stage reads").
    changed_keys : list of str
        Dotted config keys whose values differ from the config of the previous run in
        this directory.
    """

    run_dir: Path
    ran: list[str] = field(default_factory=list)
    cached: list[str] = field(default_factory=list)
    records: dict[str, StageRecord] = field(default_factory=dict)
    elapsed_s: float = 0.0
    peak_rss_mib: float = 0.0
    previous: str = ""
    changed_keys: list[str] = field(default_factory=list)


@contextlib.contextmanager
def _progress_bars(enabled: bool):
    if not enabled:
        yield None
        return
    from rich.progress import (
        BarColumn,
        MofNCompleteColumn,
        Progress,
        TextColumn,
        TimeElapsedColumn,
        TimeRemainingColumn,
    )
    from rich.table import Column

    # fixed widths: at 80 columns every bar, count and time stays visible (a long stage
    # description is cut with an ellipsis, never wrapped)
    with Progress(TextColumn("{task.description}", table_column=Column(
                      width=32, no_wrap=True, overflow="ellipsis")),
                  BarColumn(bar_width=14), MofNCompleteColumn(table_column=Column(width=11)),
                  TimeElapsedColumn(), TimeRemainingColumn(), transient=False) as prog:
        yield prog


def _write_error(exc: OSError, store: RunStore) -> OSError | RunDirError:
    err = write_error(exc, store.root)
    return exc if err is None else err


def _next_side(stages: Sequence[Stage], k: int, digests: dict) -> Stage | None:
    """The stage that may start in a process of its own while stage ``k`` runs: the first
    ``own_process`` stage after ``k`` whose upstream stages are all done (none of the stages
    in between can need it: they come before it). It is waited for where it stands in the
    order, so it may run beside several stages (``truth_traces`` beside the tour and the
    reads)."""
    for st in stages[k + 1:]:
        if st.own_process and all(u in digests for u in st.upstream):
            return st
    return None


def run_study(config: StudyConfig, run_dir: str | Path, stages: Sequence[Stage], *,
              progress: bool = False, force: Sequence[str] = (),
              command_line: Sequence[str] | None = None,
              manifest_extra: Callable[[StudyConfig], dict] | None = None,
              force_dir: bool = False,
              checks: Sequence[Callable[[StageContext], None]] | None = None) -> StudyResult:
    """Run (or resume) a study into ``run_dir``.

    Parameters
    ----------
    config : StudyConfig
        The resolved study configuration.
    run_dir : path
        Run directory: missing (created), empty, or a run directory of this tool.
        ``config.toml`` and ``manifest.json`` are (re)written there.
    stages : sequence of Stage
        The stages, in order (the full study: :data:`pipeline.stages.STAGES`, or call
        :func:`pipeline.apps.studyrun.run_full_study`).
    progress : bool
        Draw rich progress bars on stderr.
    force : sequence of str
        Stage names to re-run even if cached (downstream stages follow by hash).
    command_line : sequence of str, optional
        Recorded in the manifest (default ``sys.argv``).
    manifest_extra : callable, optional
        ``f(config) -> dict`` merged into the manifest (the full study: package versions
        and the Dr.Jit backend, :func:`pipeline.stages.manifest_info`).
    force_dir : bool
        Run into a non-empty directory that is not a run directory.
    checks : sequence of callable, optional
        ``f(ctx)`` run once before the first stage that is not ``always`` (after the
        scene stage); they raise :class:`~pipeline.config.ConfigError` naming a key
        (the full study: :data:`pipeline.stages.CHECKS`).

    Returns
    -------
    StudyResult

    Raises
    ------
    StageError
        When a stage fails; the message names the stage and the cause, outputs of the
        stages before it are intact and the manifest records the failure.
    StudyInterrupted
        On Ctrl-C (a ``KeyboardInterrupt``): the stage under way is discarded, finished
        stages are kept, the manifest says ``"interrupted"`` and names the stage.
    RunDirError
        ``run_dir`` is a file, a non-empty directory that is not a run directory (and
        ``force_dir`` is false), or cannot be written (read-only, no permission, full);
        another process runs into it (:class:`~pipeline.engine.runstore.RunDirLocked`); a
        symbolic link inside it where the run must write or read
        (:class:`~pipeline.engine.runstore.UnsafePathError`).
    pipeline.config.ConfigError
        A check failed (the message names the key and value).
    """
    checks = tuple(checks or ())
    known = {s.name for s in stages}
    unknown = [f for f in force if f not in known]
    if unknown:
        raise ValueError(f"unknown stage(s) {unknown} in force; stages are {sorted(known)}")
    store = open_run_dir(run_dir, force_dir=force_dir)
    try:
        with store.lock(" ".join(command_line if command_line is not None else sys.argv)), \
                run_log(store):
            return _run_locked(store, config, stages, progress, force, command_line,
                               manifest_extra, checks)
    except OSError as exc:  # the lock itself could not be taken (read-only, full)
        err = write_error(exc, store.root)
        if err is None:
            raise
        raise err from None


def _run_locked(store, config, stages, progress, force, command_line, manifest_extra,
                checks) -> StudyResult:
    """:func:`run_study`'s body, run while the directory's lock is held."""
    t0 = time.perf_counter()
    started = utc_now()
    result = StudyResult(run_dir=store.root)
    describe_previous_run(store, config, result)
    memo: dict = {}
    digests: dict[str, str] = {}
    current: str | None = None

    def manifest(status, stage=None, failure=None, extra=None):
        write_manifest(store, config, result, started, t0, command_line, extra, failure,
                       status=status, stage=stage)

    side = None  # a stage running in its own process beside ``current``

    def stop_side():
        nonlocal side
        if side is not None:
            side.proc.stop()
            store.discard(side.stage.name)
            side = None

    try:
        manifest("running")
        atomic_write_text(store.path("config.toml"), config_to_toml(config))
        with _progress_bars(progress) as prog:
            for k, st in enumerate(stages):
                if side is not None and side.stage is st:  # started beside stages before it
                    current = st.name
                    rec = finish_side(side, store, result, prog,
                                      lambda f: _safe(manifest, "failed", f["stage"], f, manifest_extra))
                    side = None
                    result.records[st.name] = rec
                    digests[st.name] = json_hash([rec.inputs_hash, rec.digest])
                    continue
                missing = [u for u in st.upstream if u not in digests]
                if missing:
                    raise ValueError(f"stage {st.name!r} needs {missing} to run before it")
                if checks and not st.always:
                    current = "checks"
                    _run_checks(checks, config, store, prog, memo, result, manifest)
                    checks = ()
                current = st.name
                inputs_hash = stage_inputs_hash(st, config, digests)
                rec, reason = record_or_reason(st, store, force, inputs_hash)
                if rec is not None:
                    log.info("stage %s: up to date, skipped", st.name)
                    result.cached.append(st.name)
                else:
                    log.log(logging.DEBUG if st.always else logging.INFO, "stage %s: running (%s)",
                            st.name, reason)
                    if side is None and not checks and not st.always:
                        side = start_side(_next_side(stages, k, digests), config, store, digests,
                                          force, prog)
                    if side is not None:
                        current = f"{st.name} + {side.stage.name}"
                    manifest("running", current)
                    staged = store.staging(st.name)
                    ctx = StageContext(config, store, st.name, staged, prog, memo)
                    ts = time.perf_counter()
                    try:
                        with reproducible_outputs(), final_paths_in_logs(staged, store.root):
                            info = st.func(ctx) or {}
                        check_outputs(st, staged)
                    except Exception as exc:
                        store.discard(st.name)
                        stop_side()  # its work is lost, never half-committed
                        failure = {"stage": st.name, "error": f"{type(exc).__name__}: {exc}"}
                        _safe(manifest, "failed", st.name, failure, manifest_extra)
                        raise StageError(f"stage {st.name!r} failed: {type(exc).__name__}: {exc} "
                                         f"(earlier stages' outputs in {store.root} are intact; "
                                         "fix the cause and rerun to resume)",
                                         stage=st.name, kind=type(exc).__name__) from exc
                    prev = store.read_record(st.name) if st.always else None
                    rec = store.commit(st.name, inputs_hash, staged, time.perf_counter() - ts,
                                       peak_rss_mib(), utc_now(), info)
                    if prev is not None and prev.inputs_hash == inputs_hash and prev.outputs == rec.outputs:
                        result.cached.append(st.name)  # re-checked, outputs unchanged
                    else:
                        result.ran.append(st.name)
                result.records[st.name] = rec
                digests[st.name] = json_hash([rec.inputs_hash, rec.digest])
                if side is not None:  # committed (and in the manifest); the other still runs
                    current = side.stage.name
                    manifest("running", current)
            current = None
        manifest("complete", extra=manifest_extra)
        store.remove_staging_root()
    except KeyboardInterrupt:
        stop_side()
        if current and current != "checks":
            for name in current.split(" + "):
                store.discard(name)
        _safe(manifest, "interrupted", current, None, None)
        raise StudyInterrupted(current, store.root) from None
    except OSError as exc:
        stop_side()
        err = _write_error(exc, store)
        if err is exc:
            raise
        if current and current != "checks":
            for name in current.split(" + "):
                store.discard(name)
        raise err from None
    except RunDirError as exc:  # a link on the way, a user's file: refused, named, recorded
        stop_side()
        if current and current != "checks":
            for name in current.split(" + "):
                store.discard(name)
        _safe(manifest, "failed", current, {"stage": current, "error": str(exc)}, None)
        raise
    except BaseException:
        stop_side()
        raise
    return result


def _run_checks(checks, config, store, prog, memo, result, manifest) -> None:
    ctx = StageContext(config, store, "checks", store.root / STAGING_DIR / "checks", prog, memo)
    for check in checks:
        try:
            check(ctx)
        except ConfigError as exc:
            _safe(manifest, "failed", "checks", {"stage": "checks", "error": str(exc)}, None)
            raise


def _safe(manifest, status, stage, failure, extra) -> None:
    """Write the manifest on the way out of a failure; a write error must not hide it."""
    try:
        manifest(status, stage, failure, extra)
    except OSError as exc:
        log.warning("could not update manifest.json: %s", exc)
