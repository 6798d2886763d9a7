"""Folders a command writes into that are not run directories: whose they are.

``rfidstudy figures RUN --out DIR`` and ``rfidstudy compare RUNS --out DIR`` write files
with fixed names (``baselines.pdf``, ``compare.csv``) into a folder the user names. As
``git`` never overwrites an untracked file, the tool never overwrites a file it did not
write: a folder is the tool's when it is new or empty, or when it holds the marker
:data:`MARK` the tool wrote there, with its kind and the files it wrote. In a folder of
the tool's, a file of the user's (one the marker does not list) under a name the
command would write stops the command, naming it.

A folder inside a run directory (its root, ``figures/``, ``stages/``) is never an
output folder of another command: that run's own stages and report own it.
"""

from __future__ import annotations

import json
from pathlib import Path

from pipeline.config import ConfigError
from pipeline.runpaths import is_run_dir, json_dict, not_regular
from pipeline.runpaths import tool_marker as own_marker
from scenes.fileio import atomic_write_text

__all__ = ["MARK", "check_marker_file", "check_output_dir", "mark_output_dir", "own_marker"]

#: The marker file of an output folder (JSON: tool, kind, files written).
MARK = ".rfidstudy-output.json"


def _marker(out: Path) -> dict | None:
    d = json_dict(out / MARK, max_bytes=1 << 20)
    return d if d is not None and d.get("tool") == "rfidstudy" else None


def check_marker_file(out: str | Path, name: str) -> None:
    """Stop unless ``out/name`` (a marker: ``placement.json``, ``sweep.json``) is missing
    or a regular file: a symbolic link there is never followed to decide whose the folder
    is, and a FIFO is never opened.

    Raises
    ------
    ConfigError
        ``--out <out>: <out/name>: a symbolic link, not followed ...`` or ``... not a
        regular file (a FIFO) ...`` (:func:`pipeline.runpaths.not_regular`).
    """
    why = not_regular(Path(out) / name)
    if why is not None:
        raise ConfigError(f"--out {out}: {why}; the folder is not used")


def check_output_dir(out: str | Path, kind: str, names=()) -> Path:
    """The resolved output folder, or a :class:`ConfigError` naming why the command may
    not write there.

    Parameters
    ----------
    out : path
        The folder (created later by the command if missing).
    kind : str
        What writes it (``"figures"``, ``"compare"``): a folder of another kind is refused.
    names : iterable of str
        File names the command will write: in a folder of the tool's, one of them present
        but not listed in the marker is the user's file, and is refused.

    Raises
    ------
    ConfigError
        ``out`` is a file; cannot be resolved (a link loop); lies in a run directory; is
        a non-empty folder without the tool's marker, or with another kind's; holds a
        user's file under a name in ``names``.
    """
    out = Path(out)
    try:
        res = out.resolve()
        if out.exists() and not out.is_dir():
            raise ConfigError(f"--out {out}: a file, not a folder")
        entries = sorted(p.name for p in out.iterdir()) if out.is_dir() else []
    except (OSError, RuntimeError) as exc:  # ELOOP, no permission
        raise ConfigError(f"--out {out}: cannot be used ({getattr(exc, 'strerror', None) or exc})") from None
    for d in (res, *res.parents):
        if d.is_dir() and is_run_dir(d):
            raise ConfigError(f"--out {out}: inside the run directory {d}; write elsewhere (a "
                              "run's folders are its stages' and its report's)")
    if not entries:
        return res
    check_marker_file(out, MARK)
    mark = _marker(out)
    if mark is None:
        shown = ", ".join(entries[:3]) + (", ..." if len(entries) > 3 else "")
        raise ConfigError(f"--out {out}: not empty ({shown}) and not a {kind} folder of "
                          "rfidstudy: choose a new or empty folder (nothing of yours is "
                          "overwritten)")
    if mark.get("kind") != kind:
        raise ConfigError(f"--out {out}: a {mark.get('kind')} folder of rfidstudy, not a "
                          f"{kind} folder: choose another")
    ours = set(mark.get("files") or [])
    theirs = sorted(n for n in names if n in entries and n not in ours)
    if theirs:
        raise ConfigError(f"--out {out}: {theirs[0]} is not a file rfidstudy wrote there; move "
                          "it, or choose another folder")
    return res


def mark_output_dir(out: str | Path, kind: str, files) -> Path:
    """Write (or extend) the folder's marker with the ``files`` just written there."""
    out = Path(out)
    mark = _marker(out) or {"tool": "rfidstudy", "kind": kind, "files": []}
    names = sorted(set(mark.get("files") or []) | {Path(f).name for f in files})
    mark.update(tool="rfidstudy", kind=kind, files=names)
    return atomic_write_text(out / MARK, json.dumps(mark, indent=1) + "\n")
