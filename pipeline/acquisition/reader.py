"""Simulated UHF RFID reader: ray-traced gains become reads, misses and RSSI.

For every read attempt (read cycle, active antenna, tag) the one-way channel gain g
from the ray tracer (both antenna patterns included) goes through the monostatic
backscatter link budget of ``docs/physics.md``:

- power at the tag ``P_tag = P_tx + G(g) - L_pol``; the tag answers only if
  ``P_tag >= tag_sensitivity_dbm`` (forward link);
- backscatter power at the reader ``P_rx = P_tx + 2 G(g) + M - 2 L_pol``; the reader
  hears it only if ``P_rx >= reader_sensitivity_dbm`` (reverse link);
- a powered and heard tag is still lost with probability
  ``anticollision_miss_probability`` (``inventory = "fixed"``), independently per
  attempt, or is singulated ``seen_count`` times by the EPC Gen2 Q algorithm during the
  antenna's dwell (``inventory = "gen2"``, :mod:`pipeline.acquisition.gen2`);
- a read reports ``RSSI = Q(P_rx + N(0, rssi_noise_db^2))`` with ``Q`` rounding to the
  reader's resolution. The thresholds act on the noise-free powers: the RSSI noise is
  the reader's measurement error, not a change of the link;
- each tag deviates from the nominal one (:mod:`pipeline.acquisition.population`):
  its sensitivity and modulation factor are offset, and a tag on metal loses gain;
- every attempt happens on a channel of the reader's regional hop sequence
  (:mod:`pipeline.acquisition.channels`), the gain is the coherent sum at that channel,
  and a read also reports the backscatter phase and the Doppler shift
  (:mod:`pipeline.acquisition.phase`).

Pairs farther apart than the budget's free-space maximum range (maximum pattern gains,
plus ``range_margin_db`` for constructive multipath) cannot be read and are not traced.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import pandas as pd

from pipeline.acquisition.channels import ChannelPlan, channel_schedule
from pipeline.acquisition.config import ReaderConfig
from pipeline.acquisition.gen2 import InventoryStats, inventory_counts
from pipeline.acquisition.phase import (
    antenna_velocity,
    doppler_hz,
    phase_offsets,
    power_phase_rad,
    reported_phase_rad,
)
from pipeline.acquisition.population import TagPopulation
from pipeline.acquisition.readlog import READ_COLUMNS
from pipeline.acquisition.track import PoseTrack, interpolate_poses
from pipeline.robot.kinematics import antenna_poses
from propagation import antenna_frame_angles

__all__ = [
    "ReadAttempts",
    "ReaderResponse",
    "in_range_mask",
    "read_attempts",
    "reader_response",
    "reads_from_gains",
]


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
    seen_count : numpy.ndarray
        Times the tag was singulated in the attempt, int64 (``read`` as 0/1 in the
        ``"fixed"`` inventory).
    """

    tag_power_dbm: np.ndarray
    rx_power_dbm: np.ndarray
    powered: np.ndarray
    heard: np.ndarray
    collided: np.ndarray
    read: np.ndarray
    rssi_dbm: np.ndarray
    seen_count: np.ndarray


def reader_response(
    gain_db: np.ndarray, reader: ReaderConfig, rng: np.random.Generator, *,
    sensitivity_offset_db=0.0, modulation_offset_db=0.0, tag_loss_db=0.0, inventory=None,
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
    sensitivity_offset_db, modulation_offset_db, tag_loss_db : array_like
        Per-entry tag deviations (broadcast to ``gain_db``; :class:`TagPopulation`): the
        tag's threshold is ``tag_sensitivity_dbm + sensitivity_offset_db``; ``P_tag`` loses
        ``tag_loss_db``; ``P_rx`` loses ``2 tag_loss_db`` and gains ``modulation_offset_db``.
    inventory : callable, optional
        ``inventory(powered, heard) -> seen_count`` (same shape, int): the Gen2 inventory
        replacing ``anticollision_miss_probability`` (the uniform draws are still taken).

    Returns
    -------
    ReaderResponse
    """
    g = np.asarray(gain_db, dtype=float)
    b = reader.link_budget()
    u = rng.random(g.shape)
    z = rng.standard_normal(g.shape)
    with np.errstate(invalid="ignore"):
        p_tag = np.asarray(b.tag_power_dbm(g), dtype=float) - tag_loss_db
        p_rx = (np.asarray(b.reader_rssi_dbm(g), dtype=float) - 2.0 * np.asarray(tag_loss_db)
                + modulation_offset_db)
    p_tag = np.broadcast_to(p_tag, g.shape).astype(float)
    p_rx = np.broadcast_to(p_rx, g.shape).astype(float)
    powered = p_tag >= b.tag_sensitivity_dbm + np.asarray(sensitivity_offset_db)
    heard = p_rx >= b.reader_sensitivity_dbm
    if inventory is None:
        collided = powered & heard & (u < reader.anticollision_miss_probability)
        read = powered & heard & ~collided
        seen = read.astype(np.int64)
    else:
        seen = np.asarray(inventory(powered, heard), dtype=np.int64).reshape(g.shape)
        read = powered & heard & (seen > 0)
        collided = powered & heard & ~read
    rssi = p_rx + reader.rssi_noise_db * z
    if reader.rssi_resolution_db > 0:
        rssi = np.round(rssi / reader.rssi_resolution_db) * reader.rssi_resolution_db
    rssi = np.where(read, rssi, np.nan)
    return ReaderResponse(p_tag, p_rx, powered, heard, collided, read, rssi, seen)


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
    channel_index : numpy.ndarray
        Index into ``plan.channels_hz`` of each attempt's channel, shape (n,), int64.
    frequency_hz : numpy.ndarray
        Channel of each attempt, shape (n,), float64, Hz.
    antenna_velocity_mps : numpy.ndarray
        True velocity of the active antenna, shape (n, 3), float64, m/s.
    slot_s : float
        Length of one antenna slot [s] (``1 / read_rate_hz``, divided by the antennas in
        ``"all"`` mode): the time the antenna inventories, switching included.
    plan : ChannelPlan
        The channels in hop order and the dwell.
    """

    time_s: np.ndarray
    cycle: np.ndarray
    antenna: np.ndarray
    true_robot: np.ndarray
    est_robot: np.ndarray
    true_antenna: np.ndarray
    est_antenna: np.ndarray
    channel_index: np.ndarray
    frequency_hz: np.ndarray
    antenna_velocity_mps: np.ndarray
    slot_s: float
    plan: ChannelPlan


def read_attempts(track: PoseTrack, mounts: list, reader: ReaderConfig,
                  plan: ChannelPlan | None = None, frequency_hz: float | None = None) -> ReadAttempts:
    """Read-attempt schedule along a track, with true and estimated antenna poses.

    Cycle ``k`` starts at ``t_0 + k / read_rate_hz`` for every start within the track.
    ``round_robin``: one attempt per cycle, antenna ``k mod n_antennas``. ``all``: one
    attempt per antenna, antenna ``a`` at ``t_k + a / (read_rate_hz n_antennas)``.
    Robot poses are interpolated linearly (heading along the shortest arc) and composed
    with the mounts by :func:`pipeline.robot.antenna_poses`. Each attempt's channel
    follows ``plan`` (default: the reader's channels in listed order, region ``"none"``
    at ``frequency_hz``) from the track's start; the antenna's velocity is the central
    difference of its true pose over +-10 ms (one-sided at the track's ends).
    """
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

    def pose_at(tq):
        return antenna_poses(interpolate_poses(track.t_s, track.true_poses, tq), mounts)[rows, antenna]

    vel = antenna_velocity(t, pose_at, t_range_s=(t0, t1))
    plan = reader.channel_plan(frequency_hz) if plan is None else plan
    ch = channel_schedule(t, plan, t0)
    slot = reader.antenna_slot_s(n_ant)
    return ReadAttempts(t, cycle, antenna, true_robot, est_robot, true_ant, est_ant, ch,
                        plan.channels_hz[ch], vel, float(slot), plan)


def in_range_mask(d_m: np.ndarray, reader: ReaderConfig, frequency_hz: float | None = None,
                  extra_margin_db=0.0) -> np.ndarray:
    """Pairs that could possibly be read, hence worth tracing: ``d <= max_range``.

    ``max_range = reader.link_budget(frequency_hz).max_range_m(margin_db=reader.range_margin_db)``:
    the free-space distance at which a tag seen with both antennas' maximum gains, plus
    the margin for constructive multipath, receives exactly its sensitivity.
    ``extra_margin_db`` (broadcast to ``d_m``, e.g. per tag (m,)) widens it: a tag more
    sensitive than nominal reaches farther.
    """
    r = float(reader.link_budget(frequency_hz).max_range_m(margin_db=reader.range_margin_db))
    return np.asarray(d_m) <= r * 10.0 ** (np.asarray(extra_margin_db, dtype=float) / 20.0)


def reads_from_gains(
    attempts: ReadAttempts,
    tags,
    gain_db: np.ndarray,
    traced: np.ndarray,
    reader: ReaderConfig,
    rng: np.random.Generator,
    *,
    h: np.ndarray | None = None,
    dh_dpos: np.ndarray | None = None,
    population: TagPopulation | None = None,
    offsets_rad: np.ndarray | None = None,
    aux_rng: np.random.Generator | None = None,
    info: dict | None = None,
) -> pd.DataFrame:
    """The read table of a schedule whose gains are known (traced or from a cache).

    Parameters
    ----------
    attempts : ReadAttempts
        Schedule, channels and antenna poses, n attempts.
    tags : scenes.TagSet
        m tags.
    gain_db : numpy.ndarray
        One-way gains (n, m) at each attempt's channel, dB; -inf where not traced.
    traced : numpy.ndarray
        bool (n, m), pairs that were traced (``in_range`` column).
    reader : ReaderConfig
    rng : numpy.random.Generator
        Passed to :func:`reader_response` (the RSSI noise and fixed-mode misses).
    h, dh_dpos : numpy.ndarray, optional
        Channel coefficients (n, m) and their position derivative (n, m, 3) at each
        attempt's channel; without them ``phase_rad`` and ``doppler_hz`` are NaN.
    population : TagPopulation, optional
        Per-tag deviations, the tags' own phase offsets included; default the nominal tag
        (no deviation, phase offset 0).
    offsets_rad : numpy.ndarray, optional
        Phase offset per (antenna, channel index), (n_antennas, n_channels); default
        drawn from ``aux_rng`` (:func:`pipeline.acquisition.phase.phase_offsets`).
    aux_rng : numpy.random.Generator, optional
        Phase offsets and noise, the pi ambiguity, Doppler noise and the Gen2 slot
        counters; default a child of ``rng`` (``rng.spawn``: ``rng``'s own stream, hence the
        RSSI noise and fixed-mode misses, are those of a reader without them).
    info : dict, optional
        Filled with JSON-able facts for the read log's metadata: the phase offsets
        (``phase_offsets_rad``) and, for the Gen2 inventory, its dwell and slot counts.

    Returns
    -------
    pandas.DataFrame
        n * m rows, attempt-major, columns :data:`READ_COLUMNS`.
    """
    att = attempts
    n, m = len(att.time_s), len(tags)
    aux = rng.spawn(1)[0] if aux_rng is None else aux_rng
    geo_t = antenna_frame_angles(att.true_antenna, tags.positions_m)
    geo_e = antenna_frame_angles(att.est_antenna, tags.positions_m)
    tag_row = np.tile(np.arange(m), n)
    pop = {} if population is None else {
        "sensitivity_offset_db": population.sensitivity_offset_db[tag_row],
        "modulation_offset_db": population.modulation_offset_db[tag_row],
        "tag_loss_db": population.detuning_loss_db[tag_row]}
    info = {} if info is None else info
    inventory = None
    if reader.inventory == "gen2":
        stats = InventoryStats()
        dwell = reader.gen2.dwell_s(att.slot_s)

        def inventory(powered, heard):
            return inventory_counts(powered.reshape(n, m), heard.reshape(n, m), dwell,
                                    reader.gen2, aux, stats=stats)

        info["gen2"] = {"dwell_s": dwell, "stats": stats}
    resp = reader_response(np.asarray(gain_db, dtype=float).reshape(-1), reader, rng,
                           inventory=inventory, **pop)
    if "gen2" in info:
        st = info["gen2"].pop("stats")
        info["gen2"].update(n_empty=st.n_empty, n_single=st.n_single, n_collided=st.n_collided,
                            slot_efficiency=st.efficiency, inventory_time_s=st.time_s)
    if offsets_rad is None:
        offsets_rad = phase_offsets(max(int(att.antenna.max(initial=0)) + 1, 1),
                                    len(att.plan.channels_hz), aux)
    info["phase_offsets_rad"] = np.asarray(offsets_rad).tolist()
    rep = np.repeat
    if h is None:
        phase = np.full(n * m, np.nan)
        dop = np.full(n * m, np.nan)
    else:
        hh = np.asarray(h, complex).reshape(-1)
        off = rep(np.asarray(offsets_rad)[att.antenna, att.channel_index], m)
        if population is not None:  # the tag's own reflection phase
            off = off + population.phase_offset_rad[tag_row]
        # the chip's reflection phase moves with the power it absorbs above its threshold
        threshold = reader.tag_sensitivity_dbm + pop.get("sensitivity_offset_db", 0.0)
        with np.errstate(invalid="ignore"):
            off = off + power_phase_rad(resp.tag_power_dbm - threshold,
                                        reader.phase_power_shift_rad, reader.phase_power_span_db)
        phase = reported_phase_rad(hh, off, reader.phase_noise_rad, aux,
                                   reader.phase_resolution_rad)
        dop = np.full(n * m, np.nan) if dh_dpos is None else doppler_hz(
            hh, np.asarray(dh_dpos, complex).reshape(-1, 3), rep(att.antenna_velocity_mps, m, axis=0))
        dop = dop + reader.doppler_noise_hz * aux.standard_normal(n * m)
    cols = {
        "time_s": rep(att.time_s, m),
        "cycle": rep(att.cycle, m),
        "antenna": rep(att.antenna, m),
        "tag_id": pd.Categorical.from_codes(tag_row, categories=[str(i) for i in tags.ids]),
        "read": resp.read,
        "rssi_dbm": resp.rssi_dbm,
        "frequency_hz": rep(att.frequency_hz, m),
        "phase_rad": np.where(resp.read, phase, np.nan),
        "doppler_hz": np.where(resp.read, dop, np.nan),
        "seen_count": resp.seen_count,
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
