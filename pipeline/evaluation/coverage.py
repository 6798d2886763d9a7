"""Detection coverage of a ray-traced field plane: where a tag would be read.

A cell of the planar RSSI field (``propagation.RssiField``) is *covered* when the
probability of reading a tag there exceeds one half: the backscatter link closes
(``LinkBudget.detected``: tag power >= tag sensitivity and RSSI >= reader
sensitivity, docs/physics.md "The backscatter link") and the reader's anti-collision
miss probability q leaves ``1 - q > 0.5`` (q: the ``"fixed"`` reader's constant, or the
Gen2 reader's for a tag joining the field pose's antenna slot,
:func:`pipeline.acquisition.singulation.miss_probability_at_poses`). The field's gain is the reader side
only (an isotropic receiver), so the tag antenna's gain
``budget.tag_antenna_gain_dbi`` is added before the budget decides.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from pipeline.evaluation.truth import check_miss_probability

__all__ = ["CoverageResult", "detection_coverage"]


@dataclass(frozen=True)
class CoverageResult:
    """Coverage of one field plane.

    Attributes
    ----------
    fraction : float
        Covered cells / cells considered, in [0, 1] (0 when no cell is considered).
    n_cells : int
        Cells considered (inside free space where a mask was given).
    n_covered : int
        Cells with detection probability > 0.5.
    """

    fraction: float
    n_cells: int
    n_covered: int

    def to_dict(self) -> dict:
        """JSON-able dict of the three fields."""
        return {"fraction": self.fraction, "n_cells": self.n_cells, "n_covered": self.n_covered}


def detection_coverage(plane_gain_db, budget, free=None,
                       miss_probability=0.0) -> CoverageResult:
    """Fraction of field cells where a tag is read with probability > 0.5.

    Parameters
    ----------
    plane_gain_db : array_like, float64, any shape
        One-way channel gain per cell, reader pattern included, isotropic receiver
        [dB]; -inf where no ray arrived.
    budget : propagation.LinkBudget
        Link budget; its ``tag_antenna_gain_dbi`` is added to the gain and its
        ``detected`` applies both thresholds.
    free : array_like of bool, same shape, optional
        Cells to consider (e.g. those inside the scene's free space); all if None.
    miss_probability : float or array_like, same shape as ``plane_gain_db``
        Anti-collision miss probability q in [0, 1) of a closed link (read with
        probability ``1 - q``): one for the plane or one per cell.

    Returns
    -------
    CoverageResult
    """
    g = np.asarray(plane_gain_db, dtype=np.float64).ravel()
    mask = np.ones(g.shape, bool) if free is None else np.asarray(free, dtype=bool).ravel()
    if mask.shape != g.shape:
        raise ValueError(f"free has {mask.size} cells, plane_gain_db has {g.size}")
    q = check_miss_probability(miss_probability, np.shape(plane_gain_db), "one per cell")
    q = q if np.ndim(q) == 0 else np.asarray(q).ravel()[mask]
    with np.errstate(invalid="ignore"):
        closed = np.asarray(budget.detected(g[mask] + budget.tag_antenna_gain_dbi), dtype=bool)
    covered = closed & ((1.0 - q) > 0.5)
    n = int(covered.size)
    return CoverageResult(fraction=float(covered.mean()) if n else 0.0, n_cells=n,
                          n_covered=int(covered.sum()))
