"""One entry point for the competitors: fit them all, load any of them.

``fit_competitors`` fits Joho et al. (2009), Vorst & Zell (2008) and the project's own
sector read region (key ``liu2006``: not a reproduction of the paper the chapter cites,
:mod:`.liu2006`) on the training tour's read attempts within ``d_max_m`` (MCL geometry by default, what
the robot knows), with the fuzzy model's RSSI range; ``load_competitor`` reads any of
their files, dispatching on its ``"kind"``.
"""

from __future__ import annotations

import pandas as pd

from pipeline.evaluation.cells import CellGrid
from pipeline.sensormodels._common import attempts_from_reads, file_kind, read_model_file
from pipeline.sensormodels.joho2009 import JOHO2009, Joho2009Model, fit_joho2009
from pipeline.sensormodels.liu2006 import LIU2006, Liu2006Model, fit_liu2006
from pipeline.sensormodels.vorst2008 import VORST2008, Vorst2008Model, fit_vorst2008

__all__ = ["COMPETITORS", "MODEL_CLASSES", "fit_competitors", "load_competitor"]

#: Competitor names, in the order :func:`fit_competitors` returns them.
COMPETITORS = (JOHO2009, LIU2006, VORST2008)
#: kind -> model class.
MODEL_CLASSES = {JOHO2009: Joho2009Model, LIU2006: Liu2006Model, VORST2008: Vorst2008Model}


def fit_competitors(reads: pd.DataFrame, rssi_range_dbm, *, d_max_m: float,
                    grid: CellGrid | None = None, rng=None, pose: str = "est",
                    dz_m=None, joho: dict | None = None, liu: dict | None = None,
                    vorst: dict | None = None) -> dict:
    """Fit the three paper competitors on one reads table.

    Parameters
    ----------
    reads : pandas.DataFrame
        ``reads.parquet`` of the TRAINING tour (read, rssi_dbm, d_<pose>_m, alpha_<pose>_rad).
    rssi_range_dbm : (float, float)
        The fuzzy model's normalisation range (fs of every model uses it).
    d_max_m : float
        Only attempts with d < d_max_m are used (the training sets' range) [m].
    grid : CellGrid, optional
        Polar cells of the Joho model; default ``CellGrid(d_max_m=d_max_m)``.
    rng : numpy.random.Generator
        Cross-validation folds of the Vorst model (required).
    pose : {"est", "true"}
        Geometry columns.
    dz_m : array_like (len(reads),) or float
        Each row's tag height above its antenna [m]
        (:func:`~._common.tag_height_differences`): the Vorst & Zell model's table is over
        the horizontal range (required by it: a ValueError without).
    joho, liu, vorst : dict, optional
        Extra keyword arguments of :func:`fit_joho2009`, :func:`fit_liu2006`,
        :func:`fit_vorst2008`.

    Returns
    -------
    dict
        ``{"joho2009": Joho2009Model, "liu2006": Liu2006Model, "vorst2008": Vorst2008Model}``.
    """
    if rng is None:
        raise ValueError("fit_competitors: pass rng (a numpy Generator, e.g. the stage's)")
    att = attempts_from_reads(reads, d_max_m, pose=pose, dz_m=dz_m)
    grid = CellGrid(d_max_m=d_max_m) if grid is None else grid
    return {
        JOHO2009: fit_joho2009(att, rssi_range_dbm, grid, **(joho or {})),
        LIU2006: fit_liu2006(att, rssi_range_dbm, d_max_m=d_max_m, **(liu or {})),
        VORST2008: fit_vorst2008(att, rssi_range_dbm, rng, d_max_m=d_max_m, **(vorst or {})),
    }


def load_competitor(path):
    """Read any competitor model file, choosing the class by its ``"kind"``."""
    d = read_model_file(path)
    kind = file_kind(d, str(path))
    cls = MODEL_CLASSES.get(kind)
    if cls is None:
        raise ValueError(f"{path}: unknown sensor model kind {kind!r}; expected one of "
                         f"{sorted(MODEL_CLASSES)}")
    return cls.from_dict(d, str(path))
