"""Stage ``report``: the self-contained ``report.html`` (figures embedded, ``pipeline.report.html``)."""

from __future__ import annotations

from pipeline import runfiles
from pipeline.engine.study import Stage
from pipeline.report.html import write_report
from pipeline.runfiles import STAGE_OUTPUTS

__all__ = ["STAGE", "stage_report"]


def stage_report(ctx) -> dict:
    """Write ``report.html`` from the run directory's files."""
    write_report(ctx.store.root, out=ctx.out(runfiles.REPORT))
    return {}


STAGE = Stage("report", stage_report, (), ("figures", "evaluation"), version=2,  # each version's change: CHANGELOG.md
              description="report.html",  # runfiles: a label, not a path
              outputs=STAGE_OUTPUTS["report"])
