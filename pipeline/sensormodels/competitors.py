"""One entry point for the competitors: fit them all, load any of them.

``fit_competitors`` fits every ``"competitor"`` of the registry
(:data:`~.registry.SENSOR_MODELS`: Joho et al. (2009), Vorst & Zell (2008) and the
project's own sector read region, key ``liu2006``: not a reproduction of the paper the
chapter cites, :mod:`.liu2006`) on the training tour's read attempts within ``d_max_m``
(MCL geometry by default, what the robot knows), with the fuzzy model's RSSI range;
``load_competitor`` reads any of their files, dispatching on its ``"kind"``.
"""

from __future__ import annotations

import pandas as pd

from pipeline.evaluation.cells import CellGrid
from pipeline.sensormodels import registry
from pipeline.sensormodels._common import attempts_from_reads, file_kind, read_model_file

__all__ = ["COMPETITORS", "MODEL_CLASSES", "fit_competitors", "load_competitor"]


def _classes() -> dict:
    """kind -> model class of every competitor of the registry, in study order."""
    return {k: registry.model_info(k).model_class for k in registry.model_names(role="competitor")}


#: Competitor names, in the order :func:`fit_competitors` returns them (the registry's).
COMPETITORS = registry.model_names(role="competitor")
#: kind -> model class.
MODEL_CLASSES = _classes()


def fit_competitors(reads: pd.DataFrame, rssi_range_dbm, *, d_max_m: float,
                    grid: CellGrid | None = None, rng=None, pose: str = "est",
                    dz_m=None, options: dict | None = None) -> dict:
    """Fit every competitor of the registry on one reads table.

    Parameters
    ----------
    reads : pandas.DataFrame
        ``reads.parquet`` of the TRAINING tour (read, rssi_dbm, d_<pose>_m, alpha_<pose>_rad).
    rssi_range_dbm : (float, float)
        The fuzzy model's normalisation range (fs of every model uses it).
    d_max_m : float
        Only attempts with d < d_max_m are used (the training sets' range) [m].
    grid : CellGrid, optional
        Polar cells (the Joho model's); default ``CellGrid(d_max_m=d_max_m)``.
    rng : numpy.random.Generator
        The competitors' random stream (the Vorst model's cross-validation folds),
        drawn in the registry's study order (required).
    pose : {"est", "true"}
        Geometry columns.
    dz_m : array_like (len(reads),) or float
        Each row's tag height above its antenna [m]
        (:func:`~._common.tag_height_differences`): the Vorst & Zell model's table is over
        the horizontal range (required by it: a ValueError without).
    options : dict, optional
        Competitor key -> extra keyword arguments of its fit, over the registry's
        ``fit_options`` (e.g. ``{"liu2006": {"d_step_m": 0.1}}``); an unknown key raises
        ValueError.

    Returns
    -------
    dict
        Key -> fitted model, in the registry's study order (``{"joho2009":
        Joho2009Model, "liu2006": Liu2006Model, "vorst2008": Vorst2008Model}`` by default).
    """
    if rng is None:
        raise ValueError("fit_competitors: pass rng (a numpy Generator, e.g. the stage's)")
    names = registry.model_names(role="competitor")
    options = dict(options or {})
    unknown = sorted(set(options) - set(names))
    if unknown:
        raise ValueError(f"fit_competitors: options for unknown competitors {unknown}; "
                         f"the registry's are {list(names)}")
    att = attempts_from_reads(reads, d_max_m, pose=pose, dz_m=dz_m)
    grid = CellGrid(d_max_m=d_max_m) if grid is None else grid
    infos = [registry.model_info(k) for k in names]
    return {m.key: m.fit(att, rssi_range_dbm, d_max_m=d_max_m, grid=grid, rng=rng,
                         **{**m.fit_options, **options.get(m.key, {})})
            for m in infos}


def load_competitor(path):
    """Read any competitor model file, choosing the class by its ``"kind"``."""
    d = read_model_file(path)
    kind = file_kind(d, str(path))
    classes = _classes()
    cls = classes.get(kind)
    if cls is None:
        raise ValueError(f"{path}: unknown sensor model kind {kind!r}; expected one of "
                         f"{sorted(classes)}")
    return cls.from_dict(d, str(path))
