"""Simulated UHF RFID reader: ray-traced gains become reads, misses and RSSI.

For every read attempt (read cycle, active antenna, tag) the one-way channel gain g
from the ray tracer (both antenna patterns included) goes through the monostatic
backscatter link budget of ``docs/physics.md``:

- power at the tag ``P_tag = P_tx + G(g) - L_pol``; the tag answers only if
  ``P_tag >= tag_sensitivity_dbm`` (forward link);
- backscatter power at the reader ``P_rx = P_tx + 2 G(g) + M - 2 L_pol``; the reader
  hears it only if ``P_rx >= reader_sensitivity_dbm`` (reverse link);
- a powered and heard tag is still lost with probability
  ``anticollision_miss_probability`` (Gen2 slot collisions), independently per attempt;
- a read reports ``RSSI = Q(P_rx + N(0, rssi_noise_db^2))`` with ``Q`` rounding to the
  reader's resolution. The thresholds act on the noise-free powers: the RSSI noise is
  the reader's measurement error, not a change of the link.

Pairs farther apart than the budget's free-space maximum range (maximum pattern gains,
plus ``range_margin_db`` for constructive multipath) cannot be read and are not traced.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pandas as pd

from pipeline.acquisition.config import ReaderConfig, reader_metadata
from pipeline.acquisition.readlog import POSE_COLUMNS, READ_COLUMNS, ReadLog
from pipeline.acquisition.track import PoseTrack, as_pose_track, interpolate_poses
from propagation import antenna_frame_angles

__all__ = [
    "ReadAttempts",
    "ReaderResponse",
    "in_range_mask",
    "read_attempts",
    "reader_response",
    "reads_from_gains",
    "simulate_reads",
]

logger = logging.getLogger(__name__)


@dataclass(frozen=True)
class ReaderResponse:
    """What the reader makes of a batch of one-way gains.

    Attributes
    ----------
    tag_power_dbm : numpy.ndarray
        Power at the tag chip, same shape as the gains, float64, dBm (-inf for gain 0).
    rx_power_dbm : numpy.ndarray
        Noise-free backscatter power at the reader, float64, dBm.
    powered : numpy.ndarray
        bool, ``tag_power_dbm >= tag_sensitivity_dbm`` (forward link closes).
    heard : numpy.ndarray
        bool, ``rx_power_dbm >= reader_sensitivity_dbm`` (reverse link closes).
    collided : numpy.ndarray
        bool, lost to anti-collision although powered and heard.
    read : numpy.ndarray
        bool, ``powered & heard & ~collided``.
    rssi_dbm : numpy.ndarray
        Reported RSSI with noise and quantisation, float64, dBm; NaN where not read.
    """

    tag_power_dbm: np.ndarray
    rx_power_dbm: np.ndarray
    powered: np.ndarray
    heard: np.ndarray
    collided: np.ndarray
    read: np.ndarray
    rssi_dbm: np.ndarray


def reader_response(
    gain_db: np.ndarray, reader: ReaderConfig, rng: np.random.Generator
) -> ReaderResponse:
    """Apply the backscatter link budget, anti-collision losses, noise and quantisation.

    Parameters
    ----------
    gain_db : array_like
        One-way channel power gains in dB (both antenna patterns included), any shape;
        -inf for links that were not traced.
    reader : ReaderConfig
        Reader (thresholds come from ``reader.link_budget()``; they do not depend on
        the carrier frequency).
    rng : numpy.random.Generator
        Source of the anti-collision losses and RSSI noise. Exactly two arrays of
        ``gain_db.size`` draws are taken (uniform, then standard normal), whatever the
        gains, so runs are reproducible and independent of which links read.

    Returns
    -------
    ReaderResponse
    """
    g = np.asarray(gain_db, dtype=float)
    b = reader.link_budget()
    u = rng.random(g.shape)
    z = rng.standard_normal(g.shape)
    with np.errstate(invalid="ignore"):
        p_tag = np.asarray(b.tag_power_dbm(g), dtype=float)
        p_rx = np.asarray(b.reader_rssi_dbm(g), dtype=float)
    powered = p_tag >= b.tag_sensitivity_dbm
    heard = p_rx >= b.reader_sensitivity_dbm
    collided = powered & heard & (u < reader.anticollision_miss_probability)
    read = powered & heard & ~collided
    rssi = p_rx + reader.rssi_noise_db * z
    if reader.rssi_resolution_db > 0:
        rssi = np.round(rssi / reader.rssi_resolution_db) * reader.rssi_resolution_db
    rssi = np.where(read, rssi, np.nan)
    return ReaderResponse(p_tag, p_rx, powered, heard, collided, read, rssi)


@dataclass(frozen=True)
class ReadAttempts:
    """When and with which antenna the reader tries to read, and where the robot is.

    Attributes
    ----------
    time_s : numpy.ndarray
        Attempt times, shape (n,), float64, seconds.
    cycle : numpy.ndarray
        Read-cycle index of each attempt, shape (n,), int64.
    antenna : numpy.ndarray
        Active antenna index, shape (n,), int64.
    true_robot : numpy.ndarray
        True robot pose at each attempt, shape (n, 3).
    est_robot : numpy.ndarray
        Estimated robot pose at each attempt, shape (n, 3).
    true_antenna : numpy.ndarray
        True pose of the active antenna, shape (n, 6) [x, y, z, yaw, pitch, roll].
    est_antenna : numpy.ndarray
        Active antenna pose composed from the estimated robot pose, shape (n, 6).
    """

    time_s: np.ndarray
    cycle: np.ndarray
    antenna: np.ndarray
    true_robot: np.ndarray
    est_robot: np.ndarray
    true_antenna: np.ndarray
    est_antenna: np.ndarray


def read_attempts(track: PoseTrack, mounts: list, reader: ReaderConfig) -> ReadAttempts:
    """Read-attempt schedule along a track, with true and estimated antenna poses.

    Cycle ``k`` starts at ``t_0 + k / read_rate_hz`` for every start within the track.
    ``round_robin``: one attempt per cycle, antenna ``k mod n_antennas``. ``all``: one
    attempt per antenna, antenna ``a`` at ``t_k + a / (read_rate_hz n_antennas)``.
    Robot poses are interpolated linearly (heading along the shortest arc) and composed
    with the mounts by :func:`pipeline.robot.antenna_poses`.
    """
    from pipeline.robot.kinematics import antenna_poses

    n_ant = len(mounts)
    if n_ant == 0:
        raise ValueError("the robot has no antennas")
    t0, t1 = float(track.t_s[0]), float(track.t_s[-1])
    n_cycles = int(np.floor((t1 - t0) * reader.read_rate_hz + 1e-9)) + 1
    k = np.arange(n_cycles)
    if reader.antenna_mode == "round_robin":
        cycle, antenna = k, k % n_ant
        t = t0 + k / reader.read_rate_hz
    else:
        cycle = np.repeat(k, n_ant)
        antenna = np.tile(np.arange(n_ant), n_cycles)
        t = t0 + cycle / reader.read_rate_hz + antenna / (reader.read_rate_hz * n_ant)
        keep = t <= t1
        cycle, antenna, t = cycle[keep], antenna[keep], t[keep]
    true_robot = interpolate_poses(track.t_s, track.true_poses, t)
    est_robot = interpolate_poses(track.t_s, track.est_poses, t)
    rows = np.arange(len(t))
    true_ant = antenna_poses(true_robot, mounts)[rows, antenna]
    est_ant = antenna_poses(est_robot, mounts)[rows, antenna]
    return ReadAttempts(t, cycle, antenna, true_robot, est_robot, true_ant, est_ant)


def in_range_mask(d_m: np.ndarray, reader: ReaderConfig, frequency_hz: float | None = None
                  ) -> np.ndarray:
    """Pairs that could possibly be read, hence worth tracing: ``d <= max_range``.

    ``max_range = reader.link_budget(frequency_hz).max_range_m(margin_db=reader.range_margin_db)``:
    the free-space distance at which a tag seen with both antennas' maximum gains, plus
    the margin for constructive multipath, receives exactly its sensitivity.
    """
    r = float(reader.link_budget(frequency_hz).max_range_m(margin_db=reader.range_margin_db))
    return np.asarray(d_m) <= r


def _trace_gains(scene, tags, poses6: np.ndarray, mask: np.ndarray, frequency_hz: float,
                 trace: dict):
    """Trace the masked pairs (unique antenna poses only); gains (n, m) in dB and traced."""
    from propagation import trace_links

    n, m = mask.shape
    gain_db = np.full((n, m), -np.inf)
    traced = np.zeros((n, m), dtype=bool)
    rows = np.flatnonzero(mask.any(axis=1))
    if len(rows) == 0:
        return gain_db, traced, 0
    uniq, inv = np.unique(poses6[rows], axis=0, return_inverse=True)
    inv = inv.reshape(-1)
    umask = np.zeros((len(uniq), m), dtype=bool)
    np.logical_or.at(umask, inv, mask[rows])
    kw = {"tag_normals": tags.normals, **trace}
    links = trace_links(
        scene,
        uniq,
        tags.positions_m,
        frequency_hz=frequency_hz,
        pairs=umask,
        **kw,
    )
    g = np.asarray(links.gain_db, dtype=float)[inv]
    t = np.asarray(links.traced, dtype=bool)[inv]
    sel = mask[rows] & t
    gain_db[rows] = np.where(sel, g, -np.inf)
    traced[rows] = sel
    return gain_db, traced, int(np.asarray(links.traced).sum())


def _poses_frame(track: PoseTrack) -> pd.DataFrame:
    cols = {"time_s": track.t_s}
    for prefix, arr in (
        ("true", track.true_poses),
        ("odom", track.odom_poses),
        ("est", track.est_poses),
    ):
        cols[f"{prefix}_x_m"] = arr[:, 0]
        cols[f"{prefix}_y_m"] = arr[:, 1]
        cols[f"{prefix}_theta_rad"] = arr[:, 2]
    return pd.DataFrame(cols, columns=list(POSE_COLUMNS)).astype(POSE_COLUMNS)


def reads_from_gains(
    attempts: ReadAttempts,
    tags,
    gain_db: np.ndarray,
    traced: np.ndarray,
    reader: ReaderConfig,
    rng: np.random.Generator,
) -> pd.DataFrame:
    """The read table of a schedule whose gains are known (traced or from a cache).

    Parameters
    ----------
    attempts : ReadAttempts
        Schedule and antenna poses, n attempts.
    tags : scenes.TagSet
        m tags.
    gain_db : numpy.ndarray
        One-way gains (n, m), dB; -inf where not traced.
    traced : numpy.ndarray
        bool (n, m), pairs that were traced (``in_range`` column).
    reader : ReaderConfig
    rng : numpy.random.Generator
        Passed to :func:`reader_response`.

    Returns
    -------
    pandas.DataFrame
        n * m rows, attempt-major, columns :data:`READ_COLUMNS`.
    """
    att = attempts
    n, m = len(att.time_s), len(tags)
    geo_t = antenna_frame_angles(att.true_antenna, tags.positions_m)
    geo_e = antenna_frame_angles(att.est_antenna, tags.positions_m)
    resp = reader_response(np.asarray(gain_db, dtype=float).reshape(-1), reader, rng)
    rep = np.repeat
    cols = {
        "time_s": rep(att.time_s, m),
        "cycle": rep(att.cycle, m),
        "antenna": rep(att.antenna, m),
        "tag_id": pd.Categorical.from_codes(
            np.tile(np.arange(m), n), categories=[str(i) for i in tags.ids]
        ),
        "read": resp.read,
        "rssi_dbm": resp.rssi_dbm,
    }
    for prefix, p in (("true", att.true_antenna), ("est", att.est_antenna)):
        for j, name in enumerate(("x_m", "y_m", "z_m", "yaw_rad")):
            cols[f"{prefix}_ant_{name}"] = rep(p[:, j], m)
    cols.update(
        d_true_m=geo_t.d_m.reshape(-1),
        alpha_true_rad=geo_t.alpha_rad.reshape(-1),
        d_est_m=geo_e.d_m.reshape(-1),
        alpha_est_rad=geo_e.alpha_rad.reshape(-1),
        gain_db=np.asarray(gain_db).reshape(-1),
        tag_power_dbm=resp.tag_power_dbm,
        rx_power_dbm=resp.rx_power_dbm,
        powered=resp.powered,
        in_range=np.asarray(traced, dtype=bool).reshape(-1),
    )
    return pd.DataFrame(cols, columns=list(READ_COLUMNS)).astype(READ_COLUMNS)


def simulate_reads(
    scene,
    robot,
    track,
    reader: ReaderConfig,
    rng: np.random.Generator,
    *,
    trace: dict | None = None,
    cache_dir: str | Path | None = None,
    tags=None,
    frequency_hz: float | None = None,
) -> ReadLog:
    """Simulate the reader along a robot track in a ray-traced scene.

    Parameters
    ----------
    scene : scenes.Scene
        The scene; its tags are the population the reader inventories unless `tags`
        is given.
    robot : pipeline.robot.Robot
        Supplies the antenna mounts (``robot.antennas``).
    track : PoseTrack, LocalizationResult, Trajectory or tuple
        True and estimated robot poses over time, see
        :func:`pipeline.acquisition.track.as_pose_track`; a tuple is
        ``(true_poses, est_poses, t_s)``.
    reader : ReaderConfig
        Read rate, antenna multiplexing, noise, quantisation, powers, sensitivities and
        losses (the study's ``[reader]``).
    rng : numpy.random.Generator
        Source of anti-collision losses and RSSI noise.
    trace : dict, optional
        Keyword arguments for :func:`propagation.trace_links` (``max_depth``,
        ``samples_per_src``, ``reader_pattern``, ``tag_pattern``, ...);
        ``frequency_hz`` is the argument below and ``pairs`` comes from the range mask.
    cache_dir : str or Path, optional
        Trace cache directory passed to :func:`propagation.trace_links`.
    tags : scenes.TagSet, optional
        The tags this tour can read (e.g. only the training or only the held-out
        layout); default ``scene.tags``.
    frequency_hz : float, optional
        Carrier frequency [Hz] (default: :class:`propagation.LinkBudget`'s).

    Returns
    -------
    ReadLog
        One row per (attempt, tag) with columns :data:`READ_COLUMNS`; rows of untraced
        (out-of-range) pairs have ``in_range`` False, ``read`` False, ``gain_db`` -inf.
        ``metadata`` counts the traced pairs (``n_pairs_traced``).
    """
    trk = as_pose_track(track)
    trace = dict(trace or {})
    for key in ("frequency_hz", "pairs"):
        if key in trace:
            raise ValueError(f"simulate_reads: trace[{key!r}] is set by the reader, remove it")
    if cache_dir is not None:
        trace["cache_dir"] = cache_dir
    budget = reader.link_budget(frequency_hz)
    mounts = list(robot.antennas)
    att = read_attempts(trk, mounts, reader)
    tags = scene.tags if tags is None else tags
    n, m = len(att.time_s), len(tags)
    d_true = antenna_frame_angles(att.true_antenna, tags.positions_m).d_m
    mask = in_range_mask(d_true, reader, budget.frequency_hz)
    gain_db, traced, n_traced = _trace_gains(scene, tags, att.true_antenna, mask,
                                             budget.frequency_hz, trace)
    reads = reads_from_gains(att, tags, gain_db, traced, reader, rng)
    excess_db = _check_margin(gain_db, traced, d_true, reader.range_margin_db, budget)
    meta = {
        "scene": scene.name,
        "scene_hash": scene.content_hash(),
        "antennas": [getattr(a, "name", str(i)) for i, a in enumerate(mounts)],
        "tag_ids": [str(i) for i in tags.ids],
        "reader": reader_metadata(reader, budget),
        "trace": {k: v for k, v in trace.items() if k not in ("cache_dir", "progress")},
        "n_slots": int(n),  # (cycle, active antenna) slots; rows = n_slots * n_tags
        "n_pairs": int(n * m),
        "n_pairs_in_range": int(mask.sum()),
        "n_pairs_traced": int(n_traced),
        "max_range_m": float(budget.max_range_m(margin_db=reader.range_margin_db)),
        "range_margin_db": float(reader.range_margin_db),
        "max_excess_over_free_space_db": excess_db,
    }
    logger.info(
        "simulate_reads: %d antenna slots x %d tags, %d pairs in range (%d unique traced), %d reads",
        n,
        m,
        int(mask.sum()),
        n_traced,
        int(reads["read"].sum()),
    )
    return ReadLog(reads=reads, poses=_poses_frame(trk), metadata=meta)


def _check_margin(gain_db, traced, d_m, range_margin_db: float, budget) -> float | None:
    """Largest excess of a traced gain over free space with maximum pattern gains [dB].

    Links beyond ``max_range_m(range_margin_db)`` are not traced; an excess above the
    margin on the traced links says some of them might have been readable. The value is
    recorded in the read log's metadata and reported (metrics ``reads.range_margin``,
    report); the log says so at INFO level. None when nothing was traced.
    """
    if not traced.any():
        return None
    from propagation import free_space_gain_db

    b = budget
    fs = free_space_gain_db(
        d_m[traced],
        b.frequency_hz,
        gain_tx_dbi=b.reader_antenna_gain_dbi,
        gain_rx_dbi=b.tag_antenna_gain_dbi,
    )
    excess = float(np.max(gain_db[traced] - fs))
    if excess > range_margin_db:
        logger.info(
            "ray-traced gain exceeds free space with maximum pattern gains by %.1f dB, more "
            "than range_margin_db = %.1f dB: tags beyond the traced range might have been "
            "readable (recorded in metrics.json reads.range_margin)",
            excess,
            range_margin_db,
        )
    return excess
