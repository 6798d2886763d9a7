"""A recording's files read, checked and joined: :func:`load_recording`.

The reads file's format is told apart (``format = "auto"``): a ROS 2 bag by its folder's
``metadata.yaml`` or a ``.mcap`` / ``.db3`` suffix (:mod:`.rosbag`: the reads and the
poses from its topics), a CSV by its header: ``sllurp log``'s
``timestamp,reader,antenna,rssi,epc`` (:mod:`.csvformats`) or an Impinj tag report CSV
(:mod:`.impinj`). What the import leaves out is counted, never merged
silently: reads of EPCs absent from the tag layout (listed), reads outside the poses'
time span. A read on a port no mount is on stops the import (``recording.antenna_ports``).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import pandas as pd

from pipeline.recording.csvformats import (
    READ_FIELDS,
    SLLURP_COLUMNS,
    RecordingError,
    read_poses_csv,
    read_sllurp_csv,
    read_tags_csv,
)
from pipeline.recording.impinj import IMPINJ_FIELDS, impinj_header, read_impinj_csv
from pipeline.recording.rosbag import read_rosbag
from scenes.scene import TagSet

__all__ = ["READ_FIELDS", "Recording", "detect_format", "is_rosbag", "load_recording",
           "recorded_tagset"]

#: EPCs listed by name in the import's summary (the rest counted).
LISTED = 20


@dataclass
class Recording:
    """A recording as the study takes it.

    Attributes
    ----------
    reads : pandas.DataFrame
        One row per tag report of a tag in the layout on a mounted port, in time order:
        :data:`READ_FIELDS` (``t_s`` [s since 1970], ``antenna_port`` 1-based, ``rssi_dbm``,
        ``epc``, ``phase_rad``, ``frequency_hz``, ``doppler_hz`` (NaN where the format has
        none), ``seen_count``).
    poses : pandas.DataFrame or None
        ``t_s, x_m, y_m, yaw_rad``; None for fixed antennas.
    tags : pandas.DataFrame
        ``epc, x_m, y_m, z_m, nx, ny, nz`` (normals NaN where the file gives none).
    format : str
        ``"sllurp"``, ``"impinj"`` or ``"rosbag"``.
    info : dict
        What the import counted: reads in the file, kept, of unknown EPCs (and the first
        :data:`LISTED` of them), outside the poses' span.
    """

    reads: pd.DataFrame
    poses: pd.DataFrame | None
    tags: pd.DataFrame
    format: str
    info: dict = field(default_factory=dict)


def is_rosbag(path: str | Path) -> bool:
    """``path`` is a ROS 2 bag: a folder with ``metadata.yaml``, or a ``.mcap`` / ``.db3``
    file."""
    p = Path(path)
    return (p.is_dir() and (p / "metadata.yaml").is_file()) or (
        p.is_file() and p.suffix.lower() in (".mcap", ".db3"))


def detect_format(path: str | Path) -> str:
    """``"rosbag"`` (:func:`is_rosbag`), else ``"sllurp"`` or ``"impinj"`` from the reads
    file's header.

    Raises
    ------
    RecordingError
        Neither header (the file's is quoted, shortened).
    """
    if is_rosbag(path):
        return "rosbag"
    if Path(path).is_dir():
        raise RecordingError(f"{path}: a folder, and not a ROS 2 bag (no metadata.yaml): name "
                             "the reads file, or the bag's folder")
    head = impinj_header(path)
    if all(c in head for c in SLLURP_COLUMNS):
        return "sllurp"
    if any(c in head for c, _ in IMPINJ_FIELDS["epc"]):
        return "impinj"
    if not Path(path).is_file():
        raise RecordingError(f"{path}: no such file")
    raise RecordingError(f"{path}:1: neither sllurp log's header ({','.join(SLLURP_COLUMNS)}) nor "
                         f"an Impinj report's (an EPC column); the header is "
                         f"{','.join(head)[:120]!r}: set recording.format")


def load_recording(rcfg, *, region: str = "", n_mounts: int) -> Recording:
    """Read the files a ``[recording]`` section names (:class:`~.config.RecordingConfig`).

    Parameters
    ----------
    rcfg : RecordingConfig
    region : str
        The channel plan for Impinj channel indices when ``rcfg.region`` is empty.
    n_mounts : int
        The study's antenna mounts: ports ``rcfg.antenna_ports`` or 1..n_mounts.

    A ROS 2 bag (``format = "rosbag"``) gives the reads (``rcfg.reads_topic``) and the
    poses (``rcfg.pose_topic``; ``rcfg.poses``, where set, replaces them):
    :func:`.rosbag.read_rosbag`.

    Raises
    ------
    RecordingError
        A file that cannot be read (named, with its line; a bag, with the topic), a tag layout over
        ``max_tags``, a read on a port no mount is on, no read of a known tag left.
    """
    fmt = detect_format(rcfg.reads) if rcfg.format == "auto" else rcfg.format
    bag_poses = None
    if fmt == "rosbag":
        raw, bag_poses = read_rosbag(rcfg.reads, reads_topic=rcfg.reads_topic,
                                     pose_topic="" if rcfg.poses else rcfg.pose_topic)
    elif fmt == "sllurp":
        raw = read_sllurp_csv(rcfg.reads, rcfg.region or region)
        n_sorted = int(raw.attrs.get("n_reordered", 0))
        raw = raw.drop(columns=["reader"])
        raw["seen_count"] = 1
    else:
        raw = read_impinj_csv(rcfg.reads, rcfg.region or region)
    n_reordered = n_sorted if fmt == "sllurp" else int(raw.attrs.get("n_reordered", 0))
    raw = raw[list(READ_FIELDS)]
    if rcfg.time_offset_s:
        raw["t_s"] = raw["t_s"] + float(rcfg.time_offset_s)
    tags = read_tags_csv(rcfg.tags)
    if len(tags) > rcfg.max_tags:
        raise RecordingError(f"{rcfg.tags}: {len(tags)} tags, more than recording.max_tags = "
                             f"{rcfg.max_tags}")
    ports = list(rcfg.antenna_ports) or list(range(1, n_mounts + 1))
    if len(ports) != n_mounts:
        raise RecordingError(f"recording.antenna_ports lists {len(ports)} ports for {n_mounts} "
                             "[[robot.antennas]] mounts: one port per mount, in table order")
    stray = sorted(set(raw["antenna_port"].tolist()) - set(ports))
    if stray:
        n = int(raw["antenna_port"].isin(stray).sum())
        raise RecordingError(f"{rcfg.reads}: {n} reads on port(s) {stray[:8]}, where no mount is "
                             f"(the mounts are on ports {ports}): add the mounts to "
                             "[[robot.antennas]] and their ports to recording.antenna_ports")
    known = raw["epc"].isin(set(tags["epc"]))
    unknown = raw.loc[~known, "epc"].value_counts()
    info = {"format": fmt, "n_reads_in_file": int(len(raw)), "n_tags": int(len(tags)),
            "n_reads_unknown_epc": int((~known).sum()),
            "unknown_epcs": {str(k): int(v) for k, v in unknown.head(LISTED).items()},
            "n_unknown_epcs": int(len(unknown)), "n_reads_reordered": n_reordered,
            "n_tags_normal_guessed": int((~np.all(np.isfinite(
                tags[["nx", "ny", "nz"]].to_numpy(np.float64)), axis=1)).sum())}
    reads = raw.loc[known].reset_index(drop=True)
    poses = read_poses_csv(rcfg.poses) if rcfg.poses else bag_poses
    if poses is not None:
        t = poses["t_s"].to_numpy(np.float64)
        tr = reads["t_s"].to_numpy(np.float64)
        inside = (tr >= t[0]) & (tr <= t[-1])
        info["n_reads_outside_poses"] = int((~inside).sum())
        reads = reads.loc[inside].reset_index(drop=True)
    else:
        info["n_reads_outside_poses"] = 0
    if reads.empty:
        raise RecordingError(f"{rcfg.reads}: no read of a tag in {rcfg.tags} "
                             + ("within the poses' time span " if poses is not None else "")
                             + f"({info['n_reads_in_file']} reads in the file, "
                             f"{info['n_reads_unknown_epc']} of unknown EPCs)")
    info["n_reads"] = int(len(reads))
    info["ports"] = ports
    return Recording(reads, poses, tags, fmt, info)


def recorded_tagset(rec: Recording, antenna_xy=None):
    """The recording's tags as a :class:`scenes.scene.TagSet` (ids = EPCs).

    A tag whose file gives no normal faces the nearest robot pose (or, for fixed
    antennas, the nearest of ``antenna_xy`` (k, 2)) horizontally: tags in an aisle face it.
    """
    t = rec.tags
    pos = t[["x_m", "y_m", "z_m"]].to_numpy(np.float64)
    nrm = t[["nx", "ny", "nz"]].to_numpy(np.float64)
    missing = ~np.all(np.isfinite(nrm), axis=1)
    if missing.any():
        ref = (rec.poses[["x_m", "y_m"]].to_numpy(np.float64) if rec.poses is not None
               else np.asarray(antenna_xy, np.float64).reshape(-1, 2))
        d = ref[None, :, :] - pos[missing, None, :2]
        near = ref[np.argmin(np.einsum("ijk,ijk->ij", d, d), axis=1)] - pos[missing, :2]
        norm = np.linalg.norm(near, axis=1, keepdims=True)
        flat = np.where(norm > 1e-9, near / np.maximum(norm, 1e-12), np.array([[1.0, 0.0]]))
        nrm[missing] = np.column_stack([flat, np.zeros(len(flat))])
    return TagSet(ids=t["epc"].to_numpy(str), positions_m=pos, normals=nrm)
