"""Every headline number with its 95 % interval, and each model against the chapter's ANFIS.

From the per-unit tables of one run or of a study's replicates pooled
(:class:`~.units.UnitTables`), :func:`headline_intervals` computes the headline
metrics of every model with a cluster-bootstrap interval over the independent units
(:func:`~.intervals.unit_interval`), and the paired difference of each model to the
reference model on the same units with its verdict
(:func:`~.intervals.paired_difference`). ``metrics.json`` keeps them under
``intervals`` and ``comparisons``; every ranking the report states comes from them.

The metrics (:data:`METRICS`), each the pooled statistic over its units' observations:

==================================  ===============================================  =========
key                                 statistic                                        units
==================================  ===============================================  =========
heldout.rssi_mae_db / _rmse_db      mean |e| / sqrt(mean e^2) of fs_dbm - noise-     tags
/ _abs_bias_db                      free RSSI over held-out closing links [dB]
heldout.detection_mae               mean over the (d, alpha) cells with >=          (none:
                                    min_attempts held-out attempts of |fT(centre) -  CELL_MAE_
                                    p_detect|                                        NOTE)
heldout.detection_brier             mean (fT - read)^2 over held-out attempts        tags
fig7.median_pct / share_below_20    chapter Sec. 5 error |f̄s - s| x 100 of the       tags
                                    in-domain (pose, antenna, tag) groups: median;
                                    share below 20 %
tag_localisation.median_m / p90_m   MAP error of the held-out tags' positions [m]    tags
/ within_0_5m                       (per tag); share within 0.5 m
robot_localisation.median_m         median position error over ALL steps of every    filter
                                    filter run [m]; ``_before_kidnap`` /             runs
                                    ``_after_kidnap``: the steps before / from the
                                    kidnapping
robot_localisation.converged_share  share of filter runs that converged / recovered  filter
/ recovered_share                   (:func:`pipeline.localisation.filter_metrics`)   runs
==================================  ===============================================  =========

Units of different replicates are pooled as units of one sample: the tags of one
replicate share its tour (a correlation the intervals do not model; the per-replicate
values are reported beside them, ``replicates.json``).
"""

from __future__ import annotations

import dataclasses
import zlib
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
import pandas as pd

from pipeline.evaluation.intervals import (
    CONFIDENCE,
    N_RESAMPLES,
    Interval,
    clusters_of,
    fold_interval,
    paired_difference,
    unit_interval,
    weighted_mean,
    weighted_quantile,
)
from pipeline.evaluation.units import UnitTables

__all__ = ["METRICS", "MetricSpec", "REFERENCE", "headline_estimates", "headline_intervals",
           "metric_statistic"]

#: The model every other is compared with: the chapter's ANFIS on MCL poses.
REFERENCE = "anfis"

#: The |bias| metric, whose interval is the signed bias's, folded (fold_interval).
ABS_BIAS = "heldout.rssi_abs_bias_db"
SIGNED_BIAS = "heldout.rssi_bias_db"


@dataclass(frozen=True)
class MetricSpec:
    """One headline metric.

    Attributes
    ----------
    key : str
        ``section.name`` in ``intervals`` / ``comparisons``.
    label : str
        What it is, with its unit, for tables.
    table : str
        The :class:`~.units.UnitTables` field it is computed from.
    lower_is_better : bool
    unit : str
        What one resampled unit is.
    """

    key: str
    label: str
    table: str
    lower_is_better: bool
    unit: str
    no_interval: str | None = None
    """Why the metric gets no interval (None: it gets one)."""
    quantile: bool = False
    """A quantile of pooled observations (median, p90): its interval is the percentile
    interval, not BCa (:func:`~.intervals.unit_interval`)."""


#: Why the detection cell MAE is given without an interval.
CELL_MAE_NOTE = (
    "not resampled: each cell's truth is the mean over the attempts that fall in it, and a "
    "resample that draws a tag twice averages fewer distinct positions, so nearly every "
    "resample's MAE exceeds the estimate (on the default study's 5 replicates the BCa "
    "interval missed its own estimate); the Brier score carries the detection interval")

METRICS: tuple[MetricSpec, ...] = (
    MetricSpec("heldout.rssi_mae_db", "held-out RSSI MAE [dB]", "rssi_links", True, "tag"),
    MetricSpec("heldout.rssi_rmse_db", "held-out RSSI RMSE [dB]", "rssi_links", True, "tag"),
    MetricSpec("heldout.rssi_abs_bias_db", "held-out RSSI |bias| [dB]", "rssi_links", True, "tag"),
    MetricSpec("heldout.detection_mae", "held-out detection MAE (cells)", "detection_attempts",
               True, "tag", no_interval=CELL_MAE_NOTE),
    MetricSpec("heldout.detection_brier", "held-out detection Brier score", "detection_attempts",
               True, "tag"),
    MetricSpec("fig7.median_pct", "Fig. 7 median error, in-domain [%]", "fig7_groups", True, "tag", quantile=True),
    MetricSpec("fig7.share_below_20pct", "Fig. 7 share of in-domain groups below 20 %", "fig7_groups",
               False, "tag"),
    MetricSpec("tag_localisation.median_m", "tag localisation median [m]", "tag_errors", True, "tag", quantile=True),
    MetricSpec("tag_localisation.p90_m", "tag localisation p90 [m]", "tag_errors", True, "tag", quantile=True),
    MetricSpec("tag_localisation.within_0_5m", "tags localised within 0.5 m", "tag_errors",
               False, "tag"),
    MetricSpec("robot_localisation.median_m", "robot median error, all steps [m]", "robot_steps",
               True, "filter run", quantile=True),
    MetricSpec("robot_localisation.median_before_kidnap_m", "robot median before the kidnapping [m]",
               "robot_steps", True, "filter run", quantile=True),
    MetricSpec("robot_localisation.median_after_kidnap_m", "robot median from the kidnapping [m]",
               "robot_steps", True, "filter run", quantile=True),
    MetricSpec("robot_localisation.converged_share", "filter runs converged", "robot_steps",
               False, "filter run"),
    MetricSpec("robot_localisation.recovered_share", "filter runs recovered after the kidnapping",
               "robot_steps", False, "filter run"),
)

Statistic = Callable[[np.ndarray], np.ndarray]


def _sums(codes: np.ndarray, n: int, values: np.ndarray) -> np.ndarray:
    return np.bincount(codes, weights=np.asarray(values, np.float64), minlength=n)


def _ratio(num: np.ndarray, den: np.ndarray) -> Statistic:
    def stat(w):
        with np.errstate(invalid="ignore", divide="ignore"):
            return (w @ num) / (w @ den)
    return stat


def _rssi(rows: pd.DataFrame, codes: np.ndarray, n: int, name: str) -> Statistic:
    e = rows["error_db"].to_numpy(np.float64)
    cnt = _sums(codes, n, np.ones_like(e))
    if name == "heldout.rssi_mae_db":
        return _ratio(_sums(codes, n, np.abs(e)), cnt)
    if name == "heldout.rssi_abs_bias_db":
        f = _ratio(_sums(codes, n, e), cnt)
        return lambda w: np.abs(f(w))
    if name == SIGNED_BIAS:  # its interval, folded, is the |bias| interval
        return _ratio(_sums(codes, n, e), cnt)
    f = _ratio(_sums(codes, n, e * e), cnt)
    return lambda w: np.sqrt(f(w))


def _detection(rows: pd.DataFrame, codes: np.ndarray, n: int, name: str, cells: pd.DataFrame,
               min_attempts: int) -> Statistic:
    ft = rows["ft"].to_numpy(np.float64)
    read = rows["read"].to_numpy(np.float64)
    if name == "heldout.detection_brier":
        return _ratio(_sums(codes, n, (ft - read) ** 2), _sums(codes, n, np.ones_like(ft)))
    cell_ids, cell_code = np.unique(rows["cell"].to_numpy(np.int64), return_inverse=True)
    k = len(cell_ids)
    flat = codes * k + cell_code
    n_att = np.bincount(flat, minlength=n * k).reshape(n, k)
    p_sum = np.bincount(flat, weights=rows["p_true"].to_numpy(np.float64),
                        minlength=n * k).reshape(n, k)
    centre = pd.Series(cells["ft_centre"].to_numpy(np.float64), index=cells["cell"].to_numpy(np.int64))
    ft_c = centre.reindex(cell_ids).to_numpy(np.float64)

    # the cells scored are those the observed sample scores (>= min_attempts attempts):
    # letting each resample choose its own cells makes the statistic jump with the cell
    # set (a tag drawn twice lifts cells over the threshold), and its intervals missed
    # their own estimate on the default study
    keep = n_att.sum(axis=0) >= min_attempts
    n_att, p_sum, ft_c = n_att[:, keep], p_sum[:, keep], ft_c[keep]

    def stat(w):
        att = w @ n_att
        with np.errstate(invalid="ignore", divide="ignore"):
            p = (w @ p_sum) / att
            ok = att > 0  # a cell none of the drawn tags reached is left out
            return np.where(ok, np.abs(ft_c - p), 0.0).sum(axis=-1) / ok.sum(axis=-1)
    return stat


def _pooled(values: np.ndarray, codes: np.ndarray, how: str) -> Statistic:
    v = np.asarray(values, np.float64)
    if how == "median":
        return lambda w: weighted_quantile(v, w[..., codes], 0.5)
    if how == "p90":
        return lambda w: weighted_quantile(v, w[..., codes], 0.9)
    return lambda w: weighted_mean(v, w[..., codes])  # a share: mean of a 0/1 indicator


def _statistic(spec: MetricSpec, rows: pd.DataFrame, codes: np.ndarray, n: int,
               cells: pd.DataFrame | None, min_attempts: int) -> Statistic:
    name = spec.key
    if spec.table == "rssi_links":
        return _rssi(rows, codes, n, name)
    if spec.table == "detection_attempts":
        return _detection(rows, codes, n, name, cells, min_attempts)
    if spec.table == "fig7_groups":
        e = rows["error_pct"].to_numpy(np.float64)
        return (_pooled(e, codes, "median") if name == "fig7.median_pct"
                else _pooled(e < 20.0, codes, "share"))
    if spec.table == "tag_errors":
        e = rows["error_m"].to_numpy(np.float64)
        return {"tag_localisation.median_m": _pooled(e, codes, "median"),
                "tag_localisation.p90_m": _pooled(e, codes, "p90"),
                "tag_localisation.within_0_5m": _pooled(e <= 0.5, codes, "share")}[name]
    # robot_steps: every step of every filter run
    e = rows["error_m"].to_numpy(np.float64)
    after = rows["after_kidnap"].to_numpy(bool)
    if name == "robot_localisation.median_m":
        return _pooled(e, codes, "median")
    if name.endswith("_kidnap_m"):
        sel = after if "after" in name else ~after
        return _pooled(e[sel], codes[sel], "median")
    col = "converge_s" if name.endswith("converged_share") else "recover_s"
    per_run = np.zeros(n)
    per_run[codes] = np.isfinite(rows[col].to_numpy(np.float64))
    return lambda w: weighted_mean(per_run, w)


def metric_statistic(key: str, rows: pd.DataFrame, codes: np.ndarray, n_units: int, *,
                     cells: pd.DataFrame | None = None, min_attempts: int = 1) -> Statistic:
    """The weighted statistic of headline metric ``key`` on one model's ``rows``.

    Parameters
    ----------
    key : str
        A :data:`METRICS` key.
    rows : pandas.DataFrame
        That model's rows of the metric's :class:`~.units.UnitTables` table.
    codes : numpy.ndarray, int
        Unit index of each row, in [0, n_units): rows of the same unit share a code, and
        two statistics with the same codes are paired (a placement study compares
        candidates on the same (replicate, tag) units this way).
    n_units : int
    cells : pandas.DataFrame, optional
        The model's ``detection_cells`` (detection metrics only).
    min_attempts : int

    Returns
    -------
    callable
        ``statistic(w)`` as :func:`~.intervals.unit_interval` takes it.
    """
    spec = next((m for m in METRICS if m.key == key), None)
    if spec is None:
        raise KeyError(f"unknown headline metric {key!r}")
    return _statistic(spec, rows, np.asarray(codes, np.int64), int(n_units), cells,
                      int(min_attempts))


def _rng(seed: int, *names: str) -> np.random.Generator:
    return np.random.default_rng([int(seed), *(zlib.crc32(s.encode()) for s in names)])


class _ByModel:
    """One metric table split by model once: each model's rows (in table order) and its
    sorted units, and each model's detection cells. The statistics and comparisons ask
    for every model's rows several times; a boolean filter of the whole table per ask
    was about half of a study's evaluation stage (pandas, measured on the tiny study)."""

    def __init__(self, df: pd.DataFrame, tables: UnitTables):
        for col in ("model", "unit"):
            if df[col].isna().any():  # a row nobody can score: a bug upstream, not a unit
                raise ValueError(f"a unit table has rows without a {col}")
        # in the table's order of first appearance (groupby keeps it with sort=False)
        self.rows = {m: sub for m, sub in df.groupby("model", sort=False, observed=True)}
        self.models = list(self.rows)
        self.n_units = int(df["unit"].nunique())
        self.unit_of_row = {m: sub["unit"].to_numpy() for m, sub in self.rows.items()}
        self.units = {m: np.unique(u) for m, u in self.unit_of_row.items()}
        cells = tables.detection_cells
        self.cells = (None if cells is None
                      else {m: sub for m, sub in cells.groupby("model", sort=False, observed=True)})
        self._empty_cells = None if cells is None else cells.iloc[:0]

    def cells_of(self, model: str) -> pd.DataFrame | None:
        if self.cells is None:
            return None
        return self.cells.get(model, self._empty_cells)


def _tables_of(tables: UnitTables):
    """Per metric with a table: (spec, its rows split by model) with ``unit`` and
    ``model`` as str; each table split once, however many metrics read it."""
    split: dict[str, _ByModel] = {}
    for spec in METRICS:
        df = getattr(tables, spec.table)
        if df is None or df.empty:
            continue
        if spec.table not in split:
            df = df.assign(unit=df["unit"].astype(str), model=df["model"].astype(str))
            split[spec.table] = _ByModel(df, tables)
        yield spec, split[spec.table]


def _stats_on(spec: MetricSpec, by: _ByModel, models, units: np.ndarray, min_attempts: int) -> dict:
    """The weighted statistics of ``models`` over exactly ``units`` (sorted; rows of other
    units are left out), index i of a weight vector being ``units[i]`` for every model."""
    out = {}
    for model in models:
        # ``units`` is sorted (np.unique, np.intersect1d): a row's code is its unit's place
        u = by.unit_of_row[model]
        code = np.searchsorted(units, u)
        keep = code < len(units)
        keep[keep] = units[code[keep]] == u[keep]
        rows = by.rows[model]
        if not keep.all():
            rows, code = rows.iloc[np.flatnonzero(keep)], code[keep]
        out[model] = _statistic(spec, rows, code, len(units), by.cells_of(model),
                                int(min_attempts))
    return out


def _own_statistics(spec: MetricSpec, by: _ByModel, min_attempts: int) -> dict:
    """Each model's statistic over its own units: ``{model: (statistic, n_units)}``."""
    out = {}
    for m in by.models:
        units = by.units[m]
        out[m] = (_stats_on(spec, by, [m], units, min_attempts)[m], len(units))
    return out


def headline_estimates(tables: UnitTables, *, min_attempts: int) -> dict:
    """The headline metrics without intervals: ``{key: {model: estimate}}`` (NaN: undefined)."""
    return {spec.key: {m: float(f(np.ones(n)))
                       for m, (f, n) in _own_statistics(spec, by, min_attempts).items()}
            for spec, by in _tables_of(tables)}


def headline_intervals(tables: UnitTables, *, seed: int, min_attempts: int,
                       reference: str = REFERENCE, n_resamples: int = N_RESAMPLES,
                       replicated: bool = False) -> dict:
    """Intervals of every headline metric and paired comparisons with ``reference``.

    Parameters
    ----------
    tables : UnitTables
        One run's tables, or the replicates' pooled (:func:`~.units.concat_unit_tables`).
    seed : int
        Seeds the resampling; each (metric, model) has its own stream, so a number does
        not depend on which other models were scored.
    min_attempts : int
        Cells with fewer held-out attempts are left out of the detection MAE (the
        study's ``training.min_attempts``).
    reference : str
    n_resamples : int
    replicated : bool
        The units are (replicate, tag) / (replicate, filter run) pairs (for the record).

    Returns
    -------
    dict
        ``{"intervals": {key: {"label", "unit", "n_units", "models": {name: Interval
        dict}}}, "comparisons": {"reference", "confidence", "metrics": {key: {name:
        Comparison dict}}}}``; a metric whose table is absent is left out.
    """
    intervals, comparisons = {}, {}
    for spec, by in _tables_of(tables):
        unit = f"replicate x {spec.unit}" if replicated else spec.unit
        own = _own_statistics(spec, by, min_attempts)
        sec = {"label": spec.label, "unit": unit, "n_units": by.n_units}
        if spec.no_interval:
            sec["models"] = {m: Interval(float(f(np.ones(n))), None, None, n, unit, "none",
                                         note=spec.no_interval).to_dict()
                             for m, (f, n) in own.items()}
            intervals[spec.key] = sec
            continue
        # pooled replicates: two-stage resampling, replicate then unit (clusters_of)
        how = "percentile" if spec.quantile else "BCa"
        signed = (_own_statistics(dataclasses.replace(spec, key=SIGNED_BIAS), by, min_attempts)
                  if spec.key == ABS_BIAS else None)
        sec["models"] = {}
        for m, (f, n) in own.items():
            kw = dict(unit=unit, n_resamples=n_resamples, clusters=clusters_of(by.units[m]),
                      method=how)
            if signed is not None:  # |bias|: the signed bias's interval, folded at 0
                iv = fold_interval(unit_interval(signed[m][0], n, _rng(seed, spec.key, m), **kw))
            else:
                iv = unit_interval(f, n, _rng(seed, spec.key, m), **kw)
            sec["models"][m] = iv.to_dict()
        intervals[spec.key] = sec
        if reference not in own:
            continue
        comparisons[spec.key] = {}
        ref_units = by.units[reference]
        for m in own:
            if m == reference:
                continue
            # paired: both models on the units both were scored on
            common = np.intersect1d(by.units[m], ref_units)
            pair = _stats_on(spec, by, [m, reference], common, min_attempts)
            comparisons[spec.key][m] = paired_difference(
                pair[m], pair[reference], len(common), _rng(seed, spec.key, m, reference),
                lower_is_better=spec.lower_is_better, unit=unit,
                n_resamples=n_resamples, clusters=clusters_of(common),
                method="percentile" if spec.quantile else "BCa").to_dict()
    return {"intervals": intervals,
            "comparisons": {"reference": reference, "confidence": CONFIDENCE,
                            "how": "model minus reference on the same resampled units; "
                                   "'better'/'worse' where the 95 % interval excludes 0",
                            "metrics": comparisons}}
