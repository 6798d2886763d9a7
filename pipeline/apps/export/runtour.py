"""What every export of a run shares: the exported clock, the EPCs of tag ids, the run's
training tour as read (:func:`run_tour`) and the tag layout and mounts written beside
the reads (:func:`write_layout`). Used by the CSV export (:mod:`.export`) and the ROS 2
bag writer (:mod:`.rosbag_export`).
"""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path
from typing import NamedTuple

import numpy as np
import pandas as pd

from pipeline import runfiles
from pipeline.config import load_config
from pipeline.recording.csvformats import write_tags_csv
from pipeline.runpaths import inside
from scenes.fileio import atomic_write_text, read_npz

__all__ = ["EPC_DIGITS", "EPOCH_S", "RunTour", "epc_of", "run_tour", "tag_id_of", "write_layout"]

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
    run = Path(run_dir)
    try:
        reads = pd.read_parquet(inside(run, runfiles.TRAIN_READS),
                                columns=["time_s", "antenna", "tag_id", "read", "rssi_dbm",
                                         "frequency_hz", "phase_rad", "doppler_hz", "seen_count"])
        tags = pd.read_parquet(inside(run, runfiles.SCENE_TAGS))
        with read_npz(inside(run, runfiles.TRAIN_TRACK)) as z:
            t_s, est = np.asarray(z["t_s"], np.float64), np.asarray(z["est"], np.float64)
            odom = (np.asarray(z["odom"], np.float64) if "odom" in z
                    else np.full_like(est, np.nan))
        cfg = load_config(inside(run, "config.toml"))
    except (OSError, KeyError) as exc:
        raise ValueError(f"{run}: cannot read the run's files ({exc})") from None
    got = reads[reads["read"].to_numpy(bool)]
    # a recorded study's tag ids are its EPCs already (pipeline.stages.recorded)
    epc = (str if inside(run, runfiles.RECORDING_IMPORT).is_file() else epc_of)
    train = tags[tags["split"].astype(str) == "train"] if "split" in tags else tags
    return RunTour(got, train, t_s, est, odom, cfg, epc)


def write_layout(tour: RunTour, out: Path) -> list[Path]:
    """``out/tags.csv`` (the training tags) and ``out/mounts.toml`` (the antenna mounts,
    reader port k = the k-th). Atomic each."""
    import dataclasses

    import tomli_w


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
