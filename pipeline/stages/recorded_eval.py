"""Stage ``recorded_eval``: every model on the held-out tags' recorded reads -> ``metrics.json``.

A recording has no noise-free truth: each model is scored against what the reader
measured on the held-out tags (``eval_reads.parquet``), on the recorded poses:

- RSSI: ``fs_dbm(d, alpha)`` minus the measured RSSI of each held-out read within
  ``training.d_max_m`` (MAE, RMSE, |bias| [dB]);
- detection: the Brier score of ``fT(d, alpha)`` on the held-out attempts inside the
  models' (d, alpha) grid, and the cell MAE of ``fT`` at the cell centres against the
  cells' measured read frequencies.

The per-unit tables go to ``evaluation/`` (:mod:`pipeline.evaluation.units`, the held-out
tag the unit) and every number gets its interval over tags and its paired comparison
with the chapter's ANFIS (:func:`pipeline.evaluation.headline.headline_intervals`).
``metrics.json`` holds ``source = "recording"``, ``heldout`` (estimates, against
``"measured"``), ``intervals``, ``comparisons``, ``recording`` (what the import
counted), ``sim_vs_real`` (:mod:`pipeline.stages.sim_vs_real`), ``calibration``
(:mod:`pipeline.stages.calibration`) and ``model_fits``; with the downstream stage on,
``tag_localisation`` and ``robot_localisation`` as a simulated study's evaluation stage
copies them (:mod:`pipeline.stages.downstream`: the held-out tags localised against the
recording's tag layout; the robot's a sentence saying why it was not run), the tags'
errors among the intervals' tables (``tag_localisation.*``, over held-out tags).
"""

from __future__ import annotations

import json

import numpy as np
import pandas as pd

from pipeline import runfiles
from pipeline.engine.runstore import atomic_write_json
from pipeline.engine.study import Stage
from pipeline.evaluation import units as u
from pipeline.evaluation.cells import CellGrid
from pipeline.evaluation.headline import headline_estimates, headline_intervals
from pipeline.evaluation.interface import detection_probability
from pipeline.evaluation.tables import write_parquet_atomic
from pipeline.runfiles import STAGE_OUTPUTS
from pipeline.sensormodels import tag_height_differences
from pipeline.sensormodels.registry import stage_version
from pipeline.stages.common import read_reads, split_tags
from pipeline.stages.evaluation import model_fits, study_models

__all__ = ["STAGE", "recorded_unit_tables", "stage_recorded_eval"]


def recorded_unit_tables(eval_reads: pd.DataFrame, sensors: dict, grid, *, d_max_m: float,
                         rssi_names, detection_names, dz_m=None):
    """The :class:`~pipeline.evaluation.units.UnitTables` of a recording (module doc):
    ``rssi_links`` error_db = predicted - measured, ``detection_attempts`` with
    ``p_true`` the measured outcome (so a cell's mean is its read frequency)."""
    d = eval_reads["d_est_m"].to_numpy(np.float64)
    a = eval_reads["alpha_est_rad"].to_numpy(np.float64)
    read = eval_reads["read"].to_numpy(bool)
    unit = eval_reads["tag_id"].astype(str).to_numpy()
    meas = eval_reads["rssi_dbm"].to_numpy(np.float64)
    keep = read & (d < d_max_m) & np.isfinite(meas)
    rssi = pd.concat([pd.DataFrame({"model": n, "unit": unit[keep],
                                    "error_db": np.asarray(sensors[n].fs_dbm(d[keep], a[keep]),
                                                           np.float64) - meas[keep]})
                      for n in rssi_names], ignore_index=True)
    idx = grid.index(d, a)
    v = idx.valid
    dz = None if dz_m is None else np.asarray(dz_m, np.float64)[v]
    det = pd.concat([pd.DataFrame({"model": n, "unit": unit[v], "cell": idx.flat[v].astype(np.int64),
                                   "read": read[v], "p_true": read[v].astype(np.float64),
                                   "ft": np.asarray(detection_probability(sensors[n], d[v], a[v], dz),
                                                    np.float64)})
                     for n in detection_names], ignore_index=True)
    cells = u.detection_cells(sensors, grid, names=detection_names)
    empty = pd.DataFrame({"model": pd.Series(dtype=str), "unit": pd.Series(dtype=str),
                          "error_pct": pd.Series(dtype=float)})
    return u.UnitTables(rssi_links=rssi, detection_attempts=det, detection_cells=cells,
                        fig7_groups=empty)


def stage_recorded_eval(ctx) -> dict:
    """Score every model on the held-out recorded reads; write ``metrics.json`` (module doc)."""
    cfg = ctx.config
    tr = cfg.training
    eval_reads, _ = read_reads(ctx, "eval_")
    sensors, rssi_names, det_names, competitors = study_models(ctx, "recorded")
    grid = CellGrid(d_max_m=tr.d_max_m, d_bin_m=tr.d_bin_m, alpha_bin_deg=tr.alpha_bin_deg)
    dz = tag_height_differences(eval_reads, split_tags(ctx, "eval"), pose="est")
    tables = recorded_unit_tables(eval_reads, sensors, grid, d_max_m=tr.d_max_m,
                                  rssi_names=rssi_names, detection_names=det_names, dz_m=dz)
    for name in ("rssi_links", "detection_attempts", "detection_cells", "fig7_groups"):
        write_parquet_atomic(getattr(tables, name), ctx.out(u.TABLES[name]))
    tag_errors = ctx.store.path(u.TABLES["tag_errors"])
    if tag_errors.is_file():  # the downstream stage's (absent when it is disabled)
        tables.tag_errors = pd.read_parquet(tag_errors).rename(columns={"tag_id": "unit"})
    ivs = headline_intervals(tables, seed=cfg.seed, min_attempts=tr.min_attempts)
    est = headline_estimates(tables, min_attempts=tr.min_attempts)
    metrics = {
        "source": "recording",
        "heldout": {"against": "measured", "n_tags": int(eval_reads["tag_id"].nunique()),
                    "n_attempts": int(len(eval_reads)), "n_reads": int(eval_reads["read"].sum()),
                    "estimates": est},
        **ivs,
        "recording": json.loads(ctx.input(runfiles.RECORDING_IMPORT).read_text()),
        "sim_vs_real": json.loads(ctx.input(runfiles.SIM_VS_REAL.format(name="summary.json")).read_text()),
        "calibration": json.loads(ctx.input(runfiles.CALIBRATION).read_text()),
        "model_fits": model_fits({n: sensors[n] for n in competitors}),
    }
    scores = ctx.store.path(runfiles.DOWNSTREAM_SCORES)
    if scores.is_file():  # as the simulated study's evaluation stage copies them
        down = json.loads(scores.read_text())
        metrics["tag_localisation"] = down["tag_localisation"]
        metrics["robot_localisation"] = down["robot_localisation"]
    atomic_write_json(ctx.out(runfiles.METRICS), metrics)
    return {"models": sorted(sensors)}


STAGE = Stage("recorded_eval", stage_recorded_eval,
              ("seed", "training.d_max_m", "training.d_bin_m", "training.alpha_bin_deg",
               "training.min_attempts"),
              ("recording", "models", "sim_vs_real", "calibration", "downstream"),
              version=stage_version(2),  # each version's change: CHANGELOG.md
              description="held-out scores on the recording",
              outputs=STAGE_OUTPUTS["recorded_eval"])
