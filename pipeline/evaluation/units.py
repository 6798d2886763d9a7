"""Per-unit tables of the held-out scores: what the intervals resample.

The headline numbers of ``metrics.json`` pool observations that come in independent
units (:mod:`.intervals`). To resample the units, the evaluation stage writes the
observations with their unit, one Parquet table per kind, under ``evaluation/``
(:data:`TABLES`); :mod:`.headline` computes every headline number and its interval
from them, for one run or for the replicates of a study pooled
(:func:`concat_unit_tables`).

Column ``unit`` names the independent unit: the held-out tag (``tag_id``) for
everything measured on reads of tags, the filter run (``run<j>``) for the robot; with
replicates it is prefixed by the replicate (``r<k>/``).
"""

from __future__ import annotations

from dataclasses import dataclass, fields
from pathlib import Path

import numpy as np
import pandas as pd

from pipeline import runfiles
from pipeline.evaluation.comparison import cell_centre_fT, closing_links
from pipeline.evaluation.interface import detection_probability
from pipeline.evaluation.tables import require_columns
from pipeline.evaluation.truth import TruthGrid, true_detected, true_rssi_dbm
from pipeline.runpaths import inside

__all__ = [
    "TABLES",
    "UnitTables",
    "concat_unit_tables",
    "detection_cells",
    "detection_outcomes",
    "fig7_groups",
    "rssi_link_errors",
]

#: File of each table under a run directory.
TABLES = {
    "rssi_links": runfiles.EVALUATION_TABLE.format(table="rssi_links"),
    "detection_attempts": runfiles.EVALUATION_TABLE.format(table="detection_attempts"),
    "detection_cells": runfiles.EVALUATION_TABLE.format(table="detection_cells"),
    "fig7_groups": runfiles.EVALUATION_TABLE.format(table="fig7_groups"),
    "tag_errors": runfiles.TAG_ERRORS,
    "robot_steps": runfiles.ROBOT_STEPS,
}


@dataclass
class UnitTables:
    """The observations behind the headline numbers, each with its unit.

    Attributes
    ----------
    rssi_links : pandas.DataFrame
        model, unit, error_db: ``fs_dbm(d_true, alpha_true)`` minus the noise-free RSSI of
        each held-out closing link within ``d_max_m`` [dB] (:func:`rssi_link_errors`).
    detection_attempts : pandas.DataFrame
        model, unit, cell, read, p_true, ft: one row per held-out attempt inside the truth
        grid (:func:`detection_outcomes`).
    detection_cells : pandas.DataFrame
        model, cell, ft_centre: fT at each (d, alpha) cell centre.
    fig7_groups : pandas.DataFrame
        model, unit, error_pct: chapter Fig. 7 errors of the in-domain (pose, antenna,
        tag) groups [%].
    tag_errors : pandas.DataFrame or None
        model, unit, error_m: tag-localisation MAP error per held-out tag [m].
    robot_steps : pandas.DataFrame or None
        model, unit, t_s, error_m, after_kidnap, converge_s, recover_s: every step of
        every RFID-only filter run (``unit`` the run), with the run's convergence and
        recovery times (NaN: never).
    """

    rssi_links: pd.DataFrame
    detection_attempts: pd.DataFrame
    detection_cells: pd.DataFrame
    fig7_groups: pd.DataFrame
    tag_errors: pd.DataFrame | None = None
    robot_steps: pd.DataFrame | None = None

    @classmethod
    def load(cls, run_dir, read_parquet=pd.read_parquet) -> UnitTables:
        """Read the tables of one run directory (downstream tables absent: None).

        ``read_parquet(path)`` reads one file (a caller passes its checked reader)."""
        root = Path(run_dir)
        out = {}
        for f in fields(cls):
            p = inside(root, TABLES[f.name])  # a linked folder is refused, never followed
            out[f.name] = read_parquet(p) if p.is_file() or f.name not in (
                "tag_errors", "robot_steps") else None
        tags = out["tag_errors"]
        if tags is not None and "unit" not in tags.columns:  # downstream/tag_errors.parquet
            out["tag_errors"] = tags.rename(columns={"tag_id": "unit"})
        return cls(**out)


def concat_unit_tables(tables: dict) -> UnitTables:
    """Pool the tables of several replicates, ``{k: UnitTables}``.

    Units become ``r<k>/<unit>``. Each replicate fits its own models and has its own
    held-out truth, so a (d, alpha) cell of replicate k is a cell of its own: cell
    indices are offset by k times the number of cells (the grid is the same in every
    replicate).
    """
    cells = [t.detection_cells for t in tables.values()]
    n_cells = int(max(int(c["cell"].max()) + 1 for c in cells)) if cells else 0
    out = {}
    for f in fields(UnitTables):
        parts = []
        for i, (k, t) in enumerate(tables.items()):
            df = getattr(t, f.name)
            if df is None:
                continue
            df = df.copy()
            if "unit" in df.columns:
                df["unit"] = f"r{k}/" + df["unit"].astype(str)
            if "cell" in df.columns:
                df["cell"] = df["cell"].astype(np.int64) + i * n_cells
            parts.append(df)
        out[f.name] = pd.concat(parts, ignore_index=True) if parts else None
    return UnitTables(**out)


def rssi_link_errors(eval_reads: pd.DataFrame, sensors: dict, budget, *, d_max_m: float,
                     names) -> pd.DataFrame:
    """Per held-out link and model: predicted minus noise-free RSSI [dB].

    The links are those of :func:`~.comparison.rssi_vs_truth` (noise-free link closes,
    true distance below ``d_max_m``), so the pooled statistics of a model's rows are its
    ``heldout.models.<name>.rssi_dbm`` numbers.

    Returns
    -------
    pandas.DataFrame
        model (str), unit (the tag), error_db (float64).
    """
    require_columns(eval_reads, ("tag_id",), "eval reads")
    keep = closing_links(eval_reads, budget, d_max_m)
    g = eval_reads["gain_db"].to_numpy(np.float64)
    d = eval_reads["d_true_m"].to_numpy(np.float64)
    a = eval_reads["alpha_true_rad"].to_numpy(np.float64)[keep]
    truth = true_rssi_dbm(g[keep], budget)
    unit = eval_reads["tag_id"].astype(str).to_numpy()[keep]
    parts = [pd.DataFrame({"model": name, "unit": unit,
                           "error_db": np.asarray(sensors[name].fs_dbm(d[keep], a), np.float64)
                           - truth}) for name in names]
    return _concat(parts, {"model": str, "unit": str, "error_db": float})


def detection_outcomes(eval_reads: pd.DataFrame, sensors: dict, eval_truth: TruthGrid,
                       miss_probability, budget, *, names, dz_m=None) -> pd.DataFrame:
    """Per held-out attempt inside the truth grid and model: cell, outcome, truth, fT.

    ``dz_m`` (one per row of `eval_reads`, optional): each link's tag height above its
    true antenna [m], which a model that uses it is scored with
    (:func:`~.interface.detection_probability`), as in
    :func:`~.comparison.detection_vs_truth`.

    ``p_true`` is the attempt's contribution to its cell's true detection probability
    (closed x (1 - miss probability), :func:`~.truth.detection_truth`): summed over a
    cell's attempts and divided by their number it is the cell's ``p_detect``.

    Returns
    -------
    pandas.DataFrame
        model, unit (the tag), cell (flat cell index, int64), read (bool), p_true, ft.
    """
    require_columns(eval_reads, ("tag_id", "read", "d_true_m", "alpha_true_rad", "gain_db"),
                    "eval reads")
    d = eval_reads["d_true_m"].to_numpy(np.float64)
    a = eval_reads["alpha_true_rad"].to_numpy(np.float64)
    idx = eval_truth.grid.index(d, a)
    valid = idx.valid
    q = np.broadcast_to(np.asarray(miss_probability, np.float64), (len(eval_reads),))
    closed = true_detected(eval_reads["gain_db"].to_numpy(np.float64), budget)
    base = {"unit": eval_reads["tag_id"].astype(str).to_numpy()[valid],
            "cell": idx.flat[valid].astype(np.int64),
            "read": eval_reads["read"].to_numpy(bool)[valid],
            "p_true": (closed * (1.0 - q))[valid]}
    dz = None if dz_m is None else np.broadcast_to(np.asarray(dz_m, np.float64), d.shape)[valid]
    parts = [pd.DataFrame({"model": name, **base,
                           "ft": np.asarray(detection_probability(sensors[name], d[valid],
                                                                  a[valid], dz), np.float64)})
             for name in names]
    return _concat(parts, {"model": str, "unit": str, "cell": np.int64, "read": bool,
                           "p_true": float, "ft": float})


def detection_cells(sensors: dict, grid, *, names, eval_reads: pd.DataFrame | None = None,
                    dz_m=None) -> pd.DataFrame:
    """fT at every cell centre of ``grid``, per model: model, cell, ft_centre.

    With the held-out links (`eval_reads` and their tag heights above the antennas
    ``dz_m``), a model that uses the height gets :func:`~.comparison.cell_centre_fT`'s
    mean over each cell's links, as the held-out cell MAE scores it."""
    D, A = grid.centre_mesh()
    cell = np.arange(D.size, dtype=np.int64)
    d = a = None
    if eval_reads is not None and dz_m is not None:
        d = eval_reads["d_true_m"].to_numpy(np.float64)
        a = eval_reads["alpha_true_rad"].to_numpy(np.float64)
    else:
        dz_m = None
    parts = [pd.DataFrame({"model": name, "cell": cell,
                           "ft_centre": cell_centre_fT(sensors[name], grid, None, d, a, dz_m)})
             for name in names]
    return _concat(parts, {"model": str, "cell": np.int64, "ft_centre": float})


def fig7_groups(results: dict) -> pd.DataFrame:
    """The in-domain Fig. 7 groups of each model's :class:`~.fig7.Fig7Result`:
    model, unit (the tag), error_pct [%]."""
    parts = []
    for name, res in results.items():
        t = res.table
        kept = t["in_domain"].to_numpy(bool) & np.isfinite(t["error_pct"].to_numpy(float))
        parts.append(pd.DataFrame({"model": name, "unit": t["tag_id"].astype(str).to_numpy()[kept],
                                   "error_pct": t["error_pct"].to_numpy(np.float64)[kept]}))
    return _concat(parts, {"model": str, "unit": str, "error_pct": float})


def _concat(parts: list, dtypes: dict) -> pd.DataFrame:
    if not parts:
        return pd.DataFrame({k: pd.Series(dtype=v) for k, v in dtypes.items()})
    return pd.concat(parts, ignore_index=True)
