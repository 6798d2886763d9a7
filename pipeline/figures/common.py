"""Shared plumbing of the figure functions: run-directory inputs, Figure objects, atomic saving.

Figures use :class:`matplotlib.figure.Figure` directly (no pyplot, no global
state, Agg canvas), and are written as ``figures/<name>.png`` (120 dpi) and
``figures/<name>.pdf`` via a temporary name and :func:`os.replace`. The formats and the
resolution are a :class:`FigureOutput`, chosen for a block of code with
:func:`figure_output` (``rfidstudy figures RUN --format pdf --dpi 300``); every figure is
drawn in the project's one :data:`STYLE`, and PDF and PS files embed TrueType (Type 42)
fonts, never Type 3, which journals' checkers reject.
"""

from __future__ import annotations

import contextlib
import contextvars
from dataclasses import dataclass
from pathlib import Path

import matplotlib as mpl
import numpy as np
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure

from fuzzymodel import SensorModel
from pipeline import runfiles
from pipeline.engine.runstore import (
    UnsafePathError,
    inside,
    not_regular,
    read_run_json,
    regular_file,
)
from pipeline.evaluation.baselines import BaselineSensorModel
from pipeline.figureconfig import FIGURE_FORMATS, check_figure_output
from scenes.fileio import atomic_output

__all__ = [
    "DPI",
    "FORMATS",
    "STYLE",
    "FigureOutput",
    "figure_output",
    "MissingInput",
    "find_first",
    "load_sensor",
    "model_metrics",
    "new_figure",
    "require",
    "save_figure",
]

#: Resolution of the PNG figures (for the HTML report).
DPI = 120

#: File formats a figure can be written in.
FORMATS = FIGURE_FORMATS

#: The one style of every figure (matplotlib rc keys). TrueType (Type 42) fonts in PDF and
#: PS: Type 3 fonts, matplotlib's default, are rejected by many journals' checkers; SVG
#: keeps text as text.
STYLE = {
    "pdf.fonttype": 42,
    "ps.fonttype": 42,
    "svg.fonttype": "none",
    "font.size": 9.0,
    "axes.titlesize": 10.0,
    "axes.labelsize": 9.0,
    "xtick.labelsize": 8.0,
    "ytick.labelsize": 8.0,
    "legend.fontsize": 8.0,
    "legend.frameon": False,
    "axes.spines.top": False,
    "axes.spines.right": False,
    "axes.grid": False,  # on where it helps (dot plots); never over colour maps
    "grid.linewidth": 0.5,
    "grid.alpha": 0.35,
    "lines.linewidth": 1.2,
    "image.cmap": "viridis",
}


@dataclass(frozen=True)
class FigureOutput:
    """How figures are written."""

    formats: tuple[str, ...] = ("png", "pdf")
    """File formats, each one of :data:`FORMATS`, in the order written."""
    dpi: int = DPI
    """Resolution of raster output (PNG; rasterised parts of PDF and SVG) [dots per inch]."""
    banner: str = ""
    """A line written across the top of every figure (a smoke-scale run's warning), or ""."""

    def __post_init__(self):
        object.__setattr__(self, "formats", check_figure_output(self.formats, self.dpi, "figure "))


# the default FigureOutput is frozen: immutable, safe as a ContextVar default
_OUTPUT: contextvars.ContextVar[FigureOutput] = contextvars.ContextVar(
    "figure_output", default=FigureOutput())  # noqa: B039 (frozen dataclass: immutable)


@contextlib.contextmanager
def figure_output(output: FigureOutput | None = None):
    """Within the block, figures are written as `output` says and drawn in :data:`STYLE`.

    A context variable rather than a parameter of every figure function: the figure
    functions keep their ``f(run_dir, out_dir=None)`` form, and the setting ends with the
    block (processes forked inside it, as :func:`~pipeline.figures.draw_all` forks, inherit
    it).
    """
    token = _OUTPUT.set(output or FigureOutput())
    try:
        with mpl.rc_context(STYLE):
            yield _OUTPUT.get()
    finally:
        _OUTPUT.reset(token)


class MissingInput(FileNotFoundError):
    """A figure's input file is not in the run directory (draw_all skips the figure)."""


def require(run_dir, *relpaths: str) -> Path:
    """First existing ``run_dir / p`` among `relpaths`; MissingInput naming all of them if none.

    Only a regular file reached without a symbolic link counts
    (:func:`pipeline.engine.runstore.inside`): a figure never reads a file outside the run
    directory. A link, FIFO, folder or device there is reported like a missing input,
    naming it and what it is (:func:`pipeline.engine.runstore.not_regular`).
    """
    run_dir = Path(run_dir)
    refused = []
    for p in relpaths:
        try:
            path = inside(run_dir, p)
        except UnsafePathError as exc:
            refused.append(str(exc))
            continue
        if regular_file(path):
            return path
        why = not_regular(path)
        if why is not None:
            refused.append(why)
    if refused:
        raise MissingInput("; ".join(refused))
    raise MissingInput(f"{run_dir}: none of {list(relpaths)} exists")


def find_first(run_dir, *relpaths: str) -> Path | None:
    """Like :func:`require` but returns None."""
    try:
        return require(run_dir, *relpaths)
    except MissingInput:
        return None


def new_figure(width_in: float = 6.4, height_in: float = 4.8) -> Figure:
    """A Figure attached to an Agg canvas (headless, no pyplot state)."""
    fig = Figure(figsize=(width_in, height_in), layout="constrained")
    FigureCanvasAgg(fig)
    return fig


def save_figure(fig: Figure, out_dir, name: str) -> list[Path]:
    """Write ``out_dir/name.<format>`` for each format of the current :class:`FigureOutput`
    (default PNG at :data:`DPI` and PDF) atomically; returns the paths.

    The figure's constrained layout is solved once, at the PNG's resolution, before
    either file is drawn; the figure then has no layout engine, so neither ``savefig``
    draws the whole figure a second time to lay it out (what it does for a figure with
    an engine). The layout depends on sizes in inches and points only, so the PDF's
    axes sit where the PNG's do.
    """
    output = _OUTPUT.get()
    _solve_layout(fig, output.dpi)
    if output.banner:
        _add_banner(fig, output.banner)
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    paths = []
    # the font types are read when a file is written: Type 42 even outside figure_output
    with mpl.rc_context({k: STYLE[k] for k in ("pdf.fonttype", "ps.fonttype", "svg.fonttype")}):
        for ext in output.formats:
            path = out_dir / f"{name}.{ext}"
            with atomic_output(path) as tmp:
                fig.savefig(tmp, format=ext, dpi=output.dpi)
            paths.append(path)
    return paths


#: Height of the band a banner adds above a figure [inch].
BANNER_IN = 0.22


def _add_banner(fig: Figure, text: str) -> None:
    """A red line of text in a band added above the laid-out figure (a smoke-scale run's
    warning): the figure grows by :data:`BANNER_IN` and its axes and texts keep their
    sizes in inches, so nothing of the figure is covered."""
    w, h = fig.get_size_inches()
    scale = h / (h + BANNER_IN)
    fig.set_size_inches(w, h + BANNER_IN)
    for ax in fig.axes:
        x0, y0, ww, hh = ax.get_position().bounds
        ax.set_position([x0, y0 * scale, ww, hh * scale])
    for t in fig.texts:
        x, y = t.get_position()
        t.set_position((x, y * scale))
    for leg in fig.legends:
        box = leg.get_bbox_to_anchor().transformed(fig.transFigure.inverted())
        leg.set_bbox_to_anchor((box.x0, box.y0 * scale, box.width, box.height * scale), fig.transFigure)
    fig.text(0.5, 1.0 - 0.5 * BANNER_IN / (h + BANNER_IN), text, ha="center", va="center",
             fontsize=6.5, color="#b00020")


def _solve_layout(fig: Figure, dpi_out: int = DPI) -> None:
    """Run the figure's layout engine once at `dpi_out`, then remove the engine."""
    engine = fig.get_layout_engine()
    if engine is None:
        return
    dpi = fig.dpi
    try:
        fig.set_dpi(dpi_out)
        engine.execute(fig)
    finally:
        fig.set_dpi(dpi)
    with mpl.rc_context({"figure.autolayout": False, "figure.constrained_layout.use": False}):
        fig.set_layout_engine(None)  # keep the positions just computed


def load_sensor(run_dir, name: str = "anfis"):
    """Load a model of the run by its metrics name.

    "anfis" -> ``models/sensor.json``, "anfis_truepose" -> ``models/sensor_truepose.json``
    (``fuzzymodel.SensorModel``); "baselines" -> ``models/baselines.json``,
    "baselines_truepose" -> ``models/baselines_truepose.json``
    (:class:`pipeline.evaluation.BaselineSensorModel`). Raises MissingInput.
    """
    files = {"anfis": runfiles.SENSOR_MODEL, "anfis_truepose": runfiles.SENSOR_MODEL_TRUEPOSE,
             "baselines": runfiles.BASELINES,
             "baselines_truepose": runfiles.BASELINES_TRUEPOSE}
    if name not in files:
        raise ValueError(f"unknown model name {name!r}; known {sorted(files)}")
    path = require(run_dir, files[name])
    if name.startswith("anfis"):
        return SensorModel.load(path)

    return BaselineSensorModel.load(path)


def model_metrics(run_dir) -> dict:
    """``{model name: metrics dict}`` of the HELD-OUT scores in ``metrics.json``.

    Each model's dict has ``rssi_dbm`` and ``detection`` (``heldout.models``, None where the
    model predicts no such thing) and ``fig7`` (``fig7.<model>``); the oracle bound (the
    held-out truth's own cell means) is included under the name ``bound`` (``floor`` in
    run directories from before it). Older run directories (one ``models`` section,
    in-sample) are read as they are.
    """
    path = require(run_dir, runfiles.METRICS)
    m = read_run_json(path)
    if isinstance(m, dict) and isinstance(m.get("heldout"), dict):
        held = m["heldout"]
        out = {k: dict(v) for k, v in held.get("models", {}).items()}
        for name, f7 in (m.get("fig7") or {}).items():
            out.setdefault(name, {})["fig7"] = f7
        for key in ("bound", "floor"):
            if isinstance(held.get(key), dict):
                out[key] = {k: v for k, v in held[key].items()
                            if k in ("rssi_dbm", "detection") and isinstance(v, dict)}
        return out
    if isinstance(m, dict) and "evaluation" in m and isinstance(m["evaluation"], dict):
        m = m["evaluation"]
    if not isinstance(m, dict) or not isinstance(m.get("models"), dict):
        raise ValueError(f"{path}: no 'heldout' or 'models' section")
    return m["models"]


def finite_or_nan(v) -> float:
    """JSON null -> NaN."""
    return float("nan") if v is None else float(v)


def deg(x) -> np.ndarray:
    """Radians to degrees."""
    return np.degrees(np.asarray(x, dtype=np.float64))
