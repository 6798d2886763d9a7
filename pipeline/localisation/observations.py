"""Read attempts arranged for localisation: tags x attempt slots, and their geometry.

An *attempt slot* is one read cycle of one reader antenna at one antenna pose (the
``(cycle, antenna)`` of ``eval_reads.parquet``); in a slot the reader tries every tag of
the inventory, so a read log of S slots and T tags is a (T, S) matrix of outcomes
(read or not, RSSI of a read). What a tag localiser needs from a slot is the antenna
pose; the outcomes of the tags are what differs from tag to tag. Keeping the two apart
lets the expensive part, the sensor-model predictions over (slot, candidate position)
pairs, be computed once and reused for every tag (:mod:`pipeline.localisation.tags`).

:func:`pair_geometry` is the antenna-frame geometry of
:func:`propagation.antenna_frame_angles` (same frame convention: boresight local +x,
``R = Rz(yaw) Ry(-pitch) Rx(roll)``, alpha = atan2(y_local, x_local)) written component
by component, with the bearing computed only where it is needed (pairs within a
distance), which is several times faster on the (slots x candidates) matrices here.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import NamedTuple

import numpy as np
import pandas as pd

from propagation.patterns import as_pose6

__all__ = [
    "Observations",
    "as_pose6",
    "local_xy_axes",
    "near_geometry",
    "observations_from_reads",
    "pair_geometry",
]


def pair_geometry(antenna_poses, points, alpha_within_m: float = np.inf):
    """Distance and bearing of `points` seen from `antenna_poses`, every pair.

    Parameters
    ----------
    antenna_poses : array_like, shape (n, 4) or (n, 6)
        [x_m, y_m, z_m, yaw_rad(, pitch_rad, roll_rad)], world frame.
    points : array_like, shape (k, 3)
        World points [m].
    alpha_within_m : float
        The bearing is computed only for pairs closer than this [m] (NaN elsewhere);
        default everywhere.

    Returns
    -------
    d_m, alpha_rad : numpy.ndarray, shape (n, k), float64
        As :func:`propagation.antenna_frame_angles` (alpha in (-pi, pi]).
    """
    if np.isinf(alpha_within_m):
        o = _pair_offsets(antenna_poses, points)
        ax = o.axes[:, None, :]  # local x and y axes (n, 1, 6)
        lx = ax[..., 0] * o.dx + ax[..., 1] * o.dy + ax[..., 2] * o.dz
        ly = ax[..., 3] * o.dx + ax[..., 4] * o.dy + ax[..., 5] * o.dz
        return o.d, _wrapped_bearing(ly, lx)
    d, sel, alpha_sel = near_geometry(antenna_poses, points, alpha_within_m)
    alpha = np.full(d.shape, np.nan)
    alpha.ravel()[sel] = alpha_sel
    return d, alpha


def near_geometry(antenna_poses, points, within_m: float):
    """Distance of every pair, bearing of the pairs closer than `within_m` only.

    The arithmetic of :func:`pair_geometry` (which this is, less the NaN-filled bearing
    matrix), for a caller that only needs the near pairs' bearings (the robot filter:
    :meth:`~.likelihood.ModelLikelihood.pose_loglik`).

    Parameters
    ----------
    antenna_poses : array_like, shape (n, 4) or (n, 6)
    points : array_like, shape (k, 3)
    within_m : float
        Finite distance [m].

    Returns
    -------
    d_m : numpy.ndarray, shape (n, k), float64
    sel : numpy.ndarray, shape (m,), int64
        Flat (row-major) indices into ``d_m`` of the pairs with ``d_m < within_m``, ascending.
    alpha_rad : numpy.ndarray, shape (m,), float64
        Their bearings, in (-pi, pi].
    """
    o = _pair_offsets(antenna_poses, points)
    d = o.d
    # the bearing of the pairs within reach only, gathered through flat indices (one
    # gather of both local axes per pair; the robot filter keeps ~20 % of its pairs)
    sel = np.flatnonzero(d < float(within_m))
    if not len(sel):
        return d, sel, np.zeros(0)
    axes = o.axes[sel // d.shape[1]]  # (m, 6)
    ex, ey, ez = o.dx.ravel()[sel], o.dy.ravel()[sel], o.dz.ravel()[sel]
    lx = axes[:, 0] * ex + axes[:, 1] * ey + axes[:, 2] * ez
    ly = axes[:, 3] * ex + axes[:, 4] * ey + axes[:, 5] * ez
    return d, sel, _wrapped_bearing(ly, lx)


class _PairOffsets(NamedTuple):
    """World-frame offsets of every (pose, point) pair, (n, k) each, their distances, and
    the poses' local x and y axes in world coordinates (n, 6: x axis, then y axis)."""

    axes: np.ndarray
    dx: np.ndarray
    dy: np.ndarray
    dz: np.ndarray
    d: np.ndarray


def _pair_offsets(antenna_poses, points) -> _PairOffsets:
    p = as_pose6(antenna_poses)
    pts = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    dx = pts[None, :, 0] - p[:, None, 0]
    dy = pts[None, :, 1] - p[:, None, 1]
    dz = pts[None, :, 2] - p[:, None, 2]
    return _PairOffsets(local_xy_axes(p), dx, dy, dz, np.sqrt(dx * dx + dy * dy + dz * dz))


def local_xy_axes(antenna_poses) -> np.ndarray:
    """The first two columns of :func:`propagation.patterns.pose_rotation`, bit for bit.

    The robot filter's poses share their pitch and roll (one antenna mount): their sines
    and cosines are taken once and the products are formed as ``rotation_matrix`` forms
    them (the same operations in the same order, so the same bits), a third of the work
    of the full matrices.

    Parameters
    ----------
    antenna_poses : array_like, shape (n, 4) or (n, 6)

    Returns
    -------
    numpy.ndarray, shape (n, 6), float64
        Local x axis (boresight), then local y axis, in world coordinates.
    """
    p = as_pose6(antenna_poses)
    yaw, beta, gamma = p[:, 3], -p[:, 4], p[:, 5]
    if len(p) and np.all(beta == beta[0]) and np.all(gamma == gamma[0]):
        beta, gamma = beta[:1], gamma[:1]  # one mount: broadcast below
    sa, ca = np.sin(yaw), np.cos(yaw)
    sb, cb, sc, cc = np.sin(beta), np.cos(beta), np.sin(gamma), np.cos(gamma)
    axes = np.empty((len(p), 6))
    axes[:, 0] = ca * cb
    axes[:, 1] = sa * cb
    axes[:, 2] = -sb
    axes[:, 3] = ca * sb * sc - sa * cc
    axes[:, 4] = sa * sb * sc + ca * cc
    axes[:, 5] = cb * sc
    return axes


def _wrapped_bearing(ly: np.ndarray, lx: np.ndarray) -> np.ndarray:
    """``atan2(ly, lx)`` in (-pi, pi]: atan2 gives -pi behind the antenna where ly is -0.0
    or rounds to it."""
    alpha = np.arctan2(ly, lx)
    return np.where(alpha <= -np.pi, alpha + 2.0 * np.pi, alpha)


@dataclass(frozen=True)
class Observations:
    """Outcomes of the read attempts of T tags over S attempt slots.

    Attributes
    ----------
    tag_ids : tuple of str
        The T tags, in row order.
    slot_time_s : numpy.ndarray, shape (S,)
        Time of each slot [s], increasing.
    slot_antenna : numpy.ndarray, shape (S,), int64
        Antenna index of each slot.
    slot_poses : numpy.ndarray, shape (S, 6)
        Antenna pose of each slot [x_m, y_m, z_m, yaw_rad, pitch_rad, roll_rad] (the
        pose the localiser believes: MCL, or the truth for a reference run).
    read : numpy.ndarray, shape (T, S), bool
        The tag was read in the slot.
    rssi_dbm : numpy.ndarray, shape (T, S), float64
        RSSI of a read [dBm]; NaN where not read (or read without an RSSI).
    attempted : numpy.ndarray, shape (T, S), bool
        The slot tried to read the tag (a missing row of the log is not an attempt).
    """

    tag_ids: tuple
    slot_time_s: np.ndarray
    slot_antenna: np.ndarray
    slot_poses: np.ndarray
    read: np.ndarray
    rssi_dbm: np.ndarray
    attempted: np.ndarray

    def __post_init__(self) -> None:
        ids = tuple(str(t) for t in self.tag_ids)
        if len(set(ids)) != len(ids):
            raise ValueError(f"Observations: duplicate tag ids {sorted(ids)}")
        object.__setattr__(self, "tag_ids", ids)
        t = np.asarray(self.slot_time_s, dtype=np.float64).reshape(-1)
        s = len(t)
        object.__setattr__(self, "slot_time_s", t)
        ant = np.asarray(self.slot_antenna, dtype=np.int64).reshape(-1)
        poses = as_pose6(self.slot_poses) if s else np.zeros((0, 6))
        if ant.shape != (s,) or poses.shape != (s, 6):
            raise ValueError(f"Observations: {s} slot times but slot_antenna {ant.shape} and "
                             f"slot_poses {poses.shape}")
        if not (np.all(np.isfinite(t)) and np.all(np.isfinite(poses))):
            raise ValueError("Observations: slot times and poses must be finite")
        object.__setattr__(self, "slot_antenna", ant)
        object.__setattr__(self, "slot_poses", poses)
        shape = (len(ids), s)
        read = np.asarray(self.read, dtype=bool)
        rssi = np.asarray(self.rssi_dbm, dtype=np.float64)
        att = np.asarray(self.attempted, dtype=bool)
        for name, v in (("read", read), ("rssi_dbm", rssi), ("attempted", att)):
            if v.shape != shape:
                raise ValueError(f"Observations: {name} has shape {v.shape}, expected {shape} "
                                 "(tags x slots)")
        if np.any(read & ~att):
            raise ValueError("Observations: a tag is read in a slot that did not attempt it")
        object.__setattr__(self, "read", read)
        object.__setattr__(self, "rssi_dbm", np.where(read, rssi, np.nan))
        object.__setattr__(self, "attempted", att)

    @property
    def n_tags(self) -> int:
        return len(self.tag_ids)

    @property
    def n_slots(self) -> int:
        return len(self.slot_time_s)

    def index_of(self, tag_ids: Sequence) -> np.ndarray:
        """Row index of each of `tag_ids`; ValueError naming the ids this log lacks."""
        pos = {t: i for i, t in enumerate(self.tag_ids)}
        ids = [str(t) for t in tag_ids]
        unknown = [t for t in ids if t not in pos]
        if unknown:
            raise ValueError(f"tag id(s) {unknown} not in the read log (it has "
                             f"{len(self.tag_ids)} tags: {list(self.tag_ids)[:20]})")
        return np.array([pos[t] for t in ids], dtype=np.int64)

    def select(self, tag_ids: Sequence) -> Observations:
        """The rows of `tag_ids` (in that order), all slots."""
        idx = self.index_of(tag_ids)
        return Observations(tuple(self.tag_ids[i] for i in idx), self.slot_time_s,
                            self.slot_antenna, self.slot_poses, self.read[idx],
                            self.rssi_dbm[idx], self.attempted[idx])


_POSE_COLS = ("x_m", "y_m", "z_m", "yaw_rad")


def observations_from_reads(reads: pd.DataFrame, pose: str = "est", *,
                            tag_ids: Sequence | None = None,
                            pitch_rad: Mapping | Sequence | float | None = None,
                            table: str = "eval_reads") -> Observations:
    """Arrange a ``reads.parquet``-format table (one row per attempt) as :class:`Observations`.

    Parameters
    ----------
    reads : pandas.DataFrame
        Columns ``time_s, cycle, antenna, tag_id, read, rssi_dbm`` and
        ``<pose>_ant_x_m, _y_m, _z_m, _yaw_rad`` (:data:`pipeline.acquisition.READ_COLUMNS`).
    pose : {"est", "true"}
        Antenna poses: the MCL estimate (what the robot knows) or the ground truth.
    tag_ids : sequence of str, optional
        Tags to keep, in this order; default every tag of the table (in the order of
        its categories if ``tag_id`` is categorical, as in ``reads.parquet``, else of
        first attempt). A requested id the table lacks raises ValueError naming it.
    pitch_rad : float, sequence or mapping, optional
        Antenna tilt (the table keeps no pitch): one value, one per antenna index, or
        ``{antenna index: pitch}``; default 0 (the default mounts are not tilted).
    table : str
        Name of the table in error messages.

    Returns
    -------
    Observations
        Slots are the distinct ``(cycle, antenna)`` pairs in time order; the slot pose is
        that of its first row (all rows of a slot share it).
    """
    if pose not in ("est", "true"):
        raise ValueError(f"pose must be 'est' or 'true', got {pose!r}")
    if not isinstance(reads, pd.DataFrame):
        raise ValueError(f"{table}: expected a pandas DataFrame, got {type(reads).__name__}")
    pcols = [f"{pose}_ant_{c}" for c in _POSE_COLS]
    need = ["time_s", "cycle", "antenna", "tag_id", "read", "rssi_dbm", *pcols]
    missing = [c for c in need if c not in reads.columns]
    if missing:
        raise ValueError(f"{table}: missing column(s) {missing}")
    if len(reads) == 0:
        raise ValueError(f"{table}: the read log is empty (no read attempts to localise from)")
    cyc = reads["cycle"].to_numpy(np.int64)
    ant = reads["antenna"].to_numpy(np.int64)
    key = np.stack([cyc, ant], axis=1)
    uniq, first, inv = np.unique(key, axis=0, return_index=True, return_inverse=True)
    inv = inv.reshape(-1)
    t_all = reads["time_s"].to_numpy(np.float64)
    order = np.lexsort((uniq[:, 1], t_all[first]))  # slots in time order
    rank = np.empty_like(order)
    rank[order] = np.arange(len(order))
    slot_of_row = rank[inv]
    first = first[order]
    poses4 = np.column_stack([reads[c].to_numpy(np.float64)[first] for c in pcols])
    slot_ant = ant[first]
    pitch = np.zeros(len(first))
    if pitch_rad is not None:
        if isinstance(pitch_rad, Mapping):
            lut = {int(k): float(v) for k, v in pitch_rad.items()}
            pitch = np.array([lut.get(int(a), 0.0) for a in slot_ant])
        elif np.ndim(pitch_rad) == 0:
            pitch = np.full(len(first), float(pitch_rad))
        else:
            arr = np.asarray(pitch_rad, dtype=np.float64)
            if np.any(slot_ant >= len(arr)):
                raise ValueError(f"pitch_rad has {len(arr)} entries, the log uses antenna "
                                 f"{int(slot_ant.max())}")
            pitch = arr[slot_ant]
    poses = np.column_stack([poses4, pitch, np.zeros(len(first))])
    if not np.all(np.isfinite(poses)):
        bad = int(np.sum(~np.all(np.isfinite(poses), axis=1)))
        raise ValueError(f"{table}: {bad} slot(s) with non-finite {pose} antenna poses")
    tags_col = reads["tag_id"].astype(str).to_numpy()
    seen = set(tags_col)
    if isinstance(reads["tag_id"].dtype, pd.CategoricalDtype):  # the table's tag order
        present = [str(c) for c in reads["tag_id"].cat.categories if str(c) in seen]
    else:  # order of first attempt
        present = list(pd.unique(tags_col[np.argsort(slot_of_row, kind="stable")]))
    if tag_ids is None:
        ids = present
    else:
        ids = [str(t) for t in tag_ids]
        unknown = [t for t in ids if t not in seen]
        if unknown:
            raise ValueError(f"{table}: tag id(s) {unknown} not in the read log (it has "
                             f"{len(present)} tags: {present[:20]})")
    row_of = {t: i for i, t in enumerate(ids)}
    tag_row = np.array([row_of.get(t, -1) for t in tags_col])
    keep = tag_row >= 0
    T, S = len(ids), len(first)
    flat = tag_row[keep] * S + slot_of_row[keep]
    if len(np.unique(flat)) != len(flat):
        raise ValueError(f"{table}: a tag appears twice in one (cycle, antenna) slot")
    read = np.zeros(T * S, dtype=bool)
    rssi = np.full(T * S, np.nan)
    att = np.zeros(T * S, dtype=bool)
    att[flat] = True
    read[flat] = reads["read"].to_numpy(bool)[keep]
    rssi[flat] = reads["rssi_dbm"].to_numpy(np.float64)[keep]
    return Observations(tuple(ids), t_all[first], slot_ant, poses, read.reshape(T, S),
                        rssi.reshape(T, S), att.reshape(T, S))
