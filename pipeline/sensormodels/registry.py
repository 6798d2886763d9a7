"""What each sensor model of a study is called, and which of them predict the same thing.

:data:`MODELS` is the one table of the models' display names: the figures
(:mod:`pipeline.figures.headline`), the report and ``scripts/readme_tables.py`` read their
labels from it. A competitor whose paper was not available in full is labelled
"reconstructed": its module docstring says what is reproduced and what is our choice.

:func:`merge_identical_detection` finds detection models that predict exactly the same
probabilities: on the default study Joho et al. (2009)'s detection part (reads /
attempts per polar cell, nearest-cell fill) is the Hähnel et al. (2004) grid count, bit
for bit; scored twice, it would be one loser counted as two. Such a model is scored
once, under the first name, and the merge is recorded in ``metrics.json``.
"""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass

import numpy as np

__all__ = ["MODELS", "ModelInfo", "merge_identical_detection", "model_label"]


@dataclass(frozen=True)
class ModelInfo:
    """One sensor model of a study.

    Attributes
    ----------
    key : str
        Its name in ``metrics.json``, the unit tables and ``models/``.
    label : str
        Display name in figures, reports and the README's tables.
    kind : str
        ``"both"`` (RSSI and detection), ``"rssi"`` or ``"detection"``.
    reconstructed : bool
        A competitor rebuilt from an incomplete source (the label says so).
    """

    key: str
    label: str
    kind: str = "both"
    reconstructed: bool = False


#: The study's models, in the order tables list them.
MODELS: dict[str, ModelInfo] = {m.key: m for m in (
    ModelInfo("anfis", "FCM + ANFIS, MCL poses (the chapter's)"),
    ModelInfo("anfis_truepose", "FCM + ANFIS, true poses"),
    ModelInfo("fcm_only", "FIS from FCM, no ANFIS"),
    ModelInfo("anfis_gridinit", "ANFIS from a grid partition"),
    ModelInfo("joho2009", "after Joho et al. 2009 (reconstructed)", "both", True),
    ModelInfo("log_distance", "log-distance + pattern", "rssi"),
    ModelInfo("grid_count", "grid count after Hähnel et al. 2004 (reconstructed)", "detection",
              True),
    ModelInfo("liu2006", "sector read region, project's own", "detection"),
    ModelInfo("vorst2008", "after Vorst & Zell 2008 (reconstructed)", "detection", True),
    ModelInfo("phase", "reader phase alone", "detection"),
    ModelInfo("phase_anfis", "reader phase x ANFIS"),
    ModelInfo("oracle", "ray-traced oracle"),
)}


def model_label(key: str) -> str:
    """Display name of a model (its key where it has none)."""
    info = MODELS.get(key)
    return info.label if info else key


def merge_identical_detection(sensors: dict, names: Iterable[str], d_m, alpha_rad
                              ) -> tuple[tuple[str, ...], dict[str, str]]:
    """Drop detection models whose predictions equal an earlier one's everywhere probed.

    Parameters
    ----------
    sensors : dict[str, SensorLike]
        Models by name (each with ``fT(d, alpha)``).
    names : iterable of str
        The detection models to score, in order (the first of identical ones stays).
    d_m, alpha_rad : array_like, float64, (n,)
        Where to compare them: the held-out links' distances [m] and bearings [rad],
        and any grid of cells the scores use.

    Returns
    -------
    kept : tuple of str
    merged : dict[str, str]
        Each dropped model -> the model it is identical to.
    """
    d = np.asarray(d_m, np.float64)
    a = np.asarray(alpha_rad, np.float64)
    kept: list[str] = []
    preds: dict[str, np.ndarray] = {}
    merged: dict[str, str] = {}
    for n in names:
        p = np.asarray(sensors[n].fT(d, a), np.float64)
        twin = next((k for k in kept if np.array_equal(preds[k], p, equal_nan=True)), None)
        if twin is not None and d.size:
            merged[n] = twin
            continue
        kept.append(n)
        preds[n] = p
    return tuple(kept), merged
