"""The run directory: atomic writes, per-stage staging and stage records.

Every file a stage produces is first written into a staging directory
(``<run>/.staging/<stage>/``); when the stage function returns, each file is renamed
into place (``os.replace``, atomic on one file system) and only then is the stage
record ``<run>/stages/<stage>.json`` written. A stage killed or failing half-way
therefore leaves earlier results intact and no record, so the next run redoes it.

A record holds the stage's inputs hash (config slice + upstream output digests +
stage version) and the SHA-256 of every output file; a rerun skips a stage only if
its record's inputs hash matches and every output still has the recorded digest
(a changed or truncated file is reported by name and the stage re-runs).

A directory is a run directory when it holds a ``manifest.json`` this tool wrote
(:func:`is_run_dir`: ``"tool": "rfidstudy"``, written first by every run; an older
run's manifest is known by its own keys): a folder that merely has a file of that name
(a web app's) or an empty ``stages/`` is someone else's;
:func:`open_run_dir` refuses a path that is a file, and a non-empty directory that is
not a run directory (unless told otherwise), with a :class:`RunDirError` naming it.

Containment (:mod:`pipeline.runpaths`, re-exported here): a run directory may come
from someone else, so nothing in it is trusted to point elsewhere. Every path the store
reads, hashes, writes or deletes goes through :func:`inside`: relative, no ``..``, no component a symbolic link (a link is never
followed, for reading or writing), and only regular files are read or hashed (a FIFO
or device would hang or leak). A stage record naming a path that fails this is corrupt
(named in a warning; its stage re-runs) and nothing it names is touched; a symbolic
link where the store must write stops the run naming it (:class:`UnsafePathError`),
as ``tar`` refuses to extract outside its target.

One writer: :meth:`RunStore.lock` holds an exclusive ``filelock`` lock on
``.rfidstudy.lock`` for a whole run (or a ``figures`` / ``report`` rewrite); a second
writer is refused with the holder's process id, command and start time. The lock is
an ``flock``: the kernel releases it when its process dies, so a stale lock is taken
over by the next writer. :func:`lock_holder` asks who holds it without writing: a
replicated run or a placement pools or ranks its studies only when no process (a
worker of an earlier, killed run) still writes one (:func:`check_no_writer`).
"""

from __future__ import annotations

import errno
import hashlib
import json
import logging
import os
import re
import shutil
import time
from contextlib import contextmanager
from dataclasses import asdict, dataclass, field
from pathlib import Path

from pipeline.runpaths import (
    MANIFEST,
    RECORD_DIR,
    RunDirError,
    UnsafePathError,
    file_sha256,
    inside,
    is_run_dir,
    not_regular,
    read_run_json,
    read_run_text,
    regular_file,
    run_files,
)
from scenes.fileio import atomic_write_bytes, atomic_write_text

__all__ = [
    "HOUSEKEEPING",
    "RunDirError",
    "RunDirLocked",
    "RunStore",
    "StageRecord",
    "UnsafePathError",
    "atomic_write_bytes",
    "atomic_write_json",
    "atomic_write_text",
    "check_no_writer",
    "file_sha256",
    "final_name",
    "inside",
    "is_run_dir",
    "json_hash",
    "lock_holder",
    "not_regular",
    "open_run_dir",
    "read_run_json",
    "read_run_text",
    "regular_file",
    "run_files",
    "save_npz",
    "write_error",
]

log = logging.getLogger(__name__)

STAGING_DIR = ".staging"
LOCK_FILE = ".rfidstudy.lock"
LOCK_OWNER = ".rfidstudy.owner.json"
#: Marks a directory that held other files when rfidstudy first ran into it
#: (``--force-dir``): every later run keeps protecting the files no record lists.
FOREIGN_MARK = ".rfidstudy.foreign"
#: The lock's files: housekeeping of a run in progress, not results (not in the manifest;
#: the lock file itself stays, as an flock's file must for the lock to be safe).
HOUSEKEEPING = frozenset({LOCK_FILE, LOCK_OWNER, FOREIGN_MARK})
#: Files the tool writes at a run directory's top level outside any stage record: in a
#: foreign directory (``force_dir``) a user's file under one of these names stops the run.
OWN_TOP_LEVEL = ("config.toml", MANIFEST, "run.log")

#: errno values of a run directory that cannot be written (read-only mount, permissions,
#: full disk, a file where a folder should be).
WRITE_ERRNOS = frozenset({errno.EROFS, errno.EACCES, errno.EPERM, errno.ENOSPC, errno.EDQUOT,
                          errno.ENOTDIR, errno.EISDIR, errno.EEXIST})


class RunDirLocked(RunDirError):
    """Another process holds the run directory's lock (the message names it)."""


_TEMP_NAME = re.compile(r"^\.(?P<name>.+)\.[^.]+\.tmp(?:\.[A-Za-z0-9]+)?$")


def lock_holder(root: str | Path) -> str | None:
    """Who holds run directory ``root``'s lock now, or None (free, or never locked).

    The lock is tried without waiting and released at once; nothing is written (a
    missing lock file, or one that is a link, is "never locked": nothing is created).

    Returns
    -------
    str or None
        ``"process 1234 (rfidstudy run ..., since 2026-...)"`` as the holder's owner file
        says (``"another process"`` without one).
    """
    from filelock import FileLock, Timeout

    root = Path(root)
    if not regular_file(root / LOCK_FILE):
        return None
    lock = FileLock(str(root / LOCK_FILE), timeout=0)
    try:
        lock.acquire()
    except Timeout:
        return RunStore(root)._owner()
    except OSError:  # unreadable: not this check's to judge; the writer's own lock says
        return None
    lock.release()
    return None


def check_no_writer(dirs, what: str, rows=None) -> None:
    """Stop before ``what`` (pooling, ranking) reads ``dirs`` while a process writes one.

    Parameters
    ----------
    dirs : sequence of path
        Run directories (replicates, candidates' replicates); missing ones pass.
    what : str
        What would read them (for the message).
    rows : sequence of dict, optional
        The studies' rows (:func:`pipeline.apps.studypool.run_point`), one per directory: a study
        refused for a lock (``kind`` ``RunDirLocked``) whose holder has ended since
        stops ``what`` too (its directory is not complete yet).

    Raises
    ------
    RunDirLocked
        Naming the first directory whose lock another process holds and that process
        (:func:`lock_holder`: a worker of an earlier, killed run still writing it), or
        whose study was refused for a lock.
    """
    for d in dirs:
        holder = lock_holder(d) if Path(d).is_dir() else None
        if holder is not None:
            raise RunDirLocked(f"{d} is still being written by {holder} (a worker of an "
                               f"earlier run?): {what} refused; wait for it to end, or stop "
                               "it, and rerun")
    for d, row in zip(dirs, rows or (), strict=False):
        if isinstance(row, dict) and row.get("kind") == "RunDirLocked":
            cause = str(row.get("error") or "").split(": one writer", 1)[0]
            raise RunDirLocked(f"{cause or d} when this run tried {d} (a worker of an earlier "
                               f"run?): {what} refused; rerun")


def final_name(path) -> str:
    """The file an atomic write's temporary file (``.<name>.<random>.tmp``) stands for."""
    p = Path(str(path))
    m = _TEMP_NAME.match(p.name)
    return str(p.with_name(m.group("name"))) if m else str(p)


def write_error(exc: OSError, root) -> RunDirError | None:
    """A :class:`RunDirError` for an ``OSError`` that means "cannot write here", else None."""
    if exc.errno not in WRITE_ERRNOS:
        return None
    where = final_name(exc.filename) if exc.filename is not None else root
    reason = {errno.EROFS: "the file system is read-only", errno.EACCES: "permission denied",
              errno.EPERM: "operation not permitted", errno.ENOSPC: "no space left on the device",
              errno.EDQUOT: "disk quota exceeded"}.get(exc.errno, exc.strerror or str(exc))
    return RunDirError(f"cannot write the run directory {root}: {reason} ({where})")


def open_run_dir(root: str | Path, *, force_dir: bool = False) -> RunStore:
    """The :class:`RunStore` at ``root``, after checking that it may be written.

    Parameters
    ----------
    root : path
        Run directory: missing (created), empty, or a run directory of this tool.
    force_dir : bool
        Also accept a non-empty directory that is not a run directory (its other files
        are left alone).

    Raises
    ------
    RunDirError
        ``root`` is a file (or lies under one); it is a non-empty directory that is not
        a run directory (:func:`is_run_dir`) and ``force_dir`` is false; it cannot be
        created.
    """
    path = Path(root).expanduser()
    try:
        path.resolve(strict=False)
    except (OSError, RuntimeError) as exc:  # a symbolic link loop (ELOOP)
        raise RunDirError(f"{path}: cannot be resolved ({getattr(exc, 'strerror', None) or exc})") from None
    if path.exists() and not path.is_dir():
        raise RunDirError(f"{path} is a file, not a directory: choose a directory for the run")
    for parent in path.parents:
        if parent.exists() and not parent.is_dir():
            raise RunDirError(f"{path}: {parent} is a file, not a directory")
    if path.is_dir() and not force_dir and not is_run_dir(path):
        try:
            entries = sorted(p.name for p in path.iterdir())
        except OSError as exc:
            raise RunDirError(f"cannot read the run directory {path}: {exc.strerror}") from None
        if entries:
            shown = ", ".join(entries[:3]) + (", ..." if len(entries) > 3 else "")
            raise RunDirError(
                f"{path} is not empty ({shown}) and is not a run directory of rfidstudy (no "
                f"{MANIFEST} of rfidstudy's): choose another directory, or pass --force-dir "
                "(force_dir=True) to run into it")
    first_time = path.is_dir() and not is_run_dir(path) and any(path.iterdir())
    foreign = first_time or regular_file(path / FOREIGN_MARK)
    if first_time:  # --force-dir: the tool's own outputs only, never a user's file
        for name in OWN_TOP_LEVEL:
            if os.path.lexists(path / name):
                raise RunDirError(
                    f"{path / name}: a file of yours where rfidstudy writes its {name}; "
                    "--force-dir writes only the tool's own outputs: move it, or choose "
                    "another directory")
    try:
        store = RunStore(path, foreign=foreign)
        if first_time:
            atomic_write_text(store.path(FOREIGN_MARK), "rfidstudy ran into this directory with "
                              "--force-dir: files no stage record lists are the user's\n")
        return store
    except OSError as exc:
        err = write_error(exc, path)
        if err is None:
            raise
        raise err from None


def json_hash(obj) -> str:
    """SHA-256 of the canonical JSON of ``obj`` (sorted keys)."""
    text = json.dumps(obj, sort_keys=True, separators=(",", ":"), default=str)
    return hashlib.sha256(text.encode()).hexdigest()


def atomic_write_json(path: str | Path, obj) -> Path:
    """Atomic JSON write, indented, keys sorted."""
    return atomic_write_text(path, json.dumps(obj, indent=2, sort_keys=True, default=str) + "\n")


def save_npz(path: str | Path, **arrays) -> Path:
    """Write an uncompressed NPZ whose bytes depend on the arrays only.

    ``numpy.savez`` stamps each member with the current time, so two identical saves
    differ; here every member carries a fixed date, which lets stage digests compare
    equal when a stage reproduces its outputs. Readable by ``numpy.load``.
    """
    import io
    import zipfile

    import numpy as np

    buf = io.BytesIO()
    with zipfile.ZipFile(buf, "w", compression=zipfile.ZIP_STORED) as zf:
        for name, arr in arrays.items():
            info = zipfile.ZipInfo(f"{name}.npy", date_time=(1980, 1, 1, 0, 0, 0))
            member = io.BytesIO()
            np.lib.format.write_array(member, np.asanyarray(arr), allow_pickle=False)
            zf.writestr(info, member.getvalue())
    return atomic_write_bytes(path, buf.getvalue())


@dataclass
class StageRecord:
    """What a finished stage wrote, and from which inputs.

    Attributes
    ----------
    stage : str
        Stage name.
    inputs_hash : str
        SHA-256 of the stage's inputs (config slice, upstream digests, version).
    outputs : dict[str, str]
        Output path relative to the run directory -> SHA-256 of its bytes.
    elapsed_s : float
        Wall-clock time the stage took [s].
    peak_rss_mib : float
        Peak resident memory of the process at the end of the stage [MiB].
    finished_utc : str
        ISO 8601 time the stage finished.
    info : dict
        Small JSON-able summary the stage returned (counts, solver settings).
    """

    stage: str
    inputs_hash: str
    outputs: dict[str, str]
    elapsed_s: float = 0.0
    peak_rss_mib: float = 0.0
    finished_utc: str = ""
    info: dict = field(default_factory=dict)

    @property
    def digest(self) -> str:
        """Digest of the outputs (what downstream stages hash as their input)."""
        return json_hash(self.outputs)


class RunStore:
    """A run directory with staged, atomic stage outputs and stage records.

    Every path goes through :func:`inside` (see the module docstring): nothing outside
    the directory is read, hashed, written or deleted on the strength of a file in it.

    Parameters
    ----------
    root : path
        The run directory (created if missing).
    foreign : bool
        The directory held other files before (``--force-dir``): a stage output whose
        name is already taken by a file no record of this tool lists stops the run
        naming it, instead of replacing the user's file.
    """

    def __init__(self, root: str | Path, foreign: bool = False):
        self.root = Path(root).resolve()
        self.root.mkdir(parents=True, exist_ok=True)
        self.foreign = foreign

    def path(self, rel: str) -> Path:
        """Absolute path of a run-directory file, checked by :func:`inside`."""
        return inside(self.root, rel)

    def record_path(self, stage: str) -> Path:
        """Path of a stage record."""
        return self.path(f"{RECORD_DIR}/{stage}.json")

    @contextmanager
    def lock(self, command: str = "rfidstudy"):
        """Hold the directory's exclusive lock for the ``with`` block.

        Raises
        ------
        RunDirLocked
            Another live process holds it (its pid, command and start time named).
        UnsafePathError
            The lock file is a symbolic link or not a regular file.
        """
        from filelock import FileLock, Timeout

        path = self.path(LOCK_FILE)
        if os.path.lexists(path) and not regular_file(path):
            raise UnsafePathError(f"{path} is not a regular file: it cannot serve as the lock")
        lock = FileLock(str(path), timeout=0)
        try:
            lock.acquire()
        except Timeout:
            raise RunDirLocked(f"{self.root} is in use by {self._owner()}: one writer per run "
                               "directory; wait for it to finish, or use another --out") from None
        try:
            atomic_write_json(self.path(LOCK_OWNER), {
                "pid": os.getpid(), "command": command,
                "started_utc": time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime())})
            yield self
        finally:
            try:
                self.path(LOCK_OWNER).unlink(missing_ok=True)
            except (OSError, UnsafePathError):
                pass
            lock.release()

    def _owner(self) -> str:
        """Who holds the lock, as the owner file says (best effort)."""
        try:
            o = read_run_json(self.path(LOCK_OWNER), max_bytes=4096)
            return f"process {int(o['pid'])} ({str(o['command'])[:80]}, since {str(o['started_utc'])[:20]})"
        except (OSError, ValueError, KeyError, TypeError, RunDirError):
            pass
        return "another process"

    def read_record(self, stage: str) -> StageRecord | None:
        """The stage's record, or ``None`` if absent or unreadable (with a warning).

        A record is data from the directory, so it is checked: a regular file of at
        most 16 MiB holding the record's fields with their types.
        """
        p = self.record_path(stage)
        if not os.path.lexists(p):
            return None
        try:
            rec = StageRecord(**read_run_json(p, max_bytes=16 << 20))
            if not (isinstance(rec.inputs_hash, str) and isinstance(rec.outputs, dict)
                    and all(isinstance(k, str) and isinstance(v, str) for k, v in rec.outputs.items())
                    and isinstance(rec.info, dict)):
                raise ValueError("fields of the wrong type")
            return rec
        except (ValueError, TypeError) as exc:
            log.warning("stage record %s is corrupt (%s); stage %r will re-run", p, exc, stage)
            return None

    def _safe_output(self, stage: str, rel: str) -> Path | None:
        """``inside(root, rel)`` for a path a record names, or None (warned) if unsafe."""
        try:
            return inside(self.root, rel)
        except UnsafePathError as exc:
            log.warning("stage record %s is corrupt: %s; nothing it names outside the run "
                        "directory is touched, and stage %r will re-run",
                        self.record_path(stage), exc, stage)
            return None

    def check_record(self, stage: str, inputs_hash: str) -> tuple[StageRecord | None, str]:
        """Whether ``stage`` is up to date.

        Returns
        -------
        record, reason
            The valid record and ``""``, or ``None`` and why the stage must run.
        """
        rec = self.read_record(stage)
        if rec is None:
            return None, "no record"
        if rec.inputs_hash != inputs_hash:
            return None, "inputs changed"
        for rel, digest in rec.outputs.items():
            p = self._safe_output(stage, rel)
            if p is None:
                return None, f"unsafe path {rel!r} in its record"
            if not os.path.lexists(p):
                log.warning("stage %r: output %s is missing; re-running the stage", stage, p)
                return None, f"missing {rel}"
            if not regular_file(p):
                log.warning("stage %r: output %s is not a regular file; re-running the stage",
                            stage, p)
                return None, f"not a file {rel}"
            if file_sha256(p) != digest:
                log.warning("stage %r: output %s was modified or is corrupt (checksum differs); "
                            "re-running the stage", stage, p)
                return None, f"changed {rel}"
        return rec, ""

    def staging(self, stage: str) -> Path:
        """A fresh, empty staging directory for ``stage``."""
        d = self.path(f"{STAGING_DIR}/{stage}")
        if os.path.lexists(d):
            shutil.rmtree(d)
        d.mkdir(parents=True)
        return d

    def commit(self, stage: str, inputs_hash: str, staged: Path, elapsed_s: float,
               peak_rss_mib: float, finished_utc: str, info: dict | None = None) -> StageRecord:
        """Move every staged file into place and write the stage record (last).

        Each stage owns its outputs: a file the stage's previous record lists that this
        run did not write is removed, so a run directory never holds a stale output of
        an earlier config (fewer sample poses, no field) beside the fresh ones; unless
        another stage's record lists it now (an output that moved to another stage).
        Only paths inside the run directory are replaced or removed (:func:`inside`); a
        symbolic link on the way stops the commit naming it.
        """
        previous = self.read_record(stage)
        others = {rel for name, rec in self.records().items() if name != stage for rel in rec.outputs}
        owned = others | (set(previous.outputs) if previous is not None else set())
        files = sorted(p for p in staged.rglob("*") if regular_file(p))
        dests = {f: self.path(f.relative_to(staged).as_posix()) for f in files}
        if self.foreign:  # --force-dir: never replace a file of the user's
            for f, dest in dests.items():
                rel = f.relative_to(staged).as_posix()
                if os.path.lexists(dest) and rel not in owned:
                    raise RunDirError(f"{dest}: a file of yours where stage {stage!r} writes its "
                                      "output; --force-dir writes only the tool's own outputs: "
                                      "move it, or choose another directory")
        record = self.record_path(stage)
        if os.path.lexists(record):
            record.unlink()
        outputs = {}
        for f, dest in dests.items():
            rel = f.relative_to(staged).as_posix()
            outputs[rel] = file_sha256(f)
            dest.parent.mkdir(parents=True, exist_ok=True)
            os.replace(f, dest)
        shutil.rmtree(staged, ignore_errors=True)
        for rel in sorted(set(previous.outputs) - set(outputs) - others) if previous is not None else ():
            p = self._safe_output(stage, rel)
            if p is not None and regular_file(p):
                p.unlink(missing_ok=True)
        rec = StageRecord(stage=stage, inputs_hash=inputs_hash, outputs=outputs,
                          elapsed_s=round(elapsed_s, 3), peak_rss_mib=round(peak_rss_mib, 1),
                          finished_utc=finished_utc, info=info or {})
        atomic_write_json(self.record_path(stage), asdict(rec))
        return rec

    def discard(self, stage: str) -> None:
        """Remove a failed stage's staging directory (never through a link)."""
        try:
            d = self.path(f"{STAGING_DIR}/{stage}")
        except UnsafePathError as exc:
            log.warning("not removing the staging area: %s", exc)
            return
        shutil.rmtree(d, ignore_errors=True)

    def remove_staging_root(self) -> None:
        """Remove ``.staging/`` if nothing is left in it (after a finished run)."""
        try:
            d = self.path(STAGING_DIR)
        except UnsafePathError:
            return
        if d.is_dir() and not any(d.iterdir()):
            d.rmdir()

    def records(self) -> dict[str, StageRecord]:
        """Every readable stage record, by stage name."""
        out = {}
        d = self.path(RECORD_DIR)
        if d.is_dir():
            for p in sorted(d.glob("*.json")):
                rec = self.read_record(p.stem)
                if rec is not None:
                    out[p.stem] = rec
        return out
