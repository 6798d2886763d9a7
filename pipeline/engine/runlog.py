"""What a run knows around its stages: the run directory's history and the stages' environment.

- :func:`describe_previous_run`: what the previous run in a run directory left (killed,
  interrupted, failed) and how its config differs from this one (logged, and recorded in
  the :class:`pipeline.engine.study.StudyResult`);
- :func:`config_changes`: the dotted keys whose values differ between two configs;
- :func:`reproducible_outputs`: ``SOURCE_DATE_EPOCH=0`` while a stage runs (no dates in
  PDF metadata), so identical inputs give identical bytes;
- :func:`final_paths_in_logs`: log lines naming a file in the staging area name its
  final place instead;
- :func:`write_manifest`: the run's ``manifest.json`` (status, timings, files), with
  :func:`peak_rss_mib` and :func:`utc_now`;
- :func:`run_log`: every log line of the run at INFO and above (both processes) in the run
  directory's ``run.log``, whatever the console shows.
"""

from __future__ import annotations

import contextlib
import datetime as _dt
import errno
import logging
import os
import resource
import stat
import sys
import threading
import time
import tomllib
from pathlib import Path

from pipeline.config import StudyConfig, config_to_dict
from pipeline.engine.runstore import (
    MANIFEST,
    RECORD_DIR,
    RunStore,
    UnsafePathError,
    atomic_write_json,
    read_run_json,
    regular_file,
)
from pipeline.runpaths import RUN_KIND, TOOL

__all__ = ["RUN_LOG", "config_changes", "describe_previous_run", "final_paths_in_logs",
           "is_file_handler", "log_to_file", "peak_rss_mib", "reproducible_outputs", "run_log", "utc_now",
           "write_manifest"]

#: The run directory's log file: every INFO, WARNING and ERROR line of the run.
RUN_LOG = "run.log"

#: The loggers of the project (their records go to run.log at INFO and above).
PROJECT_LOGGERS = ("pipeline", "scenes", "propagation", "fuzzymodel")

_LOG_FORMAT = "%(asctime)s %(levelname)s %(processName)s %(name)s: %(message)s"

log = logging.getLogger("pipeline.engine.study")


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


class _OnceEach(logging.Filter):
    """Passes each distinct WARNING (or worse) message once: the console of a run shows a
    repeated warning once (run.log keeps every occurrence)."""

    def __init__(self):
        super().__init__()
        self.seen: set[tuple[int, str]] = set()

    def filter(self, record: logging.LogRecord) -> bool:
        if record.levelno < logging.WARNING:
            return True
        key = (record.levelno, record.getMessage())
        if key in self.seen:
            return False
        self.seen.add(key)
        return True


class _RunLogHandler(logging.StreamHandler):
    """The handler writing run.log (told apart from console handlers)."""


def is_file_handler(h: logging.Handler) -> bool:
    """Whether a handler writes a file (run.log, a user's FileHandler), not a console."""
    return isinstance(h, (_RunLogHandler, logging.FileHandler))


def _open_log(path: Path, mode: str):
    """The log file's text stream: never through a link, never a FIFO or device (refused by
    ``fstat`` on the same descriptor, opened without blocking), appended by every writer
    (O_APPEND: each line lands whole at the end, neither process overwrites the other's).
    ``mode="w"`` starts a new file: an old regular file is unlinked first (not truncated:
    it may be a hard link to a file elsewhere)."""
    if mode == "w" and os.path.lexists(path):
        if not stat.S_ISREG(os.lstat(path).st_mode):
            raise UnsafePathError(f"{path} is not a regular file: rfidstudy does not write "
                                  "its log into it; remove it")
        os.unlink(path)
    flags = (os.O_WRONLY | os.O_CREAT | os.O_APPEND | getattr(os, "O_NOFOLLOW", 0)
             | getattr(os, "O_NONBLOCK", 0) | (os.O_EXCL if mode == "w" else 0))
    try:
        fd = os.open(path, flags, 0o644)
    except OSError as exc:
        if exc.errno in (errno.ELOOP, errno.ENXIO):  # a link; a FIFO without a reader
            raise UnsafePathError(f"{path} is a link or not a regular file: rfidstudy does "
                                  "not write its log into it; remove it") from None
        raise
    if not stat.S_ISREG(os.fstat(fd).st_mode):
        os.close(fd)
        raise UnsafePathError(f"{path} is not a regular file: rfidstudy does not write its "
                              "log into it; remove it")
    os.set_blocking(fd, True)
    return os.fdopen(fd, "w", encoding="utf-8", buffering=1)


#: Each thread's innermost open run log (:func:`log_to_file` blocks nest).
_INNERMOST: dict[int, logging.Handler] = {}


class _ThisThread(logging.Filter):
    """Passes the records of the thread that opened the log (and of processes forked from
    it) while the log is that thread's innermost: two runs in one process (threads of a
    Dask worker) keep their lines apart, and a study run inside another's stage (a
    replicate or placement candidate on one local worker) writes its own run.log, not
    its caller's too, as it would in a worker process."""

    def __init__(self, handler: logging.Handler):
        super().__init__()
        self.ident = threading.get_ident()
        self.handler = handler

    def filter(self, record: logging.LogRecord) -> bool:
        return record.thread == self.ident and _INNERMOST.get(self.ident) is self.handler


@contextlib.contextmanager
def log_to_file(path: Path, mode: str = "a"):
    """Within the block, the project's log records at INFO and above are also written to
    `path`.

    No logger's or handler's level is changed: what reaches the file is what the logging
    configuration lets through at INFO and above (the command line sets the project's
    loggers to INFO, its console handler to WARNING without ``-v``). The console handlers
    pass each distinct warning once while the block runs. Where logging is not configured
    at all (a spawned worker), warnings still reach stderr, as Python's last-resort
    handler would print them.
    """
    stream = _open_log(path, mode)
    handler = _RunLogHandler(stream)
    handler.setLevel(logging.INFO)
    handler.setFormatter(logging.Formatter(_LOG_FORMAT))
    handler.addFilter(_ThisThread(handler))
    ident = threading.get_ident()
    outer = _INNERMOST.get(ident)
    _INNERMOST[ident] = handler
    root = logging.getLogger()
    fallback = None
    if not root.handlers:  # the file handler would otherwise silence the last resort
        fallback = logging.StreamHandler(sys.stderr)
        fallback.setLevel(logging.WARNING)
        root.addHandler(fallback)
    # one filter per console handler: a shared one would let only the first handler see
    # each message
    consoles = [(h, _OnceEach()) for h in root.handlers if not is_file_handler(h)]
    for h, once in consoles:
        h.addFilter(once)
    loggers = [logging.getLogger(name) for name in PROJECT_LOGGERS]
    for lg in loggers:
        lg.addHandler(handler)
    try:
        yield handler
    finally:
        if outer is None:
            _INNERMOST.pop(ident, None)
        else:
            _INNERMOST[ident] = outer
        for lg in loggers:
            lg.removeHandler(handler)
        for h, once in consoles:
            h.removeFilter(once)
        if fallback is not None:
            root.removeHandler(fallback)
        handler.close()
        stream.close()


@contextlib.contextmanager
def run_log(store: RunStore):
    """``run.log`` of this run (written afresh: it holds this run's lines only)."""
    with log_to_file(store.path(RUN_LOG), mode="w") as handler:
        yield handler


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
            man = read_run_json(man_path)
        except ValueError:
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


def peak_rss_mib() -> float:
    """Peak resident set size of this process so far [MiB] (``getrusage``)."""
    kib = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
    return kib / 1024.0 if sys.platform != "darwin" else kib / 2**20


def utc_now() -> str:
    """The current UTC time, ISO 8601 to the second."""
    return _dt.datetime.now(_dt.timezone.utc).isoformat(timespec="seconds")


def _manifest_files(store: RunStore, result) -> list[str]:
    """Files of this run: config.toml, every stage's outputs and records (not the manifest)."""
    files = {name for name in ("config.toml", RUN_LOG) if store.path(name).is_file()}
    for name, rec in result.records.items():
        files.update(rec.outputs)
        files.add(f"{RECORD_DIR}/{name}.json")
    return sorted(files)


def write_manifest(store: RunStore, config: StudyConfig, result, started: str, t0: float,
                   command_line, manifest_extra, failure, status=None, stage=None) -> None:
    """Write ``manifest.json``: the run's status, stage under way, failure, timings per
    stage, files, and ``manifest_extra(config)`` (package versions, backend)."""
    result.elapsed_s = time.perf_counter() - t0
    result.peak_rss_mib = peak_rss_mib()

    manifest = {
        "tool": TOOL,  # what makes the folder a run directory (runpaths.is_run_dir)
        "kind": RUN_KIND,
        "seed": config.seed,
        "scene": config.scene,
        "command_line": list(command_line if command_line is not None else sys.argv),
        "started_utc": started,
        "finished_utc": utc_now(),
        "elapsed_s": round(result.elapsed_s, 3),
        "peak_rss_mib": round(result.peak_rss_mib, 1),
        "status": status or ("failed" if failure else "complete"),
        "stage": stage,
        "failure": failure,
        "previous_run": result.previous or None,
        "stages": {
            name: {
                "status": "ran" if name in result.ran else "cached",
                "elapsed_s": rec.elapsed_s,
                "peak_rss_mib": rec.peak_rss_mib,
                "finished_utc": rec.finished_utc,
                "info": rec.info,
            }
            for name, rec in result.records.items()
        },
        "files": _manifest_files(store, result),
    }
    if manifest_extra is not None:
        try:
            manifest.update(manifest_extra(config))
        except Exception as exc:  # the manifest must not hide the real result
            log.warning("manifest: could not collect environment info: %s", exc)
    atomic_write_json(store.path(MANIFEST), manifest)
