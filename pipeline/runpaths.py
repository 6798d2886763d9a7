"""Reading a run directory that may come from someone else: containment and checked reads.

Nothing in a run directory is trusted to point elsewhere. :func:`inside` turns a
relative path of the run directory into a path that stays inside it (relative, no
``..``, no component a symbolic link: a link is never followed); :func:`regular_file`,
:func:`run_files`, :func:`read_run_json`, :func:`read_run_text` and :func:`file_sha256`
read or hash regular files only (a FIFO or device would hang or leak): checked by
``lstat`` before they are opened (:func:`not_regular` names what is there instead),
opened without following a final link and checked again on the descriptor they read.
A path that fails raises :class:`UnsafePathError`, naming it. :mod:`pipeline.engine.runstore`
builds the run directory's writes on these and re-exports them.
"""

from __future__ import annotations

import errno
import hashlib
import json
import logging
import os
import stat
from pathlib import Path

__all__ = ["MANIFEST", "RECORD_DIR", "RUN_KIND", "TOOL", "RunDirError", "is_run_dir", "UnsafePathError", "file_sha256", "inside", "json_dict", "not_regular",
           "read_run_json", "read_run_text", "regular_file", "run_files", "tool_marker"]

log = logging.getLogger(__name__)


class RunDirError(RuntimeError):
    """The run directory cannot be used: a file, not a run directory, not writable.

    The message is one line naming the directory (or file) and the cause.
    """


class UnsafePathError(RunDirError):
    """A path in a run directory leads outside it (``..``, absolute, a symbolic link) or
    is not a regular file: the store refuses to read, write or delete through it."""


def inside(root: str | Path, rel: str) -> Path:
    """The path of run-directory entry ``rel``, checked to stay inside ``root``.

    Parameters
    ----------
    root : path
        The run directory (already resolved: its own path may pass through links the
        user chose).
    rel : str
        A relative POSIX path, as stage records store them.

    Returns
    -------
    Path
        ``root / rel``; no component of ``rel`` that exists is a symbolic link.

    Raises
    ------
    UnsafePathError
        ``rel`` is not a string, is empty, absolute, holds ``..`` or a NUL, or one of its
        existing components is a symbolic link (named).
    """
    root = Path(root)
    if not isinstance(rel, str) or not rel or "\x00" in rel:
        raise UnsafePathError(f"{root}: {rel!r} is not a relative path of the run directory")
    parts = rel.split("/")
    if rel.startswith("/") or os.path.isabs(rel) or any(p in ("", ".", "..") for p in parts):
        raise UnsafePathError(f"{root}: {rel!r} leads outside the run directory (absolute, "
                              "'..' or empty components are refused)")
    here = root
    for part in parts:
        here = here / part
        try:
            st = os.lstat(here)
        except FileNotFoundError:
            break  # the rest does not exist yet: nothing there to follow
        except OSError as exc:
            raise UnsafePathError(f"{here}: cannot be inspected ({exc.strerror})") from None
        if stat.S_ISLNK(st.st_mode):
            raise UnsafePathError(f"{here} is a symbolic link inside the run directory {root}: "
                                  "rfidstudy never follows links there; remove it (or copy "
                                  "the real files in its place) and rerun")
    return root / rel


def regular_file(path: str | Path) -> bool:
    """Whether ``path`` is a regular file (not a link, FIFO, device, socket or folder)."""
    try:
        return stat.S_ISREG(os.lstat(path).st_mode)
    except OSError:
        return False


_KINDS = ((stat.S_ISFIFO, "a FIFO"), (stat.S_ISDIR, "a folder"), (stat.S_ISCHR, "a device"),
          (stat.S_ISBLK, "a device"), (stat.S_ISSOCK, "a socket"))


def not_regular(path: str | Path) -> str | None:
    """Why ``path`` may not be read as a run-directory file, or None (a regular file, or
    nothing there): a message naming it, from ``lstat`` alone (nothing is opened: a FIFO
    would wait for a writer, a device may act on being opened).

    Returns
    -------
    str or None
        ``"<path>: a symbolic link ..."``, ``"<path>: not a regular file (a FIFO)"`` (a
        folder, a device, a socket), ``"<path>: cannot be inspected (...)"``, or None.
    """
    try:
        mode = os.lstat(path).st_mode
    except FileNotFoundError:
        return None
    except OSError as exc:
        return f"{path}: cannot be inspected ({exc.strerror or type(exc).__name__})"
    if stat.S_ISREG(mode):
        return None
    if stat.S_ISLNK(mode):
        return (f"{path}: a symbolic link, not followed (rfidstudy never reads through links in "
                "its folders; put the real file in its place)")
    kind = next((k for test, k in _KINDS if test(mode)), "a special file")
    return f"{path}: not a regular file ({kind}): not read"


def run_files(root: str | Path, folder: str, pattern: str) -> list[Path]:
    """The regular files of run-directory ``folder`` matching ``pattern``, sorted.

    For readers that list a folder instead of a record: ``folder`` is checked by
    :func:`inside` (a linked folder raises :class:`UnsafePathError`), and a link, FIFO or
    device among the matches is left out with a warning, never read.
    """
    d = inside(root, folder)
    if not d.is_dir():
        return []
    out = []
    for p in sorted(d.glob(pattern)):
        if regular_file(p):
            out.append(p)
        else:
            log.warning("%s is not a regular file (a link?): not read", p)
    return out


def _open_regular(path: str | Path):
    """A binary file object of ``path``, checked by ``lstat`` before it is opened
    (:func:`not_regular`: a FIFO, a device or a link is never opened), then opened
    without following a final link and without blocking and checked again on the
    descriptor it reads (the file cannot be swapped for a FIFO or a link in between).

    Raises
    ------
    UnsafePathError
        ``path`` is a link or not a regular file (the message names it and what it is).
    FileNotFoundError
        Nothing is there.
    """
    why = not_regular(path)
    if why is not None:
        raise UnsafePathError(why)
    try:
        fd = os.open(path, os.O_RDONLY | getattr(os, "O_NOFOLLOW", 0) | getattr(os, "O_NONBLOCK", 0))
    except OSError as exc:
        if exc.errno == errno.ELOOP:  # made a link since the lstat
            raise UnsafePathError(not_regular(path) or f"{path}: a symbolic link, not followed") from None
        raise
    if not stat.S_ISREG(os.fstat(fd).st_mode):
        os.close(fd)
        raise UnsafePathError(not_regular(path) or f"{path}: not a regular file: not read")
    return os.fdopen(fd, "rb")


def read_run_text(path: str | Path, max_bytes: int = 16 << 20) -> str:
    """The UTF-8 text of a run-directory file (``config.toml``), read as from a stranger.

    Parameters
    ----------
    path : path
        The file (a regular file; a link or special file is refused unopened).
    max_bytes : int
        Largest size read [bytes].

    Raises
    ------
    ValueError
        One line naming the file: a link, not a regular file (a FIFO, a folder, a
        device), missing, unreadable, larger than ``max_bytes``, or not UTF-8.
    """
    try:
        with _open_regular(path) as fh:
            data = fh.read(max_bytes + 1)
    except RunDirError as exc:
        raise ValueError(str(exc)) from None
    except OSError as exc:
        raise ValueError(f"{path}: cannot be read ({exc.strerror or type(exc).__name__})") from None
    if len(data) > max_bytes:
        raise ValueError(f"{path}: larger than {max_bytes >> 20} MiB: not read")
    try:
        return data.decode("utf-8")
    except UnicodeDecodeError:
        raise ValueError(f"{path}: not UTF-8 text") from None


def read_run_json(path: str | Path, max_bytes: int = 64 << 20):
    """The JSON document of a run-directory file, read as data from a stranger.

    Parameters
    ----------
    path : path
        The file (a regular file; a link or special file is refused).
    max_bytes : int
        Largest size read [bytes].

    Raises
    ------
    ValueError
        Naming the file: not a regular file (or a link), larger than ``max_bytes``, not
        UTF-8 JSON, or nested too deeply to parse.
    """
    try:
        with _open_regular(path) as fh:
            data = fh.read(max_bytes + 1)
        if len(data) > max_bytes:
            raise ValueError(f"larger than {max_bytes >> 20} MiB")
        return json.loads(data.decode("utf-8"))
    except RunDirError as exc:  # a link or a special file: the message names it
        raise ValueError(str(exc)) from None
    except (OSError, ValueError, RecursionError) as exc:
        raise ValueError(f"{path}: cannot read JSON: {exc}") from None


def file_sha256(path: str | Path) -> str:
    """SHA-256 hex digest of a file's bytes (opened without following a final link)."""
    h = hashlib.sha256()
    with _open_regular(path) as fh:
        for chunk in iter(lambda: fh.read(1 << 20), b""):
            h.update(chunk)
    return h.hexdigest()


def json_dict(path: str | Path, max_bytes: int = 64 << 20) -> dict | None:
    """The JSON object of a regular file (:func:`read_run_json`), or None: missing, a
    link, unreadable, not JSON, or not an object."""
    if not regular_file(path):
        return None
    try:
        d = read_run_json(path, max_bytes=max_bytes)
    except (OSError, ValueError):
        return None
    return d if isinstance(d, dict) else None


def tool_marker(path: str | Path, kind: str, legacy_keys=(), max_bytes: int = 64 << 20) -> bool:
    """Whether ``path`` is a marker this tool wrote for a folder of ``kind``: its JSON
    object says ``"tool": "rfidstudy"`` and ``"kind": kind``, or, written before markers
    said so, holds every key of ``legacy_keys``. A user's file of the same name (a
    ``manifest.json`` of a web app, a ``sweep.json`` of their own) is not."""
    d = json_dict(path, max_bytes)
    if d is None:
        return False
    if d.get("tool") == "rfidstudy":
        return d.get("kind") == kind
    return bool(legacy_keys) and set(legacy_keys) <= set(d)


#: The folder of a run directory holding its stage records, and its manifest file.
RECORD_DIR = "stages"
MANIFEST = "manifest.json"

#: What ``manifest.json`` says to mark a run directory as this tool's (``"tool"``, ``"kind"``).
TOOL, RUN_KIND = "rfidstudy", "run"
#: The keys of a manifest written before it carried ``"tool"`` (all of them present).
_LEGACY_MANIFEST_KEYS = frozenset({"command_line", "started_utc", "status", "stages", "files"})


def is_run_dir(root: str | Path) -> bool:
    """Whether ``root`` is a run directory of this tool: its ``manifest.json`` (a regular
    file; a link does not count) says ``"tool": "rfidstudy"`` and ``"kind": "run"`` (or is
    an older run's, with every key of :data:`_LEGACY_MANIFEST_KEYS`), or, the manifest
    damaged, ``stages/`` holds a stage record of this tool (``stage``, ``inputs_hash``,
    ``outputs``). A folder with someone's ``manifest.json`` (a web app's) or an empty
    ``stages/`` is not a run directory, so no command writes into it as if it were."""
    root = Path(root)
    man = json_dict(root / MANIFEST, max_bytes=16 << 20)
    if man is not None and man.get("tool") == TOOL:  # another kind of the tool's: not a run
        return man.get("kind") == RUN_KIND
    if tool_marker(root / MANIFEST, RUN_KIND, _LEGACY_MANIFEST_KEYS, max_bytes=16 << 20):
        return True
    try:
        records = run_files(root, RECORD_DIR, "*.json")
    except (OSError, RunDirError):
        return False
    for rec in records[:50]:
        try:
            d = read_run_json(rec, max_bytes=1 << 20)
        except (OSError, ValueError):
            continue
        if isinstance(d, dict) and {"stage", "inputs_hash", "outputs"} <= set(d):
            return True
    return False
