"""Whether the fitted constructions earn their place: tag-fold cross-validation within the
training tags.

:func:`pipeline.evaluation.calibration.calibrate` fits the reader's parameters alone and,
with :class:`~pipeline.evaluation.calibration.MaterialModel`, the reader and the
constructions' permittivity and conductivity together. Which of the two a calibrated
study should use is a model choice; made on the held-out tags, the held-out score of the
chosen fit would be optimistic (the choice has seen those tags). This module makes it on
the training tags alone, by K-fold cross-validation with the tag the unit (the reads of a
tag are not independent: a fold holds whole tags):

1. the training tags are dealt into ``K`` folds at random (``rng``);
2. for each fold, both fits are refitted on the other folds' attempts (each started from
   its point estimate on all training tags) and predict the fold's attempts;
3. the out-of-fold predictions of every training tag are scored as
   :func:`.simreal.sim_vs_real` scores a prediction (RSSI MAE, Brier score, ...), the two
   fits compared pairwise over the same tags, each difference with its 95 % interval
   (``with_constructions - reader_only``: negative is better for the constructions).

The construction fit's refits use the gains linearised at the point estimate over each
parameter's whole range (calibrate()'s, on the fit), as its bootstrap does: the linearisation is a model of the traced paths, not of the reads, but
it is taken at the theta all training tags chose, so a fold's tags had a say in where the
gains are linearised (a slight optimism, shared by the bootstrap's intervals).
The paired interval resamples the tags' out-of-fold errors as independent; tags of one
fold share a refit and the folds' training sets overlap, so the interval is narrower than
the procedure's own variability (Nadeau & Bengio 2003, "Inference for the generalization
error", Machine Learning 52, 239-281): the choice errs towards laying the constructions
over, which is why :func:`pipeline.stages.calibration._overlay_refusal` also asks for every
fold's refits to converge and the point estimate to be converged and inside its interval.
The rule "one of RSSI MAE and Brier score better, neither worse" takes two correlated
verdicts without a multiplicity correction.
Cross-validation as a model-selection estimate: Stone (1974), "Cross-validatory choice and
assessment of statistical predictions", J. R. Stat. Soc. B 36(2), 111-147; the unit is the
tag, as everywhere in this project's intervals.
"""

from __future__ import annotations

import numpy as np
import pandas as pd

from pipeline.evaluation.calibration import (
    CalibrationFit,
    MaterialModel,
    fit_calibration,
    predict,
    renamed,
)
from pipeline.evaluation.simreal import sim_vs_real
from pipeline.parallel import map_forked

__all__ = ["CV_FOLDS", "CV_QUANTITIES", "crossvalidate_constructions"]

#: Folds of the training tags (each refit sees 80 % of them).
CV_FOLDS = 5
#: The quantities the choice is made on (those :func:`.simreal.sim_vs_real` reports that a
#: calibration changes most: the reads' level and whether a tag is read at all).
CV_QUANTITIES = ("rssi_mae_db", "brier")


def crossvalidate_constructions(att: pd.DataFrame, budget, n_antennas: int, fit: CalibrationFit,
                                model: MaterialModel, *, rng: np.random.Generator, seed: int,
                                folds: int = CV_FOLDS) -> dict:
    """Out-of-fold comparison of the construction fit against the reader's alone (module doc).

    Parameters
    ----------
    att : pandas.DataFrame
        Every attempt given to :func:`~pipeline.evaluation.calibration.calibrate` (its
        ``split`` column picks the training tags; attempts without a traced gain are left
        out, as there).
    fit : CalibrationFit
        ``calibrate``'s fit with constructions; its ``reader_only`` the reader's alone, and
        the training attempts' gains linearised at it, which the refits use.
    model : MaterialModel
        The constructions of ``fit``.
    rng : numpy.random.Generator
        Deals the tags into folds.
    seed : int
        Seeds the intervals' resampling.
    folds : int
        K (at most the number of training tags).

    Returns
    -------
    dict
        ``folds``, ``n_tags``, ``per_fold`` (each fold's tags, whether both refits
        converged, its construction log ratios: beside ``log_ratios_all_tags``, how far a
        fold moves them), ``all_folds_converged``, and per quantity of :data:`CV_QUANTITIES` the
        ``with_constructions`` and ``reader_only`` out-of-fold estimates with intervals and
        their paired ``difference`` (with its verdict), as :func:`.simreal.sim_vs_real`
        gives them.
    """
    if fit.reader_only is None:
        raise ValueError("crossvalidate_constructions: the fit has no reader-only fit beside it "
                         "(calibrate() with a MaterialModel gives both)")
    traced = np.isfinite(att["gain_db"].to_numpy(np.float64))
    is_train = traced & (att["split"].to_numpy() == "train")
    train = att[is_train].reset_index(drop=True)
    tags = train["tag_id"].astype(str).to_numpy()
    units = np.unique(tags)
    k = int(min(folds, len(units)))
    if k < 2:
        raise ValueError(f"crossvalidate_constructions: {len(units)} training tag(s); "
                         "cross-validation needs at least 2")
    fold_of_unit = rng.permutation(np.arange(len(units)) % k)
    fold = fold_of_unit[np.searchsorted(units, tags)]
    terms = fit._terms  # noqa: SLF001 - calibrate()'s linearisation, over the whole range
    if len(terms.base_db) != len(train) or len(terms.at) != len(model.names):
        raise ValueError("crossvalidate_constructions: the fit's linearised gains are of other "
                         "attempts than att's training ones, or of other constructions than "
                         "model's (calibrate()'s att, untraced rows included)")
    start_cons, start_reader = fit._x, fit.reader_only._x  # noqa: SLF001 - our own vectors

    def one_fold(f):
        out, inn = fold == f, fold != f
        fitted = train[inn]
        # with a start vector the miss probability's start is the start's (no keyword)
        cons = fit_calibration(fitted, budget, n_antennas, terms=terms.rows(inn),
                               start=start_cons, strict=False)
        alone = fit_calibration(fitted, budget, n_antennas, start=start_reader, strict=False)
        held = train[out]
        p_c, r_c = predict(cons, held["gain_db"], held["antenna"], budget, terms.rows(out))
        p_a, r_a = predict(alone, held["gain_db"], held["antenna"], budget)
        ok = bool(cons._converged and alone._converged)  # noqa: SLF001 - our own flag
        return np.flatnonzero(out), (p_c, r_c, p_a, r_a), ok, cons.material_log_ratios.tolist()

    cols = {c: np.full(len(train), np.nan) for c in ("p_sim", "rssi_sim_dbm", "p_base", "rssi_base_dbm")}
    per_fold = []
    for rows, values, ok, theta in map_forked(one_fold, k):
        for c, v in zip(cols, values, strict=True):
            cols[c][rows] = v
        per_fold.append({"n_tags": int(np.unique(tags[rows]).size), "converged": ok,
                         "log_ratios": theta})
    cmp = renamed(sim_vs_real(train.assign(**cols), seed=seed), "with_constructions", "reader_only")
    out: dict = {"folds": k, "n_tags": len(units), "unit": "tag", "per_fold": per_fold,
                 "all_folds_converged": all(f["converged"] for f in per_fold),
                 "log_ratios_all_tags": fit.material_log_ratios.tolist()}
    out.update({key: cmp[key] for key in CV_QUANTITIES})
    return out
