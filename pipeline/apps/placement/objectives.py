"""What a placement is judged by: objectives per candidate, with intervals, compared in pairs.

Each objective is a statistic of (replicate, unit) observations of a candidate's
replicated studies, with a cluster-bootstrap 95 % interval over those units
(:mod:`pipeline.evaluation.intervals`):

===========================  ===========================================  ====================
key                          statistic                                    unit
===========================  ===========================================  ====================
read_rate                    reads / in-range attempts on the training    replicate x tag
                             tour (:mod:`pipeline.evaluation.inventory`)
completeness                 share of (tag, pass) read >= ``min_reads``   replicate x tag
                             times in that pass
surface_coverage             share of the route's read rounds in which    replicate x tag
                             the tag's coherent-gain link closes, at the
                             tag's own position and height
reads_per_pass               mean reads of a tag in one inventory pass    replicate x tag
link_margin_db               median over (tag, pass) of the pass's best   replicate x tag
                             link margin, gain - min gain [dB]
never_read                   share of tags no pass of the tour read       replicate x tag
tag_localisation_median_m    median MAP error of the held-out tags' posi- replicate x held-out
                             tions with the learned ANFIS model [m]       tag
rssi_rmse_db                 held-out RSSI RMSE of the learned ANFIS      replicate x held-out
                             model [dB]                                   tag
robot_median_m               median robot position error over all steps   replicate x filter
                             of the RFID-only filter runs (ANFIS) [m]     run
===========================  ===========================================  ====================

Candidates run the same replicate seeds, so replicate k of every candidate draws the
same held-out tags, tour randomness and filter-run draws (the tour itself is the same
unless a taller mast changes the drivable band, e.g. under shelves): two candidates
are compared on the units both have (:func:`compare_objective`), the difference's
interval from the same resampled units. The inventory objectives count the training
tags (the same physical tags in every replicate); the (replicate, tag) units are
resampled as independent, so their intervals leave out the tag-to-tag variation of a
building's other tags and are narrower than a new building's would be.

The inventory objectives need the tour and its reads only: a placement ranked and
constrained by them runs each candidate's study up to the ``reads`` stage
(:attr:`Objective.stage`, :func:`needed_stage`), never fitting a model it does not
use. ``reads_per_pass``, ``link_margin_db`` and ``never_read`` are the engineer's units
(:mod:`pipeline.evaluation.inventory`).

``surface_coverage`` replaces the sweeps' former "corridor coverage", the covered
share of one horizontal field plane at ``evaluation.field_height_m`` from one antenna
pose: an antenna at the plane's height sends its rays along the plane, few cross it,
and the plane's gain dropped by 7-14 dB there (a radio-map artefact, not physics).
Coverage is counted here on point-to-point traced links at the tags themselves.
"""

from __future__ import annotations

import zlib
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pandas as pd

from pipeline.engine.runstore import inside, read_run_json, regular_file
from pipeline.evaluation.headline import metric_statistic
from pipeline.evaluation.intervals import (
    Comparison,
    Interval,
    clusters_of,
    paired_difference,
    unit_interval,
    verdict,
)
from pipeline.evaluation.inventory import inventory_statistic
from pipeline.evaluation.units import UnitTables
from pipeline.runpaths import RECORD_DIR
from pipeline.stages import stage_names
from pipeline.stages.summary import tour_tags

__all__ = [
    "LEARNED_MODEL",
    "OBJECTIVES",
    "CandidateData",
    "Objective",
    "compare_objective",
    "load_candidate_data",
    "needed_stage",
    "objective_estimate",
    "objective_interval",
]

#: The sensor model the placement's model-based objectives use: the chapter's ANFIS.
LEARNED_MODEL = "anfis"


@dataclass(frozen=True)
class Objective:
    """One placement objective.

    Attributes
    ----------
    key : str
    label : str
        What it is, with its unit.
    lower_is_better : bool
    unit : str
        What one resampled unit is.
    source : str
        "inventory", or the :data:`pipeline.evaluation.headline.METRICS` key it is.
    table : str
        The :class:`~pipeline.evaluation.units.UnitTables` field (headline objectives).
    """

    key: str
    label: str
    lower_is_better: bool
    unit: str
    source: str = "inventory"
    table: str = ""

    @property
    def stage(self) -> str:
        """The last study stage the objective reads: ``reads`` for the inventory
        objectives (the tour's read log), ``evaluation`` for the model-based ones (its
        unit tables)."""
        return "reads" if self.source == "inventory" else "evaluation"


OBJECTIVES: dict[str, Objective] = {o.key: o for o in (
    Objective("read_rate", "read rate (reads / in-range attempts)", False, "replicate x tag"),
    Objective("completeness", "tags read >= k times per pass (share)", False, "replicate x tag"),
    Objective("surface_coverage", "route share with a closing link, at the tags", False,
              "replicate x tag"),
    Objective("reads_per_pass", "reads per tag per pass", False, "replicate x tag"),
    Objective("link_margin_db", "link margin, median over tags and passes [dB]", False,
              "replicate x tag"),
    Objective("never_read", "tags never read in the tour (share)", True, "replicate x tag"),
    Objective("tag_localisation_median_m", "tag localisation median, ANFIS [m]", True,
              "replicate x held-out tag", "tag_localisation.median_m", "tag_errors"),
    Objective("rssi_rmse_db", "held-out RSSI RMSE, ANFIS [dB]", True, "replicate x held-out tag",
              "heldout.rssi_rmse_db", "rssi_links"),
    Objective("robot_median_m", "robot localisation median, all steps [m]", True,
              "replicate x filter run", "robot_localisation.median_m", "robot_steps"),
)}


def needed_stage(keys) -> str:
    """The last study stage the objectives ``keys`` need (:attr:`Objective.stage`):
    ``reads`` when all are inventory objectives, else ``evaluation``."""
    order = stage_names()
    return max((OBJECTIVES[k].stage for k in keys), key=order.index, default="reads")


@dataclass
class CandidateData:
    """A candidate's per-unit observations, its replicates pooled (units ``r<k>/<id>``).

    Attributes
    ----------
    inventory : pandas.DataFrame
        :func:`pipeline.evaluation.inventory.tour_tag_table` rows of every replicate.
    tables : dict[str, pandas.DataFrame]
        The learned model's rows of ``rssi_links``, ``tag_errors`` and ``robot_steps``
        (absent tables left out).
    replicates : list of int
        The replicates found complete.
    """

    inventory: pd.DataFrame
    tables: dict
    replicates: list


def load_candidate_data(run_dirs: dict, budget) -> CandidateData:
    """Read a candidate's finished replicate run directories.

    Parameters
    ----------
    run_dirs : dict[int, pathlib.Path]
        Replicate index -> its run directory.
    budget : propagation.LinkBudget
        The candidates' link budget (the link-closing test of ``surface_coverage``).

    Raises
    ------
    ValueError
        A file is missing or unreadable (the message names it); a track without
        ``pass_index`` (a run directory from before it was written: rerun it).
    """
    inv, tabs = [], {}
    for k, run in run_dirs.items():
        run = Path(run)
        try:
            rows = tour_tags(run, budget)
        except (OSError, KeyError) as exc:
            raise ValueError(f"{run}: cannot read the tour's files ({exc})") from None
        if rows is None:
            raise ValueError(f"{run}/tour/train_track.npz has no pass_index (written by an "
                             "older version): rerun the study")
        rows["unit"] = f"r{k}/" + rows["unit"].astype(str)
        inv.append(rows)
        if not _stage_done(run, "evaluation"):  # a study run up to its reads only
            continue
        ut = UnitTables.load(run)
        for name in ("rssi_links", "tag_errors", "robot_steps"):
            df = getattr(ut, name)
            if df is None or df.empty:
                continue
            df = df[df["model"].astype(str) == LEARNED_MODEL].copy()
            df["unit"] = f"r{k}/" + df["unit"].astype(str)
            tabs.setdefault(name, []).append(df)
    return CandidateData(
        inventory=pd.concat(inv, ignore_index=True) if inv else pd.DataFrame(),
        tables={k: pd.concat(v, ignore_index=True) for k, v in tabs.items()},
        replicates=sorted(int(k) for k in run_dirs))


def _stage_done(run: Path, stage: str) -> bool:
    """Whether the run's last study ran (or found cached) ``stage``: its manifest lists it.
    A record left by an earlier run of other stages does not count (a study run up to
    its reads after one that fitted models keeps the old evaluation's files)."""
    if not regular_file(inside(run, f"{RECORD_DIR}/{stage}.json")):
        return False
    try:
        man = read_run_json(inside(run, "manifest.json"))
    except (OSError, ValueError):
        return False
    return isinstance(man, dict) and isinstance(man.get("stages"), dict) and stage in man["stages"]


def _rows(data: CandidateData, key: str, band: tuple[float, float] | None = None) -> pd.DataFrame:
    obj = OBJECTIVES[key]
    if obj.source == "inventory":
        df = data.inventory
        if band is not None and not df.empty:
            df = df[(df["z_m"] >= band[0]) & (df["z_m"] < band[1])]
        return df
    return data.tables.get(obj.table, pd.DataFrame(columns=["unit"]))


def _statistic(key: str, rows: pd.DataFrame, units: np.ndarray, min_reads: int):
    index = pd.Series(np.arange(len(units)), index=units)
    rows = rows[rows["unit"].isin(units)]
    codes = index.loc[rows["unit"]].to_numpy()
    obj = OBJECTIVES[key]
    if obj.source == "inventory":
        return inventory_statistic(key, rows, codes, len(units), min_reads=min_reads)
    return metric_statistic(obj.source, rows, codes, len(units))


#: Objectives that are quantiles (medians): the percentile interval, not BCa
#: (:func:`pipeline.evaluation.intervals.unit_interval`).
QUANTILE_OBJECTIVES = ("link_margin_db", "tag_localisation_median_m", "robot_median_m")


def _method(key: str) -> str:
    return "percentile" if key in QUANTILE_OBJECTIVES else "BCa"


def _rng(seed: int, *names: str) -> np.random.Generator:
    return np.random.default_rng([int(seed), *(zlib.crc32(s.encode()) for s in names)])


def objective_estimate(data: CandidateData, key: str, *, min_reads: int = 1,
                       band: tuple[float, float] | None = None) -> float:
    """The objective's value on the observed units (NaN where it has none)."""
    rows = _rows(data, key, band)
    units = np.unique(rows["unit"].astype(str)) if len(rows) else np.array([], str)
    if len(units) == 0:
        return float("nan")
    return float(_statistic(key, rows.assign(unit=rows["unit"].astype(str)), units,
                            min_reads)(np.ones(len(units))))


def objective_interval(data: CandidateData, key: str, *, seed: int, candidate: str = "",
                       min_reads: int = 1, band: tuple[float, float] | None = None) -> Interval:
    """The objective with its 95 % interval over the candidate's own units.

    ``seed`` and ``candidate`` seed the resampling stream (one per objective, band and
    candidate: a number does not depend on which other candidates ran)."""
    obj = OBJECTIVES[key]
    rows = _rows(data, key, band)
    if len(rows) == 0:
        return Interval(float("nan"), None, None, 0, obj.unit, "none",
                        note="no observations (the stage did not run, or no tag in the band)")
    rows = rows.assign(unit=rows["unit"].astype(str))
    units = np.unique(rows["unit"])
    f = _statistic(key, rows, units, min_reads)
    return unit_interval(f, len(units), _rng(seed, key, str(band), candidate), unit=obj.unit,
                         clusters=clusters_of(units), method=_method(key))


def compare_objective(a: CandidateData, b: CandidateData, key: str, *, seed: int,
                      names: tuple[str, str] = ("a", "b"), min_reads: int = 1) -> Comparison:
    """``objective(a) - objective(b)`` on the units both candidates have, with a verdict
    ("better" / "worse" for ``a``, or "not distinguishable at 95 %")."""
    obj = OBJECTIVES[key]
    ra = _rows(a, key).assign(unit=lambda d: d["unit"].astype(str))
    rb = _rows(b, key).assign(unit=lambda d: d["unit"].astype(str))
    common = np.intersect1d(ra["unit"].unique(), rb["unit"].unique())
    if len(common) == 0:  # the objective's table is absent, or no unit in common
        none = Interval(float("nan"), None, None, 0, obj.unit, "none",
                        note="no units both candidates were scored on")
        return Comparison(none, verdict(none, obj.lower_is_better), obj.lower_is_better)
    fa = _statistic(key, ra, common, min_reads)
    fb = _statistic(key, rb, common, min_reads)
    return paired_difference(fa, fb, len(common), _rng(seed, key, *names),
                             lower_is_better=obj.lower_is_better, unit=obj.unit,
                             clusters=clusters_of(common), method=_method(key))


def traced_counts(run_dir: Path) -> dict:
    """Antenna positions traced afresh and link pairs used by one study (from its stage
    records; absent numbers are 0)."""
    out = {"n_sources_traced": 0, "n_links": 0}
    for stage, keys in (("reads", ("train", "eval")), ("truth_traces", (None,))):
        try:
            info = read_run_json(inside(Path(run_dir), f"{RECORD_DIR}/{stage}.json")).get("info") or {}
        except (OSError, ValueError, AttributeError):
            continue
        for k in keys:
            sec = info if k is None else (info.get(k) or {})
            for f, v in sec.items():
                if f.endswith("sources_traced") and isinstance(v, int):
                    out["n_sources_traced"] += v
                if f in ("n_pairs_traced", "n_site_links", "n_points_traced") and isinstance(v, int):
                    out["n_links"] += v
    return out
