"""Stage ``calibration``: the simulated reader fitted to the recording (``calibration.json``,
``calibrated.toml``).

The fit and its intervals are :func:`pipeline.evaluation.calibration.calibrate`'s, on the
traced twins of the recorded attempts (``sim_vs_real/attempts.parquet``): training tags
to fit, held-out tags to score before and after. Writes into the run directory

- ``calibration.json``: each parameter with its 95 % interval, what is fixed, and the
  held-out residuals before and after with paired intervals;
- ``calibrated.toml``: the study's config with the fitted values laid over it and no
  ``[recording]``, so that a simulated study (a placement study) runs with the calibrated
  reader in the same building: each antenna's ``cable_loss_db`` less its gain offset,
  ``reader.tag_sensitivity_dbm`` plus the sensitivity offset,
  ``reader.rssi_noise_db`` the fitted spread less the quantisation's
  (``rssi_resolution_db^2 / 12``). The RSSI offset, the detection spread and the miss
  probability are reported only: the simulated reader has no key for them (its truth is
  the received power, so an offset key would bias every model against it).
"""

from __future__ import annotations

import dataclasses

import numpy as np
import pandas as pd

from pipeline.runstore import atomic_write_json
from pipeline.stages.common import link_budget
from pipeline.study import Stage

__all__ = ["STAGE", "calibrated_config", "stage_calibration"]


def calibrated_config(cfg, fit):
    """``cfg`` with ``fit`` (:class:`~pipeline.evaluation.calibration.CalibrationFit`) laid
    over it and the recording removed (module doc)."""
    from pipeline.recording.config import RecordingConfig

    antennas = tuple(dataclasses.replace(a, cable_loss_db=float(a.cable_loss_db - d))
                     for a, d in zip(cfg.robot.antennas, fit.antenna_offsets_db, strict=True))
    r = cfg.reader
    noise = float(np.sqrt(max(fit.rssi_noise_db ** 2 - r.rssi_resolution_db ** 2 / 12.0, 0.0)))
    reader = dataclasses.replace(
        r, tag_sensitivity_dbm=float(r.tag_sensitivity_dbm + fit.tag_sensitivity_offset_db),
        rssi_noise_db=noise)
    return dataclasses.replace(cfg, robot=dataclasses.replace(cfg.robot, antennas=antennas),
                               reader=reader, recording=RecordingConfig())


def stage_calibration(ctx) -> dict:
    """Fit the reader to the recording; write ``calibration.json`` and ``calibrated.toml``."""
    from pipeline.config import config_to_toml
    from pipeline.evaluation.calibration import calibrate
    from scenes.fileio import atomic_write_text

    cfg = ctx.config
    att = pd.read_parquet(ctx.input("sim_vs_real/attempts.parquet"))
    fit, report = calibrate(att, link_budget(cfg), len(cfg.robot.antennas),
                            miss_probability=att["miss_probability"].to_numpy(np.float64),
                            seed=cfg.seed)
    report["antennas"] = [a.name for a in cfg.robot.antennas]
    atomic_write_json(ctx.out("calibration.json"), report)
    atomic_write_text(ctx.out("calibrated.toml"),
                      "# the study's config with the reader calibrated to the recording "
                      "(calibration.json)\n" + config_to_toml(calibrated_config(cfg, fit)))
    mae = report["heldout"]["rssi_mae_db"]
    return {"parameters": {k: round(v["value"], 3) for k, v in report["parameters"].items()},
            "heldout_rssi_mae_db": {"before": mae["before"]["estimate"], "after": mae["after"]["estimate"]}}


STAGE = Stage("calibration", stage_calibration, ("seed", "reader", "robot"), ("sim_vs_real",),
              description="calibrate the reader to the recording")
