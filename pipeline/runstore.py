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
"""

from __future__ import annotations

import hashlib
import json
import logging
import os
import shutil
from dataclasses import asdict, dataclass, field
from pathlib import Path

from scenes.fileio import atomic_write_bytes, atomic_write_text

__all__ = [
    "RunStore",
    "StageRecord",
    "atomic_write_bytes",
    "atomic_write_json",
    "atomic_write_text",
    "file_sha256",
    "json_hash",
    "save_npz",
]

log = logging.getLogger(__name__)

RECORD_DIR = "stages"
STAGING_DIR = ".staging"


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
        """Move every staged file into place and write the stage record (last)."""
        self.record_path(stage).unlink(missing_ok=True)
        outputs = {}
        for f in sorted(p for p in staged.rglob("*") if p.is_file()):
            rel = f.relative_to(staged).as_posix()
            outputs[rel] = file_sha256(f)
            dest = self.path(rel)
            dest.parent.mkdir(parents=True, exist_ok=True)
            os.replace(f, dest)
        shutil.rmtree(staged, ignore_errors=True)
        rec = StageRecord(stage=stage, inputs_hash=inputs_hash, outputs=outputs,
                          elapsed_s=round(elapsed_s, 3), peak_rss_mib=round(peak_rss_mib, 1),
                          finished_utc=finished_utc, info=info or {})
        atomic_write_json(self.record_path(stage), asdict(rec))
        return rec

    def discard(self, stage: str) -> None:
        """Remove a failed stage's staging directory."""
        shutil.rmtree(self.root / STAGING_DIR / stage, ignore_errors=True)

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
