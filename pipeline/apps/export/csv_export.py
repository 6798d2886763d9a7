"""A finished study's training tour written as a recording a real robot would leave.

``rfidstudy export RUN --format csv --out DIR`` writes into ``DIR`` (new, empty, or an
earlier export: :mod:`pipeline.outdirs`):

- ``reads.csv``: every successful read of the training tour in ``sllurp log``'s layout
  (:mod:`.csvformats`): ``timestamp`` = :data:`EPOCH_S` + the tour's time, ``reader``
  ``simulated:5084``, ``antenna`` the reader port (the study's antenna index + 1),
  ``rssi`` whole dBm, ``epc`` :func:`epc_of` the tag id. Failed attempts are no row, as
  in a real log;
- ``reads_impinj.csv``: the same reads as an Impinj reader reports them
  (:mod:`.impinj`, raw units: 0.01 dBm, the 12-bit phase, the channel index in the
  reader's region, 1/16 Hz Doppler, the tag seen count); written where the reader's
  region has a channel table (``reader.region`` ETSI or FCC, the default ETSI);
- ``poses.csv``: the robot base's *estimated* poses (MCL), what a real robot records
  (``/amcl_pose``), on the same clock;
- ``tags.csv``: the training tags' EPCs, positions and normals;
- ``mounts.toml``: the study's ``[[robot.antennas]]``, reader port k = the k-th mount.

``--format mcap`` writes the same tour as a ROS 2 bag, with ``tags.csv`` and
``mounts.toml`` beside it (:func:`.rosbag_export.export_mcap`); :func:`export_recording` picks
the writer. The clock, the EPCs and the run files both read are :mod:`.runtour`'s.

The export is what the importers read back (``tests/pipeline/test_recording.py``: the
same reads, the same poses at the reads' times).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd

from pipeline.acquisition.channels import REGIONS
from pipeline.apps.export.rosbag_export import export_mcap
from pipeline.apps.export.runtour import EPOCH_S, RunTour, epc_of, run_tour, tag_id_of, write_layout
from pipeline.outdirs import check_output_dir, mark_output_dir
from pipeline.recording.csvformats import write_poses_csv, write_sllurp_csv
from pipeline.recording.impinj import write_impinj_csv

__all__ = ["EPOCH_S", "EXPORT_FORMATS", "RunTour", "epc_of", "export_csv", "export_recording",
           "run_tour", "tag_id_of", "write_layout"]

def export_csv(run_dir: str | Path, out_dir: str | Path) -> list[Path]:
    """Write the run's training tour as a recording (module doc); return the files.

    Raises
    ------
    pipeline.config.ConfigError
        ``out_dir`` may not be written (:func:`pipeline.outdirs.check_output_dir`).
    ValueError
        A run file is missing or unreadable (named).
    """
    names = ["reads.csv", "reads_impinj.csv", "poses.csv", "tags.csv", "mounts.toml"]
    out = check_output_dir(out_dir, "export", names)
    tour = run_tour(run_dir)
    got, epc, cfg = tour.reads, tour.epc, tour.config
    out.mkdir(parents=True, exist_ok=True)
    files = [write_sllurp_csv(pd.DataFrame({
        "t_s": EPOCH_S + got["time_s"].to_numpy(np.float64),
        "reader": "simulated:5084",
        "antenna_port": got["antenna"].to_numpy(np.int64) + 1,
        "rssi_dbm": got["rssi_dbm"].to_numpy(np.float64),
        "epc": [epc(t) for t in got["tag_id"].astype(str)],
    }), out / "reads.csv")]
    if REGIONS[cfg.reader.region].channels_hz and not cfg.reader.channels_hz:
        files.append(write_impinj_csv(pd.DataFrame({
            "t_s": EPOCH_S + got["time_s"].to_numpy(np.float64),
            "antenna_port": got["antenna"].to_numpy(np.int64) + 1,
            "rssi_dbm": got["rssi_dbm"].to_numpy(np.float64),
            "epc": [epc(t) for t in got["tag_id"].astype(str)],
            "phase_rad": got["phase_rad"].to_numpy(np.float64),
            "frequency_hz": got["frequency_hz"].to_numpy(np.float64),
            "doppler_hz": got["doppler_hz"].to_numpy(np.float64),
            "seen_count": np.maximum(got["seen_count"].to_numpy(np.int64), 1)}),
            out / "reads_impinj.csv", cfg.reader.region))
    est = tour.est
    files.append(write_poses_csv(pd.DataFrame({
        "t_s": EPOCH_S + tour.t_s, "x_m": est[:, 0], "y_m": est[:, 1],
        "yaw_rad": est[:, 2]}), out / "poses.csv"))
    files += write_layout(tour, out)
    mark_output_dir(out, "export", files)
    return files


#: Formats :func:`export_recording` writes.
EXPORT_FORMATS = ("csv", "mcap")


def export_recording(run_dir: str | Path, out_dir: str | Path, fmt: str = "csv") -> list[Path]:
    """``rfidstudy export RUN --format FMT --out DIR``: :func:`export_csv` (``"csv"``) or
    :func:`.rosbag_export.export_mcap` (``"mcap"``, a ROS 2 bag); return the files written.

    Raises
    ------
    ValueError
        An unknown ``fmt``; a run file missing or unreadable.
    pipeline.config.ConfigError
        ``out_dir`` may not be written.
    """
    if fmt == "csv":
        return export_csv(run_dir, out_dir)
    if fmt == "mcap":
        return export_mcap(run_dir, out_dir)
    raise ValueError(f"--format {fmt!r}: one of {', '.join(EXPORT_FORMATS)}")
