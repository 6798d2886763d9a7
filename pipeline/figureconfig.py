"""The study's ``[figures]`` section and the one check of a figure output it shares with
:class:`pipeline.figures.FigureOutput` (re-exported by :mod:`pipeline.config`; here, not
in :mod:`pipeline.figures`, so that the config loads no plotting library)."""

from __future__ import annotations

from pipeline.configschema import ConfigError, option, section

__all__ = ["FIGURE_FORMATS", "FiguresConfig", "check_figure_output"]

#: File formats a figure can be written in.
FIGURE_FORMATS = ("png", "pdf", "svg")


def check_figure_output(formats, dpi, where: str) -> tuple[str, ...]:
    """The checks of a figure output, shared by the study's ``[figures]`` and
    :class:`pipeline.figures.FigureOutput`: distinct names from :data:`FIGURE_FORMATS`
    and a resolution in [50, 1200] dpi. Returns the formats as a tuple; ValueError
    naming ``where`` (``"figures."``, ``"figure "``) and the value."""
    if isinstance(formats, str) or not all(isinstance(f, str) for f in formats):
        raise ValueError(f"{where}formats must be a list of names from "
                         f"{list(FIGURE_FORMATS)}, got {formats!r}")
    fmts = tuple(formats)
    if not fmts or len(set(fmts)) != len(fmts) or not set(fmts) <= set(FIGURE_FORMATS):
        raise ValueError(f"{where}formats must be distinct names from {list(FIGURE_FORMATS)}, "
                         f"got {list(fmts)}")
    # below 50 dpi text is unreadable; above 1200 a figure is hundreds of MB
    if isinstance(dpi, bool) or not isinstance(dpi, int) or not 50 <= dpi <= 1200:
        raise ValueError(f"{where}dpi must be an integer in [50, 1200], got {dpi!r}")
    return fmts


@section
class FiguresConfig:
    """The files the figures stage writes (pipeline.figures): every figure in each format.

    The report embeds the PNGs; PDF (TrueType fonts) and SVG are for papers. Each format
    is written from the same laid-out figure, and a PDF costs about as much as its PNG:
    a smoke study that nobody will print can write PNG alone. ``rfidstudy figures RUN
    --format pdf --dpi 300`` redraws a finished run's figures in any format."""

    formats: tuple[str, ...] = option(
        ("png", "pdf"), "File formats of every figure, from png, pdf and svg; png first "
        "(the report embeds it).")
    dpi: int = option(120, "Resolution of the PNG files [dots per inch], at least 50.", max=1200)

    def __post_init__(self):
        if not self.formats or self.formats[0] != "png":
            raise ConfigError(f"figures.formats must name png first (the report embeds it), "
                              f"got {list(self.formats)}")
        try:
            check_figure_output(self.formats, self.dpi, "figures.")
        except ValueError as exc:
            raise ConfigError(str(exc)) from None
