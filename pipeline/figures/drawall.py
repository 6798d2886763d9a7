"""Every figure of a run directory, skipping those whose inputs are missing."""

from __future__ import annotations

import logging
from pathlib import Path

from pipeline import runfiles
from pipeline.configschema import ConfigError, from_dict
from pipeline.engine.runstore import inside, read_run_text, regular_file
from pipeline.figureconfig import FiguresConfig
from pipeline.figures.common import FigureOutput, MissingInput, figure_output
from pipeline.figures.comparison import fig_fig7_error, fig_rho_vs_truth
from pipeline.figures.downstream import fig_downstream
from pipeline.figures.headline import fig_baselines
from pipeline.figures.scene import fig_fields, fig_mcl_error, fig_scene_top_view
from pipeline.figures.sites import fig_site_errors
from pipeline.figures.surfaces import (
    fig_learned_vs_truth_detection,
    fig_learned_vs_truth_rssi,
    fig_ssm_surface,
    fig_tdm_surface,
)
from pipeline.parallel import map_forked
from pipeline.report.recorded import draw_sim_vs_real
from pipeline.report.smokescale import smoke_banner
from pipeline.runpaths import not_regular

__all__ = ["FIGURES", "draw_all", "run_figure_output"]

log = logging.getLogger(__name__)

#: name -> figure function ``f(run_dir, out_dir=None) -> list[Path]``.
FIGURES = {
    "ssm_surface": fig_ssm_surface,
    "tdm_surface": fig_tdm_surface,
    "rho_vs_truth": fig_rho_vs_truth,
    "fig7_error": fig_fig7_error,
    "learned_vs_truth_rssi": fig_learned_vs_truth_rssi,
    "learned_vs_truth_detection": fig_learned_vs_truth_detection,
    "scene_top_view": fig_scene_top_view,
    "fields": fig_fields,
    "mcl_error": fig_mcl_error,
    "baselines": fig_baselines,
    "site_errors": fig_site_errors,
    "downstream": fig_downstream,
}


def _draw_one(name: str, run_dir: Path, out_dir: Path) -> tuple[list[Path], str | None]:
    """One figure: its files, or none and why (its input is missing)."""
    try:
        return list(FIGURES[name](run_dir, out_dir)), None
    except MissingInput as exc:
        return [], str(exc)


def _run_banner(run_dir: Path) -> str:
    """The smoke-scale banner of a run (:mod:`pipeline.report.smokescale`) from its config.toml."""
    import tomllib


    path = run_dir / "config.toml"
    if not regular_file(path):  # a link or a FIFO: the report names it
        return ""
    try:
        return smoke_banner(tomllib.loads(read_run_text(path)))
    except (ValueError, tomllib.TOMLDecodeError):
        return ""


def run_figure_output(run_dir) -> FigureOutput:
    """The formats and resolution a run's figures stage draws in: the ``[figures]`` of
    its config.toml (:class:`pipeline.config.FiguresConfig`), or PNG and PDF at 120 dpi
    where it has none (a run of a version before that section, or no config.toml).

    Raises
    ------
    ValueError
        config.toml is not TOML, or its ``[figures]`` names no valid output (the file
        named): a redraw into the study's own ``figures/`` must not write other files
        than the stage's.
    """
    import tomllib

    path = Path(run_dir) / "config.toml"
    if not regular_file(path):  # absent, or a link or a FIFO (the report names it)
        return FigureOutput()
    try:
        data = tomllib.loads(read_run_text(path))
    except tomllib.TOMLDecodeError as exc:  # worded as the report words it
        raise ValueError(f"{path}: not a valid TOML file: {exc}") from None
    try:  # read as the study reads it (keys, types, ranges, PNG first)
        fig = from_dict(FiguresConfig, data.get("figures", {}), source=str(path),
                        prefix="figures")
    except ConfigError as exc:
        detail = str(exc).removeprefix(f"{path}: ")
        raise ValueError(f"{path}: [figures] gives no figure output: {detail}") from exc
    return FigureOutput(formats=fig.formats, dpi=fig.dpi)


def _draw_recorded(run_dir: Path, out_dir: Path, output) -> list[Path]:
    """A recorded study's figures (:func:`pipeline.report.recorded.draw_sim_vs_real`):
    ``sim_vs_real_rssi`` and ``sim_vs_real_residual``, in each of ``output.formats``."""
    import matplotlib.pyplot as plt
    import pandas as pd


    links, tags = inside(run_dir, runfiles.SIM_VS_REAL.format(name="links.parquet")), inside(run_dir, runfiles.SCENE_TAGS)
    for p in (links, tags):  # a link or a FIFO in a stranger's run is refused, never followed
        why = not_regular(p)
        if why:
            raise ValueError(why)
    if not (links.is_file() and tags.is_file()):
        log.warning("recorded study without sim_vs_real/links.parquet: no figures")
        return []
    out_dir.mkdir(parents=True, exist_ok=True)
    written = []
    figs = draw_sim_vs_real(pd.read_parquet(links), pd.read_parquet(tags))
    for fig, name in zip(figs, ("sim_vs_real_rssi", "sim_vs_real_residual"), strict=True):
        for fmt in output.formats:
            path = out_dir / f"{name}.{fmt}"
            fig.savefig(path, dpi=output.dpi, bbox_inches="tight")
            written.append(path)
        plt.close(fig)
    return written


def draw_all(run_dir, out_dir=None, names=None, workers: int | None = None,
             output: FigureOutput | None = None) -> list[Path]:
    """Draw every figure (or those in `names`) from the run directory's files.

    Parameters
    ----------
    run_dir : path
        The run directory (read only).
    out_dir : path, optional
        Where to write; default ``run_dir/figures``.
    names : iterable of str, optional
        Subset of :data:`FIGURES`.
    workers : int, optional
        Processes drawing figures side by side (forked from this one,
        :func:`pipeline.parallel.map_forked`; every figure is independent and its bytes
        do not depend on where it is drawn). Default: one per CPU, or 1 (draw in this
        process) where forking is not safe.
    output : FigureOutput, optional
        Formats and resolution; default the run's own (:func:`run_figure_output`: its
        config's ``[figures]``, else PNG at 120 dpi and PDF).

    Returns
    -------
    list of pathlib.Path
        The PNG and PDF files written, in the order of `names`. A figure whose input
        files are missing is skipped with a logged warning naming them; other errors
        propagate.
    """
    run_dir = Path(run_dir)
    if not run_dir.is_dir():
        raise FileNotFoundError(f"run directory {run_dir} does not exist")
    out_dir = Path(out_dir) if out_dir is not None else run_dir / "figures"
    if output is None:
        output = run_figure_output(run_dir)
    if (run_dir / runfiles.RECORDING_IMPORT).is_file():  # a recorded study's own figures
        return _draw_recorded(run_dir, out_dir, output)
    names = list(FIGURES) if names is None else list(names)
    unknown = sorted(set(names) - set(FIGURES))
    if unknown:
        raise ValueError(f"unknown figure(s) {unknown}; known {sorted(FIGURES)}")
    banner = _run_banner(run_dir)
    if banner:
        import dataclasses

        output = dataclasses.replace(output, banner=banner)
    with figure_output(output):
        results = map_forked(lambda i: _draw_one(names[i], run_dir, out_dir), len(names),
                             workers)
    written: list[Path] = []
    for name, (paths, missing) in zip(names, results, strict=True):
        if missing is not None:
            # a stage switched off in the config wrote nothing: its figures are skipped
            # quietly; a missing file of a stage that ran is worth a warning
            off = name == "downstream" and not (run_dir / "downstream").is_dir()
            log.log(logging.INFO if off else logging.WARNING, "figure %s skipped: %s", name,
                    missing)
        written.extend(paths)
    return written
