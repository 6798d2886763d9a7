"""What the command-line modules share: the one-line errors (:mod:`pipeline.apps.cli`,
:mod:`pipeline.apps.cliscenes`)."""

from __future__ import annotations

import errno

import typer

from pipeline.engine.runstore import final_name

__all__ = ["WRITE_ERRNOS", "fail", "fail_os"]


def fail(msg: str, code: int = 2):
    """``error: msg`` on stderr, exit ``code``."""
    typer.echo(f"error: {msg}", err=True)
    raise typer.Exit(code)


def fail_os(exc: OSError, what: str, code: int = 2):
    """One line for a file-system error (read-only, permissions, a file for a folder)."""
    where = final_name(exc.filename) if exc.filename is not None else what
    fail(f"cannot write {where}: {exc.strerror or exc}", code)


#: File-system errors a command reports in one line (:func:`fail_os`), not as a traceback.
WRITE_ERRNOS = {errno.EROFS, errno.EACCES, errno.EPERM, errno.ENOSPC, errno.EDQUOT,
                 errno.ENOTDIR, errno.EISDIR, errno.EEXIST}
