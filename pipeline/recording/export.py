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
``mounts.toml`` beside it (:func:`.rosbag.export_mcap`); :func:`export_recording` picks
the writer.

The export is what the importers read back (``tests/pipeline/test_recording.py``: the
same reads, the same poses at the reads' times).
"""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path
from typing import NamedTuple

import numpy as np
import pandas as pd

from .csvformats import write_poses_csv, write_sllurp_csv, write_tags_csv
from .impinj import write_impinj_csv

__all__ = ["EPOCH_S", "EXPORT_FORMATS", "RunTour", "epc_of", "export_csv", "export_recording",
           "run_tour", "tag_id_of", "write_layout"]

#: The exported clock's zero: 2026-01-01T00:00:00Z [s since 1970] (a real log's
#: timestamps are wall-clock; a fixed origin keeps an export byte-identical).
EPOCH_S = 1_767_225_600.0

#: EPC length [hex digits]: 96 bits.
EPC_DIGITS = 24


def epc_of(tag_id: str) -> str:
    """A 96-bit EPC (24 hex digits) that carries the tag id (its UTF-8 bytes, zero-padded
    on the left); :func:`tag_id_of` reverses it. Ids longer than 12 bytes are refused."""
    raw = str(tag_id).encode("utf-8")
    if len(raw) > EPC_DIGITS // 2:
        raise ValueError(f"tag id {str(tag_id)[:20]!r}: more than {EPC_DIGITS // 2} bytes, no 96-bit EPC")
    return raw.hex().upper().rjust(EPC_DIGITS, "0")


def tag_id_of(epc: str) -> str:
    """The tag id an :func:`epc_of` EPC carries."""
    return bytes.fromhex(epc).lstrip(b"\x00").decode("utf-8")


class RunTour(NamedTuple):
    """What an export takes from a finished run (:func:`run_tour`)."""

    reads: pd.DataFrame
    """The training tour's successful reads (``reads.parquet`` rows with ``read``)."""
    tags: pd.DataFrame
    """The training tags (``scene/tags.parquet``)."""
    t_s: np.ndarray
    """Times of the poses [s from the tour's start]."""
    est: np.ndarray
    """Estimated (MCL) poses (n, 3): x [m], y [m], yaw [rad]."""
    odom: np.ndarray
    """Odometry poses (n, 3), NaN where the run has none."""
    config: object
    """The run's :class:`pipeline.config.StudyConfig`."""
    epc: Callable[[str], str]
    """Tag id -> EPC: :func:`epc_of`, or ``str`` for a recorded run (its ids are EPCs)."""


def run_tour(run_dir: str | Path) -> RunTour:
    """The run's training tour, tags and config, as the exports write them.

    Raises
    ------
    ValueError
        A run file is missing or unreadable (named).
    """
    from pipeline.config import load_config
    from pipeline.runstore import inside
    from scenes.fileio import read_npz

    run = Path(run_dir)
    try:
        reads = pd.read_parquet(inside(run, "reads.parquet"),
                                columns=["time_s", "antenna", "tag_id", "read", "rssi_dbm",
                                         "frequency_hz", "phase_rad", "doppler_hz", "seen_count"])
        tags = pd.read_parquet(inside(run, "scene/tags.parquet"))
        with read_npz(inside(run, "tour/train_track.npz")) as z:
            t_s, est = np.asarray(z["t_s"], np.float64), np.asarray(z["est"], np.float64)
            odom = (np.asarray(z["odom"], np.float64) if "odom" in z
                    else np.full_like(est, np.nan))
        cfg = load_config(inside(run, "config.toml"))
    except (OSError, KeyError) as exc:
        raise ValueError(f"{run}: cannot read the run's files ({exc})") from None
    got = reads[reads["read"].to_numpy(bool)]
    # a recorded study's tag ids are its EPCs already (pipeline.stages.recorded)
    epc = (str if inside(run, "recording/import.json").is_file() else epc_of)
    train = tags[tags["split"].astype(str) == "train"] if "split" in tags else tags
    return RunTour(got, train, t_s, est, odom, cfg, epc)


def write_layout(tour: RunTour, out: Path) -> list[Path]:
    """``out/tags.csv`` (the training tags) and ``out/mounts.toml`` (the antenna mounts,
    reader port k = the k-th). Atomic each."""
    import dataclasses

    import tomli_w

    from scenes.fileio import atomic_write_text

    train, epc = tour.tags, tour.epc
    files = [write_tags_csv(pd.DataFrame({
        "epc": [epc(t) for t in train["tag_id"].astype(str)],
        **{c: train[c].to_numpy(np.float64) for c in ("x_m", "y_m", "z_m", "nx", "ny", "nz")}}),
        out / "tags.csv")]
    mounts = {"robot": {"antennas": [{k: v for k, v in dataclasses.asdict(a).items()
                                      if v is not None} for a in tour.config.robot.antennas]}}
    files.append(atomic_write_text(out / "mounts.toml", "# reader port k = the k-th antenna\n"
                                   + tomli_w.dumps(mounts)))
    return files


def export_csv(run_dir: str | Path, out_dir: str | Path) -> list[Path]:
    """Write the run's training tour as a recording (module doc); return the files.

    Raises
    ------
    pipeline.config.ConfigError
        ``out_dir`` may not be written (:func:`pipeline.outdirs.check_output_dir`).
    ValueError
        A run file is missing or unreadable (named).
    """
    from pipeline.acquisition.channels import REGIONS
    from pipeline.outdirs import check_output_dir, mark_output_dir

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
    :func:`.rosbag.export_mcap` (``"mcap"``, a ROS 2 bag); return the files written.

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
        from .rosbag import export_mcap

        return export_mcap(run_dir, out_dir)
    raise ValueError(f"--format {fmt!r}: one of {', '.join(EXPORT_FORMATS)}")
