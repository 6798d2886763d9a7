"""``rfidstudy calibrate``: the recorded study run for its calibration (:mod:`pipeline.cli`).

The recorded study's ``calibration`` stage (:mod:`pipeline.stages.calibration`) writes
``OUT/calibration.json`` and ``OUT/calibrated.toml``; this command runs the study with
the recording and points at them. Registered on :data:`pipeline.cli.app` when that
module is imported.
"""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer

from pipeline.cli import app, run

__all__ = ["calibrate"]


@app.command()
def calibrate(
    target: Annotated[str, typer.Argument(help="Study TOML: the building, the robot and the reader.")],
    recording: Annotated[Path | None, typer.Option(help="A recording folder (reads.csv, tags.csv, "
        "poses.csv) or reads file; default: the study's [recording].")] = None,
    out: Annotated[Path, typer.Option("--out", "-o", help="Run directory.")] = Path("runs/calibration"),
    set_: Annotated[list[str] | None, typer.Option(
        "--set", "-s", help="Override a config key (repeatable).")] = None,
    progress: Annotated[bool, typer.Option(help="Show progress bars.")] = True,
):
    """Fit the simulated reader to a recording: OUT/calibration.json (each value with its
    95 % interval, held-out residuals before and after) and OUT/calibrated.toml (the study
    with the calibrated reader, for `rfidstudy run` or a placement study)."""
    if recording is None:  # the study's own [recording], or nothing to calibrate to
        from pipeline.config import ConfigError
        from pipeline.targets import resolve_target

        try:
            enabled = resolve_target(target, list(set_ or []), None).recording.enabled
        except ConfigError as exc:
            typer.echo(f"error: {exc}", err=True)
            raise typer.Exit(2) from None
        if not enabled:
            typer.echo(f"error: {target}: no recording to calibrate to: give --recording or a "
                       "[recording] section (docs/recordings.md)", err=True)
            raise typer.Exit(2)
    run(target=target, out=out, set_=set_, recording=recording, progress=progress)
    typer.echo(f"calibration: {out / 'calibration.json'}\ncalibrated study: {out / 'calibrated.toml'}")
