"""Table checks and the small run-directory files the evaluation defines.

Files defined here (paths relative to the run directory):

``scene/tags.parquet``
    One row per tag: ``tag_id`` (str), ``x_m``, ``y_m``, ``z_m`` (float64,
    world frame), ``nx``, ``ny``, ``nz`` (unit normal of the surface it sits on),
    ``split`` (``"train"``: read by the training tour; ``"eval"``: held out, read only
    by the evaluation tour).

All writers go through a temporary name and :func:`os.replace`.
"""

from __future__ import annotations

import json
from collections.abc import Iterable, Mapping
from pathlib import Path

import numpy as np
import pandas as pd

from pipeline.evaluation.metrics import nan_to_none
from scenes.fileio import atomic_output, atomic_write_text

__all__ = [
    "READS_TRUTH_COLUMNS",
    "read_tags",
    "require_columns",
    "tag_position_lookup",
    "tags_table",
    "write_json_atomic",
    "write_parquet_atomic",
    "write_tags",
]

#: reads.parquet columns the truth comparisons need.
READS_TRUTH_COLUMNS = ("antenna", "tag_id", "read", "rssi_dbm", "d_true_m", "alpha_true_rad",
                       "gain_db")


def require_columns(df: pd.DataFrame, columns: Iterable[str], where: str) -> None:
    """Raise ValueError naming `where` and the missing columns if `df` lacks any of `columns`."""
    if not isinstance(df, pd.DataFrame):
        raise TypeError(f"{where}: expected a pandas DataFrame, got {type(df).__name__}")
    missing = [c for c in columns if c not in df.columns]
    if missing:
        raise ValueError(f"{where}: missing column(s) {missing}; has {list(df.columns)}")


def write_parquet_atomic(df: pd.DataFrame, path) -> Path:
    """Write `df` to Parquet at `path` via a temporary file and rename; returns the path."""
    with atomic_output(path) as tmp:
        df.to_parquet(tmp, index=False)
    return Path(path)


def write_json_atomic(obj, path) -> Path:
    """Write `obj` as JSON (NaN -> null) via a temporary file and rename; returns the path."""
    return atomic_write_text(path, json.dumps(nan_to_none(obj), indent=2, allow_nan=False) + "\n")


def tags_table(ids, positions_m, normals=None, split=None) -> pd.DataFrame:
    """Tags as a table (format of ``scene/tags.parquet``).

    Parameters
    ----------
    ids : array_like, shape (m,), str
    positions_m : array_like, shape (m, 3), float, metres
    normals : array_like, shape (m, 3), optional (NaN if omitted)
    split : array_like, shape (m,), str, optional
        ``"train"`` (read by the training tour) or ``"eval"`` (held out: read only by
        the evaluation tour) per tag; column ``split``, omitted when None.
    """
    ids = np.asarray(ids, dtype=str).reshape(-1)
    pos = np.asarray(positions_m, dtype=np.float64).reshape(-1, 3)
    nrm = np.full_like(pos, np.nan) if normals is None else np.asarray(normals, float).reshape(-1, 3)
    if not (len(ids) == len(pos) == len(nrm)):
        raise ValueError(f"tags_table: {len(ids)} ids, {len(pos)} positions, {len(nrm)} normals")
    df = pd.DataFrame({
        "tag_id": ids, "x_m": pos[:, 0], "y_m": pos[:, 1], "z_m": pos[:, 2],
        "nx": nrm[:, 0], "ny": nrm[:, 1], "nz": nrm[:, 2],
    })
    if split is not None:
        split = np.asarray(split, dtype=str).reshape(-1)
        bad = sorted(set(split.tolist()) - {"train", "eval"})
        if len(split) != len(ids) or bad:
            raise ValueError(f"tags_table: split must hold 'train'/'eval' per tag, got {bad or len(split)}")
        df["split"] = split
    return df


def write_tags(path, ids, positions_m, normals=None, split=None) -> Path:
    """Write ``scene/tags.parquet`` (see module doc); e.g. ``write_tags(p, *scene.tags...)``."""
    return write_parquet_atomic(tags_table(ids, positions_m, normals, split), path)


def read_tags(path) -> pd.DataFrame:
    """Read a tags table written by :func:`write_tags`; errors name the file and columns."""
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"tags table {path} does not exist")
    df = pd.read_parquet(path)
    require_columns(df, ("tag_id", "x_m", "y_m", "z_m"), str(path))
    return df


def tag_position_lookup(tags) -> dict[str, np.ndarray]:
    """``{tag_id: (3,) position [m]}`` from a tags table, a mapping, or an object with
    ``ids`` and ``positions_m`` (``scenes.TagSet``)."""
    if isinstance(tags, pd.DataFrame):
        require_columns(tags, ("tag_id", "x_m", "y_m", "z_m"), "tags table")
        xyz = tags[["x_m", "y_m", "z_m"]].to_numpy(np.float64)
        return {str(t): xyz[i] for i, t in enumerate(tags["tag_id"].astype(str))}
    if isinstance(tags, Mapping):
        out = {str(k): np.asarray(v, dtype=np.float64).reshape(3) for k, v in tags.items()}
        return out
    if hasattr(tags, "ids") and hasattr(tags, "positions_m"):
        pos = np.asarray(tags.positions_m, dtype=np.float64).reshape(-1, 3)
        return {str(t): pos[i] for i, t in enumerate(np.asarray(tags.ids).tolist())}
    raise TypeError(f"tags must be a DataFrame, a mapping or a TagSet, got {type(tags).__name__}")
