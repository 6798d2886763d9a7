"""Held-out scores: every model and the oracle bound on data no model saw, and the error budget.

The evaluation tour reads a tag layout the training tour never read (``scene/tags.parquet``
column ``split``), on its own MCL run in the same map. Every number here is computed on
those reads (``eval_reads``) against the noise-free ray-traced truth:

RSSI (per model that predicts RSSI)
    :func:`~.comparison.rssi_vs_truth` on the held-out attempts whose noise-free link
    closes, with the true distance below ``d_max_m``: model ``fs_dbm(d_true, alpha_true)``
    against the noise-free RSSI [dB].
Detection (per model that predicts fT)
    :func:`~.comparison.detection_vs_truth`: fT at the cell centres against the held-out
    truth's detection probability per (d, alpha) cell (MAE), and the Brier score of
    ``fT(d_true, alpha_true)`` on the held-out read outcomes; a model that uses the tag's
    height above the antenna is given each link's (``dz_m``).
Bound (an oracle on the held-out data itself, not a model)
    The held-out truth's own (d, alpha) cell means on its own links
    (:func:`~.bound.cell_mean_bound`, cells of the truth grid holding at least
    ``min_attempts`` closing links): no function constant on those cells has a lower RSSI
    RMSE on those links, and every RSSI model is also scored on exactly them
    (``rssi_dbm_bound_links``) with its excess split into a between-cell term (>= 0) and
    a signed within-cell term (``bound_excess``, :func:`~.bound.excess_over_bound`); the
    bound at other cell sizes is in ``by_cell_size``. For detection, the held-out cell
    frequencies' own Brier score (no function constant on the cells has a lower one on
    those attempts).

The error budget (:func:`error_budget`) splits the learned model's held-out RSSI error.
"""

from __future__ import annotations

import numpy as np
import pandas as pd

from pipeline.evaluation.bound import bound_by_cell_size, cell_mean_bound, excess_over_bound
from pipeline.evaluation.comparison import detection_vs_truth, rssi_vs_truth
from pipeline.evaluation.metrics import brier_score, error_stats, nan_to_none
from pipeline.evaluation.tables import require_columns
from pipeline.evaluation.truth import TruthGrid, true_detected, true_rssi_dbm

__all__ = ["detection_bound", "error_budget", "heldout_scores", "reader_noise_stats"]


def detection_bound(eval_reads: pd.DataFrame, eval_truth: TruthGrid,
                    min_attempts: int = 5) -> dict:
    """Brier score of the held-out truth's own cell read frequencies on its own attempts.

    The frequency of reads in a cell minimises the Brier score among forecasts constant on
    the cell, so no cell model scores lower on these attempts: an oracle bound.

    Parameters
    ----------
    eval_reads : pandas.DataFrame
        Held-out read attempts (read, d_true_m, alpha_true_rad).
    eval_truth : TruthGrid
        :func:`~.truth.detection_truth` of the same reads.
    min_attempts : int
        Attempts in cells with fewer are left out.

    Returns
    -------
    dict
        ``brier``, ``n_attempts``, ``n_cells``.
    """
    require_columns(eval_reads, ("read", "d_true_m", "alpha_true_rad"), "eval reads")
    idx = eval_truth.grid.index(eval_reads["d_true_m"].to_numpy(float),
                                eval_reads["alpha_true_rad"].to_numpy(float))
    flat = np.maximum(idx.flat, 0)
    ok = idx.valid & (eval_truth.n_attempts.ravel()[flat] >= int(min_attempts))
    read = eval_reads["read"].to_numpy(bool)[ok]
    cell = flat[ok]
    _, inv, count = np.unique(cell, return_inverse=True, return_counts=True)
    freq = (np.bincount(inv.reshape(-1), weights=read.astype(float)) / count)[inv.reshape(-1)]
    return {"brier": brier_score(freq, read) if read.size else float("nan"),
            "n_attempts": int(ok.sum()), "n_cells": int(count.size)}


def reader_noise_stats(eval_reads: pd.DataFrame, budget, d_max_m: float) -> dict:
    """Reported RSSI against the noise-free RSSI on held-out reads (reader noise + quantisation).

    Returns
    -------
    dict
        ErrorStats of ``rssi_dbm - noise-free RSSI`` [dB] over reads within ``d_max_m``.
    """
    require_columns(eval_reads, ("read", "rssi_dbm", "gain_db", "d_true_m"), "eval reads")
    g = eval_reads["gain_db"].to_numpy(float)
    keep = (eval_reads["read"].to_numpy(bool) & true_detected(g, budget)
            & (eval_reads["d_true_m"].to_numpy(float) < d_max_m))
    meas = eval_reads["rssi_dbm"].to_numpy(float)[keep]
    return error_stats(meas, true_rssi_dbm(g[keep], budget)).to_dict()


def heldout_scores(sensors: dict, eval_reads: pd.DataFrame, train_truth: TruthGrid,
                   eval_truth: TruthGrid, budget, *, d_max_m: float, min_attempts: int,
                   rssi_models=None, detection_models=None, dz_m=None) -> dict:
    """RSSI and detection scores of every model and the oracle bound on held-out reads.

    Parameters
    ----------
    sensors : dict of str -> SensorLike
        Models by name (``anfis``, ``anfis_truepose``, ``log_distance``, ``grid_count``, ...).
    eval_reads : pandas.DataFrame
        The evaluation tour's reads of the held-out tags.
    train_truth, eval_truth : TruthGrid
        Truth grids of the training and of the held-out reads (same cells); the bound
        uses the held-out one's cells.
    budget : propagation.LinkBudget
    d_max_m : float
        Distance limit of the RSSI comparison (the models' training domain) [m].
    min_attempts : int
        Cells with fewer attempts are not compared.
    rssi_models, detection_models : collection of str, optional
        Names scored on RSSI / on detection (default: all); the others get None there
        (a log-distance fit predicts no detection, a grid count no RSSI).
    dz_m : array_like (len(eval_reads),), optional
        Each link's tag height above its true antenna [m]; a model that uses it (Vorst &
        Zell's ground-plane table) is scored on detection with it
        (:func:`~.comparison.detection_vs_truth`).

    Returns
    -------
    dict
        ``{"models": {name: {"rssi_dbm", "rssi_dbm_bound_links", "bound_excess",
        "detection"}}, "bound": {...}, "data": {...}}`` (None where a model predicts no
        such quantity), NaN as None.
    """
    names = list(sensors)
    rssi_models = set(names if rssi_models is None else rssi_models)
    detection_models = set(names if detection_models is None else detection_models)
    bound = cell_mean_bound(eval_reads, eval_truth.grid, budget, d_max_m=d_max_m,
                            min_count=min_attempts)
    on_bound = eval_reads.loc[bound.rows]
    models = {}
    for name, s in sensors.items():
        scored = name in rssi_models
        excess = None
        if scored and bound.n_links:
            pred = np.asarray(s.fs_dbm(on_bound["d_true_m"].to_numpy(float),
                                       on_bound["alpha_true_rad"].to_numpy(float)), float)
            if np.all(np.isfinite(pred)):
                excess = excess_over_bound(bound, pred).to_dict()
        models[name] = {
            "rssi_dbm": (rssi_vs_truth(eval_reads, s, budget, d_max_m=d_max_m).to_dict()
                         if scored else None),
            # the same model on exactly the bound's links (matched comparison)
            "rssi_dbm_bound_links": (rssi_vs_truth(on_bound, s, budget, d_max_m=d_max_m).to_dict()
                                     if scored and bound.n_links else None),
            "bound_excess": excess,
            "detection": (detection_vs_truth(eval_reads, s, eval_truth,
                                             min_attempts=min_attempts, dz_m=dz_m).to_dict()
                          if name in detection_models else None),
        }
    bound_out = {
        # RMSE (and bias) of the cell means, MAE of the cell medians: each the least a
        # function constant on the cells can reach in its own metric
        "rssi_dbm": {**error_stats(bound.cell_mean_dbm, bound.truth_dbm).to_dict(),
                     "mae": bound.mae_db},
        "cells": bound.to_dict(),
        "by_cell_size": {f"x{row['scale']:g}": row for row in bound_by_cell_size(
            eval_reads, eval_truth.grid, budget, d_max_m=d_max_m, min_count=min_attempts,
            models={n: sensors[n] for n in names if n in rssi_models})},
        "detection": detection_bound(eval_reads, eval_truth, min_attempts),
        "how": "oracle, not a model: the held-out truth's own (d, alpha) cell means (noise-free "
               "RSSI; read frequency) on its own links, cells with >= min_attempts of them; no "
               "function constant on those cells scores better on those links (RMSE: cell "
               "means; MAE: cell medians; other statistics are the cell means', not bounds)",
    }
    data = {
        "n_attempts": int(len(eval_reads)),
        "n_reads": int(eval_reads["read"].sum()),
        "n_tags": int(eval_reads["tag_id"].nunique()) if "tag_id" in eval_reads else None,
        "d_max_m": float(d_max_m),
        "reader_noise": reader_noise_stats(eval_reads, budget, d_max_m),
    }
    return nan_to_none({"models": models, "bound": bound_out, "data": data})


def error_budget(heldout: dict, est: str = "anfis", true: str = "anfis_truepose") -> dict:
    """Split the learned model's held-out RSSI RMSE into its sources.

    Terms, each a held-out RMSE [dB] against the noise-free truth, the matched ones on the
    SAME links (the bound's: closing held-out links in (d, alpha) cells holding at least
    ``min_attempts`` of them, ``n_links``):

    1. ``reader_noise``: reported RSSI against noise-free RSSI (noise + quantisation);
       what any comparison with measured RSSI carries on top of the terms below;
    2. ``representation_bound``: the held-out truth's own (d, alpha) cell mean on its own
       links (an oracle, not a model, :mod:`~.bound`): no function constant on the cells
       does better on these links, i.e. what the cells' (d, alpha) cannot tell apart
       (multipath fading with position); ``by_cell_size`` shows how it falls with smaller
       cells;
    3. ``model_form``: the model trained on TRUE poses on the same links, its excess over
       the bound split exactly into ``between_cells_db`` (its cell means against the
       truth's; >= 0 by construction) and ``within_cells_db2`` (signed: negative where
       the model follows the truth inside a cell, which no cell model can);
    4. ``localisation``: the model trained on MCL poses against the true-pose model on
       the same links (``step_db``: a signed difference, not a bound: the two models
       are fitted on different poses and neither bounds the other).

    Parameters
    ----------
    heldout : dict
        :func:`heldout_scores` output.
    est, true : str
        Names of the MCL-pose and true-pose models.

    Returns
    -------
    dict
    """
    def rmse(x):
        return None if x is None else x.get("rmse")

    m = heldout["models"]
    b = heldout["bound"]
    cells = b.get("cells") or {}
    t_ex = m.get(true, {}).get("bound_excess") or {}
    e = rmse(m.get(est, {}).get("rssi_dbm_bound_links"))
    t = rmse(m.get(true, {}).get("rssi_dbm_bound_links"))
    out = {
        "reader_noise": {"rmse_db": rmse(heldout["data"]["reader_noise"]),
                         "how": "held-out reads: reported rssi_dbm - noise-free RSSI (1 dB "
                                "noise, quantisation)"},
        "representation_bound": {
            "rmse_db": cells.get("rmse_db"), "d_bin_m": cells.get("d_bin_m"),
            "alpha_bin_deg": cells.get("alpha_bin_deg"), "n_cells": cells.get("n_cells"),
            "how": "oracle bound: the held-out truth's own (d, alpha) cell mean on its own "
                   "links; no function constant on these cells does better on them"},
        "by_cell_size": {k: {"rmse_db": v.get("rmse_db"), "d_bin_m": v.get("d_bin_m"),
                             "alpha_bin_deg": v.get("alpha_bin_deg"), "n_links": v.get("n_links"),
                             f"{est}_rmse_db": v.get(f"{est}_rmse_db")}
                         for k, v in (b.get("by_cell_size") or {}).items()},
        "model_form": {"rmse_db": t, "between_cells_db": t_ex.get("between_cells_db"),
                       "within_cells_db2": t_ex.get("within_cells_db2"),
                       "how": f"{true} (trained on true poses) on the bound's links: RMSE^2 = "
                              "bound^2 + between^2 + within (between >= 0; within signed)"},
        "localisation": {"rmse_db": e, "step_db": None if (e is None or t is None) else
                         float(e - t),
                         "how": f"{est} (trained on MCL poses) against {true} on the same "
                                "links: a signed difference, not a bound"},
        "total": {"rmse_db": rmse(m.get(est, {}).get("rssi_dbm")),
                  "how": f"{est} held-out RSSI RMSE against the noise-free truth, all links"},
        "n_links": {"value": cells.get("n_links"),
                    "how": "links of the matched terms: held-out closing links in (d, alpha) "
                           "cells holding at least min_attempts of them"},
    }
    return nan_to_none(out)
