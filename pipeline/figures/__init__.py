"""Figures from a run directory's files alone: one function per figure, PNG + PDF each.

Every ``fig_*(run_dir, out_dir=None) -> list[Path]`` reads only files in
`run_dir` (see each module's doc for the exact files) and writes
``<out_dir or run_dir/figures>/<name>.png`` and ``.pdf`` atomically; it raises
:class:`MissingInput` when an input is absent, which :func:`draw_all` turns
into a logged warning. No statistics are computed here: model surfaces are
evaluated from the saved models, errors come from :mod:`pipeline.evaluation`.
:func:`draw_all` draws the figures side by side in forked processes, one per CPU
(in this process where another thread runs), and each figure's layout is solved once
for both its files (:func:`pipeline.figures.common.save_figure`).
"""

from pipeline.figures.common import DPI, STYLE, FigureOutput, MissingInput, figure_output
from pipeline.figures.comparison import fig_fig7_error, fig_rho_vs_truth
from pipeline.figures.downstream import fig_downstream
from pipeline.figures.drawall import FIGURES, draw_all, run_figure_output
from pipeline.figures.headline import fig_baselines
from pipeline.figures.scene import fig_fields, fig_mcl_error, fig_scene_top_view, scene_top_view
from pipeline.figures.sites import fig_site_errors
from pipeline.figures.surfaces import (
    fig_learned_vs_truth_detection,
    fig_learned_vs_truth_rssi,
    fig_ssm_surface,
    fig_tdm_surface,
)

__all__ = [
    "DPI",
    "FIGURES",
    "STYLE",
    "FigureOutput",
    "MissingInput",
    "draw_all",
    "figure_output",
    "fig_baselines",
    "fig_downstream",
    "fig_fields",
    "fig_fig7_error",
    "fig_learned_vs_truth_detection",
    "fig_learned_vs_truth_rssi",
    "fig_mcl_error",
    "fig_rho_vs_truth",
    "fig_scene_top_view",
    "fig_site_errors",
    "fig_ssm_surface",
    "fig_tdm_surface",
    "run_figure_output",
    "scene_top_view",
]
