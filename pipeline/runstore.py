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

A directory is a run directory when it holds ``stages/`` or ``manifest.json``;
:func:`open_run_dir` refuses a path that is a file, and a non-empty directory that is
not a run directory (unless told otherwise), with a :class:`RunDirError` naming it.
"""

from __future__ import annotations

import errno
import hashlib
import json
import logging
import os
import re
import shutil
from dataclasses import asdict, dataclass, field
from pathlib import Path

from scenes.fileio import atomic_write_bytes, atomic_write_text

__all__ = [
    "RunDirError",
    "RunStore",
    "StageRecord",
    "atomic_write_bytes",
    "atomic_write_json",
    "atomic_write_text",
    "file_sha256",
    "final_name",
    "json_hash",
    "open_run_dir",
    "save_npz",
    "write_error",
]

log = logging.getLogger(__name__)

RECORD_DIR = "stages"
STAGING_DIR = ".staging"
MANIFEST = "manifest.json"

#: errno values of a run directory that cannot be written (read-only mount, permissions,
#: full disk, a file where a folder should be).
WRITE_ERRNOS = frozenset({errno.EROFS, errno.EACCES, errno.EPERM, errno.ENOSPC, errno.EDQUOT,
                          errno.ENOTDIR, errno.EISDIR, errno.EEXIST})


class RunDirError(RuntimeError):
    """The run directory cannot be used: a file, not a run directory, not writable.

    The message is one line naming the directory (or file) and the cause.
    """


_TEMP_NAME = re.compile(r"^\.(?P<name>.+)\.[^.]+\.tmp(?:\.[A-Za-z0-9]+)?$")


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


def is_run_dir(root: str | Path) -> bool:
    """Whether ``root`` holds this tool's ``stages/`` records or ``manifest.json``."""
    root = Path(root)
    return (root / RECORD_DIR).is_dir() or (root / MANIFEST).is_file()


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
        ``root`` is a file (or lies under one); it is a non-empty directory without
        ``stages/`` or ``manifest.json`` and ``force_dir`` is false; it cannot be created.
    """
    path = Path(root).expanduser()
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
                f"stages/, no {MANIFEST}): choose another directory, or pass --force-dir "
                "(force_dir=True) to run into it")
    try:
        return RunStore(path)
    except OSError as exc:
        err = write_error(exc, path)
        if err is None:
            raise
        raise err from None


def file_sha256(path: str | Path) -> str:
    """SHA-256 hex digest of a file's bytes."""
    h = hashlib.sha256()
    with open(path, "rb") as fh:
        for chunk in iter(lambda: fh.read(1 << 20), b""):
            h.update(chunk)
    return h.hexdigest()


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

    Parameters
    ----------
    root : path
        The run directory (created if missing).
    """

    def __init__(self, root: str | Path):
        self.root = Path(root).resolve()
        self.root.mkdir(parents=True, exist_ok=True)

    def path(self, rel: str) -> Path:
        """Absolute path of a run-directory file."""
        return self.root / rel

    def record_path(self, stage: str) -> Path:
        """Path of a stage record."""
        return self.root / RECORD_DIR / f"{stage}.json"

    def read_record(self, stage: str) -> StageRecord | None:
        """The stage's record, or ``None`` if absent or unreadable (with a warning)."""
        p = self.record_path(stage)
        if not p.exists():
            return None
        try:
            data = json.loads(p.read_text(encoding="utf-8"))
            return StageRecord(**data)
        except (OSError, ValueError, TypeError) as exc:
            log.warning("stage record %s is corrupt (%s); stage %r will re-run", p, exc, stage)
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
            p = self.path(rel)
            if not p.exists():
                log.warning("stage %r: output %s is missing; re-running the stage", stage, p)
                return None, f"missing {rel}"
            if file_sha256(p) != digest:
                log.warning("stage %r: output %s was modified or is corrupt (checksum differs); "
                            "re-running the stage", stage, p)
                return None, f"changed {rel}"
        return rec, ""

    def staging(self, stage: str) -> Path:
        """A fresh, empty staging directory for ``stage``."""
        d = self.root / STAGING_DIR / stage
        if d.exists():
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
        """
        previous = self.read_record(stage)
        others = {rel for name, rec in self.records().items() if name != stage for rel in rec.outputs}
        self.record_path(stage).unlink(missing_ok=True)
        outputs = {}
        for f in sorted(p for p in staged.rglob("*") if p.is_file()):
            rel = f.relative_to(staged).as_posix()
            outputs[rel] = file_sha256(f)
            dest = self.path(rel)
            dest.parent.mkdir(parents=True, exist_ok=True)
            os.replace(f, dest)
        shutil.rmtree(staged, ignore_errors=True)
        for rel in sorted(set(previous.outputs) - set(outputs) - others) if previous is not None else ():
            self.path(rel).unlink(missing_ok=True)
        rec = StageRecord(stage=stage, inputs_hash=inputs_hash, outputs=outputs,
                          elapsed_s=round(elapsed_s, 3), peak_rss_mib=round(peak_rss_mib, 1),
                          finished_utc=finished_utc, info=info or {})
        atomic_write_json(self.record_path(stage), asdict(rec))
        return rec

    def discard(self, stage: str) -> None:
        """Remove a failed stage's staging directory."""
        shutil.rmtree(self.root / STAGING_DIR / stage, ignore_errors=True)

    def remove_staging_root(self) -> None:
        """Remove ``.staging/`` if nothing is left in it (after a finished run)."""
        d = self.root / STAGING_DIR
        if d.is_dir() and not any(d.iterdir()):
            d.rmdir()

    def records(self) -> dict[str, StageRecord]:
        """Every readable stage record, by stage name."""
        out = {}
        d = self.root / RECORD_DIR
        if d.is_dir():
            for p in sorted(d.glob("*.json")):
                rec = self.read_record(p.stem)
                if rec is not None:
                    out[p.stem] = rec
        return out
