"""Held-out scores: every model and the floor on data no model saw, and the error budget.

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
    ``fT(d_true, alpha_true)`` on the held-out read outcomes.
Floor (fitted on TRAINING data only)
    The best any (d, alpha) cell model can do at the grid's resolution, learned from the
    training tour: each held-out link predicted by the mean noise-free RSSI of its cell
    in the training truth (:func:`~.comparison.rssi_cell_mean_floor` with the training
    :class:`~.truth.TruthGrid`), and each held-out attempt's read probability by the
    training truth's cell ``p_detect``.

The error budget (:func:`error_budget`) splits the learned model's held-out RSSI error.
"""

from __future__ import annotations

import numpy as np
import pandas as pd

from .comparison import closing_links, detection_vs_truth, rssi_cell_mean_floor, rssi_vs_truth
from .metrics import brier_score, error_stats, nan_to_none
from .tables import require_columns
from .truth import TruthGrid, true_detected, true_rssi_dbm

__all__ = ["detection_floor", "error_budget", "floor_link_mask", "heldout_scores",
           "reader_noise_stats"]


def detection_floor(eval_reads: pd.DataFrame, train_truth: TruthGrid, eval_truth: TruthGrid,
                    min_attempts: int = 5) -> dict:
    """Detection scores of the training truth's cell probabilities on held-out data.

    Parameters
    ----------
    eval_reads : pandas.DataFrame
        Held-out read attempts (read, d_true_m, alpha_true_rad).
    train_truth : TruthGrid
        :func:`~.truth.detection_truth` of the TRAINING reads: the predictor.
    eval_truth : TruthGrid
        The same of the held-out reads: the target of the cell MAE (same grid).
    min_attempts : int
        Cells with fewer attempts in either grid are not compared.

    Returns
    -------
    dict
        ``mae``, ``rmse``, ``bias`` (cells), ``n_cells``, ``brier`` (attempts whose cell
        the training truth covers), ``n_attempts``.
    """
    require_columns(eval_reads, ("read", "d_true_m", "alpha_true_rad"), "eval reads")
    if train_truth.grid.to_dict() != eval_truth.grid.to_dict():
        raise ValueError("detection_floor: training and held-out truth grids differ")
    ok = (train_truth.n_attempts >= min_attempts) & (eval_truth.n_attempts >= min_attempts)
    cells = error_stats(train_truth.p_detect[ok], eval_truth.p_detect[ok])
    idx = train_truth.grid.index(eval_reads["d_true_m"].to_numpy(float),
                                 eval_reads["alpha_true_rad"].to_numpy(float))
    flat = np.maximum(idx.flat, 0)
    covered = idx.valid & (train_truth.n_attempts.ravel()[flat] >= min_attempts)
    p = train_truth.p_detect.ravel()[flat[covered]]
    outcome = eval_reads["read"].to_numpy(bool)[covered]
    return {"mae": cells.mae, "rmse": cells.rmse, "bias": cells.bias, "n_cells": int(ok.sum()),
            "brier": brier_score(p, outcome), "n_attempts": int(covered.sum())}


def floor_link_mask(eval_reads: pd.DataFrame, train_truth: TruthGrid, budget, d_max_m: float,
                    min_count: int) -> np.ndarray:
    """Rows of `eval_reads` the floor can score: closing links within ``d_max_m`` whose
    (d, alpha) cell holds at least ``min_count`` closing links in the TRAINING truth
    (:func:`~.comparison.rssi_cell_mean_floor`'s own selection), shape (n_rows,) bool."""
    keep = closing_links(eval_reads, budget, d_max_m)
    d = eval_reads["d_true_m"].to_numpy(float)
    idx = train_truth.grid.index(d, eval_reads["alpha_true_rad"].to_numpy(float))
    covered = idx.valid & (train_truth.n_closed.ravel()[np.maximum(idx.flat, 0)] >= int(min_count))
    return keep & covered


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
                   rssi_models=None, detection_models=None) -> dict:
    """RSSI and detection scores of every model and of the floor on held-out reads.

    Parameters
    ----------
    sensors : dict of str -> SensorLike
        Models by name (``anfis``, ``anfis_truepose``, ``log_distance``, ``grid_count``, ...).
    eval_reads : pandas.DataFrame
        The evaluation tour's reads of the held-out tags.
    train_truth, eval_truth : TruthGrid
        Truth grids of the training and of the held-out reads (same cells).
    budget : propagation.LinkBudget
    d_max_m : float
        Distance limit of the RSSI comparison (the models' training domain) [m].
    min_attempts : int
        Cells with fewer attempts are not compared.
    rssi_models, detection_models : collection of str, optional
        Names scored on RSSI / on detection (default: all); the others get None there
        (a log-distance fit predicts no detection, a grid count no RSSI).

    Returns
    -------
    dict
        ``{"models": {name: {"rssi_dbm": dict | None, "detection": dict | None}},
        "floor": {...}, "data": {...}}``, NaN as None.
    """
    names = list(sensors)
    rssi_models = set(names if rssi_models is None else rssi_models)
    detection_models = set(names if detection_models is None else detection_models)
    models = {}
    on_floor = eval_reads.loc[floor_link_mask(eval_reads, train_truth, budget, d_max_m,
                                              min_attempts)]
    for name, s in sensors.items():
        models[name] = {
            "rssi_dbm": (rssi_vs_truth(eval_reads, s, budget, d_max_m=d_max_m).to_dict()
                         if name in rssi_models else None),
            # the same model on exactly the links the floor scores (matched comparison)
            "rssi_dbm_floor_links": (rssi_vs_truth(on_floor, s, budget, d_max_m=d_max_m).to_dict()
                                     if name in rssi_models else None),
            "detection": (detection_vs_truth(eval_reads, s, eval_truth,
                                             min_attempts=min_attempts).to_dict()
                          if name in detection_models else None),
        }
    floor = {
        "rssi_dbm": rssi_cell_mean_floor(eval_reads, train_truth, budget, d_max_m=d_max_m,
                                         min_count=min_attempts).to_dict(),
        "detection": detection_floor(eval_reads, train_truth, eval_truth, min_attempts),
        "how": "training truth's (d, alpha) cell means (noise-free RSSI, p_detect) applied to "
               "the held-out links; fitted on training data only",
    }
    data = {
        "n_attempts": int(len(eval_reads)),
        "n_reads": int(eval_reads["read"].sum()),
        "n_tags": int(eval_reads["tag_id"].nunique()) if "tag_id" in eval_reads else None,
        "d_max_m": float(d_max_m),
        "reader_noise": reader_noise_stats(eval_reads, budget, d_max_m),
    }
    return nan_to_none({"models": models, "floor": floor, "data": data})


def error_budget(heldout: dict, est: str = "anfis", true: str = "anfis_truepose") -> dict:
    """Split the learned model's held-out RSSI RMSE into its sources.

    Each term is a held-out RMSE [dB] against the noise-free truth, all of them (but the
    reader noise and the total) on the SAME links: those the floor can score (a training
    cell with enough closing links; ``n_links``), and its increment over the term before it (``step_db``, plain difference; ``step_quadrature_db`` =
    sqrt(b^2 - a^2) when b > a, the part that adds independently):

    1. ``reader_noise``: reported RSSI against noise-free RSSI (noise + quantisation);
       what any comparison with measured RSSI carries on top of the terms below;
    2. ``representation``: the floor, the training truth's (d, alpha) cell mean: what a
       model of (d, alpha) alone cannot represent (multipath fading with position);
    3. ``model_form``: the model trained on TRUE poses against the floor: what the
       three-rule Takagi-Sugeno form and its training lose;
    4. ``localisation``: the model trained on MCL poses against the true-pose model:
       what the robot's pose error costs.

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
    noise = rmse(heldout["data"]["reader_noise"])
    floor = rmse(heldout["floor"]["rssi_dbm"])
    # matched: every term on the links the floor scores (cells the training truth covers)
    t = rmse(m.get(true, {}).get("rssi_dbm_floor_links"))
    e = rmse(m.get(est, {}).get("rssi_dbm_floor_links"))
    n_links = (heldout["floor"]["rssi_dbm"] or {}).get("n")

    def step(a, b):
        if a is None or b is None:
            return None, None
        return float(b - a), float(np.sqrt(b * b - a * a)) if b > a else 0.0

    out = {"reader_noise": {"rmse_db": noise, "how": "held-out reads: reported rssi_dbm - "
                                                     "noise-free RSSI (1 dB noise, quantisation)"},
           "representation": {"rmse_db": floor, "how": "floor: training truth's (d, alpha) cell "
                                                       "mean on the held-out links"}}
    for key, (a, b, how) in {
        "model_form": (floor, t, f"{true} (trained on true poses) against the floor"),
        "localisation": (t, e, f"{est} (trained on MCL poses) against {true}"),
    }.items():
        s, sq = step(a, b)
        out[key] = {"rmse_db": b, "step_db": s, "step_quadrature_db": sq, "how": how}
    out["total"] = {"rmse_db": rmse(m.get(est, {}).get("rssi_dbm")),
                    "how": f"{est} held-out RSSI RMSE against the noise-free truth, all links"}
    out["n_links"] = {"value": n_links, "how": "links of the matched terms (representation, "
                      "model form, localisation): held-out closing links whose training cell "
                      "holds enough closing links for a cell mean"}
    return nan_to_none(out)
