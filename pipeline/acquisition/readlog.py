"""The reader's log: one row per read attempt, plus the robot poses, as Parquet.

Column names are the project contract (``reads.parquet`` and ``poses.parquet`` in a run
directory). Files are written to a temporary name and renamed into place, so a killed
run never leaves a file that looks complete.
"""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import pandas as pd
import pyarrow as pa
import pyarrow.parquet as pq

from pipeline import runfiles
from scenes.fileio import atomic_output

__all__ = [
    "POSE_COLUMNS",
    "READ_COLUMNS",
    "ReadLog",
    "read_table",
    "write_table",
]

#: Columns of ``reads.parquet`` and their dtypes (one row per read attempt).
READ_COLUMNS: dict[str, str] = {
    "time_s": "float64",  # time of the attempt [s]
    "cycle": "int32",  # read-cycle index
    "antenna": "int8",  # index into the robot's antenna mounts
    "tag_id": "category",  # tag identifier
    "read": "bool",  # reported by the reader in this attempt
    "rssi_dbm": "float32",  # reported RSSI (noise, quantisation); NaN if not read
    "frequency_hz": "float64",  # channel of the attempt (regional hop sequence) [Hz]
    "phase_rad": "float32",  # reported backscatter phase in [0, 2 pi), mod(-arg h^2 + ...); NaN if not read
    "doppler_hz": "float32",  # reported Doppler shift, positive approaching; NaN if not read
    "seen_count": "int16",  # singulations of the tag in the attempt (Gen2 inventory; 0/1 fixed)
    "true_ant_x_m": "float32",
    "true_ant_y_m": "float32",
    "true_ant_z_m": "float32",
    "true_ant_yaw_rad": "float32",
    "est_ant_x_m": "float32",
    "est_ant_y_m": "float32",
    "est_ant_z_m": "float32",
    "est_ant_yaw_rad": "float32",
    "d_true_m": "float32",
    "alpha_true_rad": "float32",
    "d_est_m": "float32",
    "alpha_est_rad": "float32",
    "gain_db": "float32",  # ray-traced one-way gain (both patterns); -inf if not traced
    "tag_power_dbm": "float32",  # power at the tag chip; -inf if not traced
    "rx_power_dbm": "float32",  # noise-free backscatter power at the reader; -inf if not traced
    "powered": "bool",  # tag_power_dbm >= tag sensitivity
    "in_range": "bool",  # pair was traced (within the budget's maximum range)
}

#: Columns of ``poses.parquet`` (one row per pose of the robot's track).
POSE_COLUMNS: dict[str, str] = {
    "time_s": "float64",
    "true_x_m": "float64",
    "true_y_m": "float64",
    "true_theta_rad": "float64",
    "odom_x_m": "float64",
    "odom_y_m": "float64",
    "odom_theta_rad": "float64",
    "est_x_m": "float64",
    "est_y_m": "float64",
    "est_theta_rad": "float64",
}

_META_KEY = b"rfidstudy"


def _check_columns(df: pd.DataFrame, columns: dict[str, str], what: str) -> None:
    missing = [c for c in columns if c not in df.columns]
    if missing:
        raise ValueError(f"{what}: missing column(s) {missing}")


def write_table(df: pd.DataFrame, path: str | Path, metadata: dict | None = None) -> Path:
    """Write a DataFrame as Parquet via a temporary file renamed into place.

    Parameters
    ----------
    df : pandas.DataFrame
        Table to write (index dropped).
    path : str or Path
        Destination ``.parquet`` file; parent directories are created.
    metadata : dict, optional
        JSON-able metadata stored in the Parquet schema under the key ``rfidstudy``.

    Returns
    -------
    Path
        The written path.
    """
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    table = pa.Table.from_pandas(df, preserve_index=False)
    if metadata is not None:
        meta = dict(table.schema.metadata or {})
        meta[_META_KEY] = json.dumps(metadata, sort_keys=True, default=_json_default).encode()
        table = table.replace_schema_metadata(meta)
    with atomic_output(path) as tmp:
        pq.write_table(table, tmp)
    return path


def read_table(path: str | Path) -> tuple[pd.DataFrame, dict]:
    """Read a Parquet file written by :func:`write_table`: the frame and its metadata.

    Raises
    ------
    FileNotFoundError
        Naming the path.
    """
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"no such Parquet file: {path}")
    table = pq.read_table(path)
    meta = (table.schema.metadata or {}).get(_META_KEY)
    return table.to_pandas(), (json.loads(meta) if meta else {})


def _json_default(obj: object) -> object:
    if isinstance(obj, np.generic):
        return obj.item()
    if isinstance(obj, np.ndarray):
        return obj.tolist()
    raise TypeError(f"not JSON-serialisable: {type(obj).__name__}")


@dataclass
class ReadLog:
    """What the simulated reader reported along a tour.

    Attributes
    ----------
    reads : pandas.DataFrame
        One row per read attempt (cycle, active antenna, tag), columns
        :data:`READ_COLUMNS`.
    poses : pandas.DataFrame
        One row per robot pose of the track, columns :data:`POSE_COLUMNS`.
    metadata : dict
        JSON-able description: reader config, antenna names, tag ids, scene hash,
        trace settings, counts of traced pairs.
    n_sources_traced : int
        Antenna positions traced afresh (not written: the files do not depend on the cache).
    """

    reads: pd.DataFrame
    poses: pd.DataFrame
    metadata: dict = field(default_factory=dict)
    n_sources_traced: int = 0

    def __post_init__(self) -> None:
        _check_columns(self.reads, READ_COLUMNS, "ReadLog.reads")
        _check_columns(self.poses, POSE_COLUMNS, "ReadLog.poses")

    @property
    def n_attempts(self) -> int:
        """Number of read attempts (rows of ``reads``)."""
        return len(self.reads)

    @property
    def n_reads(self) -> int:
        """Number of successful reads."""
        return int(self.reads["read"].sum())

    def write(self, run_dir: str | Path, prefix: str = "") -> tuple[Path, Path]:
        """Write ``{prefix}reads.parquet`` and ``{prefix}poses.parquet`` into ``run_dir``.

        Use ``prefix="eval_"`` for the held-out evaluation path.
        """
        run_dir = Path(run_dir)
        r = write_table(self.reads, run_dir / runfiles.READS.format(prefix=prefix), self.metadata)
        p = write_table(self.poses, run_dir / runfiles.POSES.format(prefix=prefix))
        return r, p

    @classmethod
    def read(cls, run_dir: str | Path, prefix: str = "") -> ReadLog:
        """Read a log written by :meth:`write`."""
        run_dir = Path(run_dir)
        reads, meta = read_table(run_dir / runfiles.READS.format(prefix=prefix))
        poses, _ = read_table(run_dir / runfiles.POSES.format(prefix=prefix))
        return cls(reads=reads, poses=poses, metadata=meta)
