"""Stage ``figures``: every figure from the run directory's files alone
(``pipeline.figures``); writes ``figures/<name>.<format>`` for each of the study's
``figures.formats`` (PNG and PDF by default)."""

from __future__ import annotations

from pathlib import Path

from pipeline.engine.study import Stage
from pipeline.figures import draw_all, scene_top_view
from pipeline.figures.common import FigureOutput, figure_output
from pipeline.runfiles import STAGE_OUTPUTS

__all__ = ["STAGE", "draw_figures", "draw_scene_top_view", "stage_figures"]


def draw_figures(run_dir: str | Path, out_dir: str | Path,
                 output: FigureOutput | None = None) -> list[Path]:
    """Every figure of a run, from the run directory's files alone (pipeline.figures.draw_all).

    Parameters
    ----------
    run_dir, out_dir : path
    output : FigureOutput, optional
        Formats and resolution (default: the run's own, :func:`pipeline.figures.run_figure_output`).

    Returns
    -------
    list of pathlib.Path
        Files written under ``out_dir``.
    """
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    return draw_all(Path(run_dir), out_dir=out, output=output)


def draw_scene_top_view(scene, png: str | Path) -> Path:
    """Top view of a scene (walls at laser height, tags, route) as PNG, via
    pipeline.figures: the one file named, nothing beside it (a PDF of the same name
    there would be someone's file)."""
    png = Path(png)
    png.parent.mkdir(parents=True, exist_ok=True)
    with figure_output(FigureOutput(formats=("png",))):
        return Path(scene_top_view(scene, png))


def stage_figures(ctx) -> dict:
    """Draw every figure into the stage's staging area, in the study's formats."""
    fig = ctx.config.figures
    paths = draw_figures(ctx.store.root, ctx.staging_dir / "figures",
                         FigureOutput(formats=fig.formats, dpi=fig.dpi))
    return {"n_files": len(paths)}


STAGE = Stage("figures", stage_figures, ("figures",), ("scene", "tour", "reads", "truth_traces", "models", "truth",
                                                        "evaluation"),
              version=2,  # each version's change: CHANGELOG.md
              description="figures",
              outputs=STAGE_OUTPUTS["figures"])
