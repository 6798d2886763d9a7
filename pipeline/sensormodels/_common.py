"""What the competitor sensor models share: the SensorLike methods, JSON files, input rows.

Every competitor is a :class:`CompetitorModel`: it predicts the detection probability
``fT(d, alpha)`` and, where its paper has one, the expected RSSI; ``fs`` is that RSSI
normalised with the model's ``rssi_range_dbm`` (the fuzzy model's range, for
comparability) and ``rho = fs * fT``, as for ``fuzzymodel.SensorModel``.

A model without an RSSI prediction (``predicts_rssi = False``) returns ``fs = 1``
everywhere, so that ``rho = fT`` (the read carries only the detection), and
``fs_dbm = NaN``; scoring code should skip its RSSI (``predicts_rssi`` tells it).

Files are JSON objects ``{"format", "kind", "reference", "description",
"rssi_range_dbm", "params"}``; ``kind`` names the model class, and loading a file of
another kind raises a ValueError naming the file and both kinds.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import ClassVar

import numpy as np
import pandas as pd

from fuzzymodel import denormalise_rssi, normalise_rssi, wrap_angle
from pipeline.configschema import check_keys
from pipeline.evaluation.tables import require_columns, tag_position_lookup, write_json_atomic

__all__ = [
    "COMPETITOR_FORMAT",
    "CompetitorModel",
    "Attempts",
    "attempts_from_reads",
    "check_rssi_range",
    "file_kind",
    "group_folds",
    "nearest_fill",
    "read_model_file",
    "tag_height_differences",
]

#: Format tag of every competitor model file.
COMPETITOR_FORMAT = "rfidstudy.sensormodels/1"
_FILE_KEYS = {"format", "kind", "reference", "description", "rssi_range_dbm", "params"}


def check_rssi_range(rssi_range_dbm, where: str = "rssi_range_dbm") -> tuple[float, float]:
    """``(lo, hi)`` as floats; ValueError unless finite with lo < hi."""
    try:
        lo, hi = (float(v) for v in rssi_range_dbm)
    except (TypeError, ValueError):
        raise ValueError(f"{where}: must be (lo, hi) in dBm, got {rssi_range_dbm!r}") from None
    if not (np.isfinite(lo) and np.isfinite(hi) and lo < hi):
        raise ValueError(f"{where}: must be finite with lo < hi, got ({lo}, {hi})")
    return lo, hi


def read_model_file(path) -> dict:
    """The JSON object in `path`; errors name the file."""
    path = Path(path)
    try:
        d = json.loads(path.read_text())
    except FileNotFoundError:
        raise FileNotFoundError(f"sensor model file {path} does not exist") from None
    except json.JSONDecodeError as exc:
        raise ValueError(f"{path}: not valid JSON ({exc})") from None
    if not isinstance(d, dict):
        raise ValueError(f"{path}: top level must be a JSON object, got {type(d).__name__}")
    return d


def file_kind(d: dict, where: str) -> str:
    """The ``kind`` of a loaded file; ValueError (naming `where`) if it has none."""
    kind = d.get("kind")
    if not isinstance(kind, str):
        fmt = d.get("format")
        raise ValueError(f"{where}: no 'kind' field (format {fmt!r}): not a competitor sensor "
                         f"model file of {COMPETITOR_FORMAT!r}")
    return kind


def nearest_fill(table: np.ndarray, known: np.ndarray) -> np.ndarray:
    """Copy of the (n_d, n_alpha) `table` whose cells where `known` is False take the value
    of the nearest known cell (distance in cell units, bearing index wrapping round).

    All unknown and no known cell: returned unchanged.
    """
    out = np.array(table, dtype=np.float64)
    if known.all() or not known.any():
        return out
    n_a = table.shape[1]
    si, sj = np.nonzero(known)
    ui, uj = np.nonzero(~known)
    dj = np.abs(uj[:, None] - sj[None, :])
    dj = np.minimum(dj, n_a - dj)
    nearest = np.argmin((ui[:, None] - si[None, :]) ** 2 + dj ** 2, axis=1)
    out[ui, uj] = out[si[nearest], sj[nearest]]
    return out


class Attempts:
    """Read attempts as flat arrays: ``d`` [m], ``alpha`` [rad] wrapped to (-pi, pi],
    ``read`` (bool), ``rssi`` [dBm] (NaN where not read or not reported) and, optionally,
    ``group`` (int codes of the attempt's tag, for cross-validation folds that keep a
    tag's correlated attempts together; None: unknown) and ``dz`` (the tag's height above
    the antenna [m], a scalar broadcast to every attempt or one per attempt; None:
    unknown), which a ground-plane model needs (:mod:`.vorst2008`)."""

    def __init__(self, d_m, alpha_rad, read, rssi_dbm=None, group=None, dz_m=None):
        d = np.asarray(d_m, dtype=np.float64).ravel()
        a = wrap_angle(np.asarray(alpha_rad, dtype=np.float64).ravel())
        r = np.asarray(read).ravel()
        if r.dtype != bool:
            if not np.all(np.isin(r, (0, 1))):
                raise ValueError("read must be boolean (or 0/1)")
            r = r.astype(bool)
        s = (np.full(d.shape, np.nan) if rssi_dbm is None
             else np.asarray(rssi_dbm, dtype=np.float64).ravel())
        g = None
        if group is not None:
            g = np.unique(np.asarray(group).ravel(), return_inverse=True)[1].reshape(-1)
        if not (d.shape == a.shape == r.shape == s.shape) or (g is not None and g.shape != d.shape):
            raise ValueError(f"d {d.shape}, alpha {a.shape}, read {r.shape}, rssi {s.shape}"
                             + ("" if g is None else f", group {g.shape}") + " differ")
        dz = None
        if dz_m is not None:
            dz = np.broadcast_to(np.asarray(dz_m, dtype=np.float64), d.shape).ravel().copy()
            if not np.isfinite(dz).all():
                raise ValueError("dz_m (tag height above the antenna) must be finite")
        ok = np.isfinite(d) & np.isfinite(a) & (d >= 0)
        self.d, self.alpha, self.read = d[ok], a[ok], r[ok]
        self.rssi = np.where(self.read, s[ok], np.nan)
        self.group = None if g is None else g[ok]
        self.dz = None if dz is None else dz[ok]

    def __len__(self) -> int:
        return int(self.d.size)

    def within(self, d_max_m: float) -> Attempts:
        """The attempts with ``d < d_max_m``."""
        keep = self.d < float(d_max_m)
        return Attempts(self.d[keep], self.alpha[keep], self.read[keep], self.rssi[keep],
                        None if self.group is None else self.group[keep],
                        None if self.dz is None else self.dz[keep])

    @property
    def has_rssi(self) -> np.ndarray:
        """Reads with a finite RSSI."""
        return self.read & np.isfinite(self.rssi)


def group_folds(groups, n_folds: int, rng: np.random.Generator) -> np.ndarray:
    """Cross-validation fold (0 .. n_folds - 1) of every item, never splitting a group.

    The equivalent of scikit-learn's ``GroupKFold``: groups, largest first (ties in an
    order drawn from ``rng``), go one by one to the fold holding the fewest items so far.

    Parameters
    ----------
    groups : array_like (n,)
        Group label of every item (e.g. its tag).
    n_folds : int
        Folds (>= 2, at most the number of groups).
    rng : numpy.random.Generator
        Breaks ties between groups of equal size.

    Returns
    -------
    numpy.ndarray (n,), int64
    """
    _, code, size = np.unique(np.asarray(groups).ravel(), return_inverse=True, return_counts=True)
    k = int(n_folds)
    if k < 2 or k > len(size):
        raise ValueError(f"group_folds: need 2 <= n_folds <= {len(size)} groups, got {n_folds}")
    order = rng.permutation(len(size))
    order = order[np.argsort(-size[order], kind="stable")]
    load = np.zeros(k, np.int64)
    fold_of = np.empty(len(size), np.int64)
    for g in order:
        f = int(np.argmin(load))
        fold_of[g] = f
        load[f] += size[g]
    return fold_of[code.reshape(-1)]


def tag_height_differences(reads: pd.DataFrame, tags, pose: str = "est") -> np.ndarray:
    """Each row's tag height above its antenna [m]: the tag's z (``tags``, a
    :class:`scenes.TagSet` or a tags table holding every ``tag_id`` of the table, see
    :func:`pipeline.evaluation.tables.tag_position_lookup`) less ``<pose>_ant_z_m``.

    Raises
    ------
    ValueError
        A ``tag_id`` of the table that ``tags`` does not hold, or a missing column.
    """
    if pose not in ("est", "true"):
        raise ValueError(f"pose must be 'est' or 'true', got {pose!r}")
    require_columns(reads, ("tag_id", f"{pose}_ant_z_m"), "reads")
    z_of = {k: float(v[2]) for k, v in tag_position_lookup(tags).items()}
    ids = reads["tag_id"].astype(str).to_numpy()
    unknown = sorted(set(ids) - set(z_of))
    if unknown:
        raise ValueError(f"reads: tag(s) {unknown[:5]} not among the {len(z_of)} tags given")
    return np.array([z_of[t] for t in ids], dtype=np.float64) - reads[f"{pose}_ant_z_m"].to_numpy(
        np.float64)


def attempts_from_reads(reads: pd.DataFrame, d_max_m: float, pose: str = "est",
                        dz_m=None) -> Attempts:
    """The attempts of a ``reads.parquet`` table with ``d < d_max_m``.

    Geometry from ``d_<pose>_m`` / ``alpha_<pose>_rad`` (``"est"``: MCL poses, what the
    robot knows; ``"true"``: ground truth); rows with non-finite geometry are dropped.
    The ``tag_id`` column, where present, is the attempts' ``group``; ``dz_m`` (one per
    row, e.g. :func:`tag_height_differences`, or a scalar), where given, their ``dz``.
    """
    if pose not in ("est", "true"):
        raise ValueError(f"pose must be 'est' or 'true', got {pose!r}")
    if not (np.isfinite(d_max_m) and d_max_m > 0):
        raise ValueError(f"d_max_m must be finite and > 0, got {d_max_m!r}")
    dc, ac = f"d_{pose}_m", f"alpha_{pose}_rad"
    require_columns(reads, ("read", "rssi_dbm", dc, ac), "reads")
    group = reads["tag_id"].astype(str).to_numpy() if "tag_id" in reads.columns else None
    return Attempts(reads[dc].to_numpy(np.float64), reads[ac].to_numpy(np.float64),
                    reads["read"].to_numpy(bool),
                    reads["rssi_dbm"].to_numpy(np.float64), group, dz_m).within(d_max_m)


class CompetitorModel:
    """Base of the competitor models: SensorLike methods and JSON persistence.

    Subclasses set ``KIND``, ``REFERENCE``, ``DESCRIPTION`` and ``predicts_rssi``, hold
    ``rssi_range_dbm``, and implement ``_detection(d, a)`` and (if ``predicts_rssi``)
    ``_rssi_dbm(d, a)`` on flat float arrays (``a`` wrapped, NaN handled here),
    ``params_dict()`` and ``from_params(params, rssi_range_dbm, where)``.
    """

    KIND: ClassVar[str] = ""
    REFERENCE: ClassVar[str] = ""
    DESCRIPTION: ClassVar[str] = ""
    #: Whether the model predicts RSSI (else fs = 1 and fs_dbm = NaN, see module doc).
    predicts_rssi: ClassVar[bool] = True
    #: Whether the model predicts the detection probability (all competitors do).
    predicts_detection: ClassVar[bool] = True

    rssi_range_dbm: tuple[float, float]

    # ----------------------------------------------------------- subclass hooks
    def _detection(self, d: np.ndarray, a: np.ndarray) -> np.ndarray:
        raise NotImplementedError

    def _rssi_dbm(self, d: np.ndarray, a: np.ndarray) -> np.ndarray:
        raise NotImplementedError

    def params_dict(self) -> dict:
        raise NotImplementedError

    @classmethod
    def from_params(cls, params: dict, rssi_range_dbm, where: str):
        raise NotImplementedError

    # ------------------------------------------------------------- evaluation
    @staticmethod
    def _apply(fn, d, alpha) -> np.ndarray:
        d, a = np.broadcast_arrays(np.asarray(d, dtype=np.float64),
                                   np.asarray(alpha, dtype=np.float64))
        df, af = d.ravel(), wrap_angle(a.ravel())
        ok = np.isfinite(df) & np.isfinite(af)
        out = np.full(df.shape, np.nan)
        if ok.any():
            out[ok] = fn(df[ok], af[ok])
        return out.reshape(d.shape)

    def fT(self, d, alpha) -> np.ndarray:  # noqa: N802 - the chapter's name
        """Detection probability in [0, 1] at (d [m], alpha [rad]); broadcasts; NaN in, NaN out."""
        return np.clip(self._apply(self._detection, d, alpha), 0.0, 1.0)

    def expected_rssi_dbm(self, d, alpha) -> np.ndarray:
        """The model's RSSI [dBm], unclipped; NaN everywhere if it predicts none."""
        if not self.predicts_rssi:
            return self._apply(lambda dd, aa: np.full(dd.shape, np.nan), d, alpha)
        return self._apply(self._rssi_dbm, d, alpha)

    def fs(self, d, alpha) -> np.ndarray:
        """Normalised RSSI in [0, 1] (1 everywhere without an RSSI prediction)."""
        if not self.predicts_rssi:
            return self._apply(lambda dd, aa: np.ones(dd.shape), d, alpha)
        rssi = self.expected_rssi_dbm(d, alpha)
        out = normalise_rssi(np.where(np.isfinite(rssi), rssi, 0.0), self.rssi_range_dbm)
        return np.where(np.isfinite(rssi), out, np.nan)

    def fs_dbm(self, d, alpha) -> np.ndarray:
        """Expected RSSI [dBm] clipped to the range like ``SensorModel.fs_dbm``; NaN without one."""
        if not self.predicts_rssi:
            return self.expected_rssi_dbm(d, alpha)
        return denormalise_rssi(self.fs(d, alpha), self.rssi_range_dbm)

    def rho(self, d, alpha) -> np.ndarray:
        """``fs * fT`` (= fT without an RSSI prediction)."""
        return self.fs(d, alpha) * self.fT(d, alpha)

    # ------------------------------------------------------------ persistence
    def to_dict(self) -> dict:
        """JSON-able dict (format :data:`COMPETITOR_FORMAT`)."""
        return {"format": COMPETITOR_FORMAT, "kind": self.KIND, "reference": self.REFERENCE,
                "description": self.DESCRIPTION,
                "rssi_range_dbm": [float(v) for v in self.rssi_range_dbm],
                "params": self.params_dict()}

    @classmethod
    def from_dict(cls, d: dict, where: str | None = None):
        """Inverse of :meth:`to_dict`; a dict of another kind raises ValueError naming both."""
        where = cls.KIND if where is None else where
        kind = file_kind(d, where)
        if kind != cls.KIND:
            raise ValueError(f"{where}: holds a sensor model of kind {kind!r}, expected "
                             f"{cls.KIND!r} (load it with pipeline.sensormodels.load_competitor)")
        check_keys(d, _FILE_KEYS, where, required={"format", "kind", "rssi_range_dbm", "params"})
        if d["format"] != COMPETITOR_FORMAT:
            raise ValueError(f"{where}: format {d['format']!r}, expected {COMPETITOR_FORMAT!r}")
        rng = check_rssi_range(d["rssi_range_dbm"], f"{where}: rssi_range_dbm")
        return cls.from_params(d["params"], rng, f"{where}: params")

    def save(self, path) -> Path:
        """Write the model as JSON (temporary file + rename); returns the path."""
        return write_json_atomic(self.to_dict(), path)

    @classmethod
    def load(cls, path):
        """Read a file written by :meth:`save`; errors name the file (and both kinds)."""
        return cls.from_dict(read_model_file(path), str(path))
