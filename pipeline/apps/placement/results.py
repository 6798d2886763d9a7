"""What a placement directory holds and the answer's shared pieces: the candidates'
run directories, which of them the ranking may use, the tag-height bands, the ranked
table and :class:`PlacementResult`.

The lowest module of the placement package's outputs: :mod:`.runner`,
:mod:`.optimise`, :mod:`.summary`, :mod:`.figures` and :mod:`.report` import from
here, and it imports none of them (the package flows one way: runner ->
optimise / summary -> figures / report).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import pandas as pd

from pipeline.apps.placement.objectives import OBJECTIVES
from pipeline.engine.runstore import inside, read_run_json, regular_file
from pipeline.runpaths import RECORD_DIR
from pipeline.stages import stage_names

__all__ = ["PlacementResult", "band_key", "candidate_dir", "complete_dirs", "height_bands",
           "ranking_table", "usable_run"]


@dataclass
class PlacementResult:
    """Outcome of :func:`~.runner.run_placement`.

    Attributes
    ----------
    out_dir : pathlib.Path
    summary : pandas.DataFrame
        One row per candidate (:func:`pipeline.apps.placement.summary.summarise`).
    answer : dict
        Recommendation, margin to the runner-up and its verdict, Pareto front.
    files : list of pathlib.Path
    """

    out_dir: Path
    summary: object
    answer: dict
    files: list = field(default_factory=list)


def candidate_dir(out: Path, name: str, k: int) -> Path:
    """``out/candidates/<name>/<k>``, checked to stay inside ``out`` without passing a
    symbolic link (:func:`pipeline.engine.runstore.inside`): a link planted in a placement
    directory never leads a study's writes, or the summary's reads, elsewhere."""
    return inside(out, f"candidates/{name}/{int(k)}")


def usable_run(run: Path, required: str) -> bool:
    """Whether a candidate's study holds what the ranking needs: its manifest says it
    completed, or failed at a stage after ``required`` (a model that could not be fitted
    leaves the tour's reads standing), and ``required``'s record is there. A study that
    failed earlier, was interrupted or is running is not used: its older stage records
    may belong to another config."""
    try:
        man = read_run_json(inside(run, "manifest.json"))
    except (OSError, ValueError):
        return False
    if not isinstance(man, dict) or not regular_file(inside(run, f"{RECORD_DIR}/{required}.json")):
        return False
    order = stage_names()
    if man.get("status") == "complete":
        return True
    failed = (man.get("failure") or {}).get("stage") if isinstance(man.get("failure"), dict) else None
    return (man.get("status") == "failed" and failed in order
            and order.index(failed) > order.index(required))


def complete_dirs(out: Path, name: str, n: int, required: str = "reads", ks=None) -> dict:
    """``{k: run directory}`` of candidate ``name``'s replicates ``range(n)`` (or ``ks``)
    that :func:`usable_run` accepts."""
    dirs = {}
    for k in (range(n) if ks is None else ks):
        d = candidate_dir(out, name, k)
        if usable_run(d, required):
            dirs[k] = d
    return dirs


def height_bands(edges) -> list[tuple[float, float]]:
    """The tag-height bands ``(low, high)`` between consecutive ``height_bands_m`` edges."""
    return [(float(a), float(b)) for a, b in zip(edges[:-1], edges[1:], strict=True)]


def band_key(band: tuple[float, float]) -> str:
    """Column name of the completeness of a tag-height band."""
    return f"completeness_{band[0]:g}_{band[1]:g}m"


def ranking_table(df: pd.DataFrame, settings) -> pd.DataFrame:
    """The ranked table as people read it: candidate, feasibility, each objective as
    ``estimate [low, high]``, the primary's difference to the best with its verdict."""
    def fmt(v, lo, hi):
        if v is None or not np.isfinite(v):
            return "–"
        if lo is None or hi is None or not (np.isfinite(lo) and np.isfinite(hi)):
            return f"{v:.3g}"
        return f"{v:.3g} [{lo:.3g}, {hi:.3g}]"

    rows = []
    for _, r in df.iterrows():
        row = {"rank": int(r["rank"]), "candidate": r["candidate"],
               "feasible": r.get("feasibility", "yes" if r["feasible"] else "no")}
        for key in OBJECTIVES:
            row[key] = fmt(r.get(key), r.get(f"{key}_low"), r.get(f"{key}_high"))
        row[f"{settings.primary} minus best"] = (
            "(recommended)" if r["rank"] == 1 else fmt(r["diff_vs_best"], r["diff_vs_best_low"],
                                                       r["diff_vs_best_high"]))
        row["verdict"] = r.get("verdict_vs_best", "")
        row["new antenna positions traced"] = int(r["n_sources_traced"])
        row["compute [s]"] = f"{r['compute_s']:.0f}"
        rows.append(row)
    return pd.DataFrame(rows)
