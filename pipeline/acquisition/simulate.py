"""The reader along a tour: schedule, ray-traced links at each attempt's channel, reads.

:func:`simulate_reads` strings the pieces together: the read-attempt schedule with its
hop sequence (:mod:`pipeline.acquisition.channels`), the tag population
(:mod:`pipeline.acquisition.population`), the ray-traced channels of the pairs in range
(one trace per antenna position, each attempt's coherent sum at its channel), and the
reader's response (:mod:`pipeline.acquisition.reader`).
"""

from __future__ import annotations

import dataclasses
import logging
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pandas as pd

from pipeline.acquisition.channels import hop_sequence, reported_channels
from pipeline.acquisition.config import ReaderConfig, reader_metadata
from pipeline.acquisition.phase import phase_offsets
from pipeline.acquisition.population import draw_population, surface_materials
from pipeline.acquisition.reader import in_range_mask, read_attempts, reads_from_gains
from pipeline.acquisition.readlog import POSE_COLUMNS, ReadLog
from pipeline.acquisition.track import PoseTrack, as_pose_track
from propagation import TraceOptions, antenna_frame_angles, free_space_gain_db, trace_links

__all__ = ["TracedLinks", "simulate_reads"]

logger = logging.getLogger(__name__)


@dataclass(frozen=True)
class TracedLinks:
    """Ray-traced links of a schedule (attempts x tags) at each attempt's channel.

    Attributes
    ----------
    gain_db : numpy.ndarray
        One-way gain, (n, m), float64, dB; -inf where not traced.
    traced : numpy.ndarray
        bool (n, m).
    h : numpy.ndarray
        One-way channel coefficient, (n, m), complex128; 0 where not traced.
    dh_dpos : numpy.ndarray
        d h / d (antenna position), (n, m, 3), complex128, 1/m.
    n_traced : int
        Unique (pose, channel) links computed.
    n_traced_sources : int
        Antenna positions ray-traced afresh (0 when all came from the path cache).
    """

    gain_db: np.ndarray
    traced: np.ndarray
    h: np.ndarray
    dh_dpos: np.ndarray
    n_traced: int
    n_traced_sources: int = 0


def _trace_gains(scene, tags, poses6: np.ndarray, mask: np.ndarray, frequency_hz: float,
                 trace, cache_dir=None, progress=None, channel_hz=None) -> TracedLinks:
    """Trace the masked pairs, deduplicated over (antenna pose, channel).

    One trace per antenna position at the carrier ``frequency_hz`` (materials there) serves
    every channel: :func:`propagation.trace_links` caches the path sets by position and
    only the coherent sum depends on ``channel_hz`` (n,), default the carrier.
    """
    n, m = mask.shape
    ch = np.full(n, float(frequency_hz)) if channel_hz is None else np.asarray(channel_hz, float)
    gain_db = np.full((n, m), -np.inf)
    traced = np.zeros((n, m), dtype=bool)
    h = np.zeros((n, m), complex)
    dh = np.zeros((n, m, 3), complex)
    rows = np.flatnonzero(mask.any(axis=1))
    if len(rows) == 0:
        return TracedLinks(gain_db, traced, h, dh, 0)
    key = np.column_stack([poses6[rows], ch[rows]])
    uniq, inv = np.unique(key, axis=0, return_inverse=True)
    inv = inv.reshape(-1)
    umask = np.zeros((len(uniq), m), dtype=bool)
    np.logical_or.at(umask, inv, mask[rows])
    links = trace_links(scene, uniq[:, :6], tags.positions_m, trace, frequency_hz=frequency_hz,
                        tag_normals=tags.normals, pairs=umask, channel_hz=uniq[:, 6],
                        channel_gradient=True, cache_dir=cache_dir, progress=progress)
    t = np.asarray(links.traced, dtype=bool)[inv]
    sel = mask[rows] & t
    gain_db[rows] = np.where(sel, np.asarray(links.gain_db, dtype=float)[inv], -np.inf)
    traced[rows] = sel
    h[rows] = np.where(sel, links.h[inv], 0)
    dh[rows] = np.where(sel[..., None], links.dh_dpos[inv], 0)
    return TracedLinks(gain_db, traced, h, dh, int(np.asarray(links.traced).sum()),
                       int(links.n_traced_sources))


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


def simulate_reads(
    scene,
    robot,
    track,
    reader: ReaderConfig,
    rng: np.random.Generator,
    *,
    trace=None,
    cache_dir: str | Path | None = None,
    progress=None,
    tags=None,
    frequency_hz: float | None = None,
    slot_channels_hz: dict | None = None,
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
    trace : propagation.TraceOptions, optional
        The tracer and its settings for :func:`propagation.trace_links` (default: the
        library's, i.e. the study's); ``frequency_hz`` is the argument below and the
        links come from the range mask.
    cache_dir : str or Path, optional
        Trace cache directory passed to :func:`propagation.trace_links`.
    progress : callable, optional
        ``progress(done, total)`` passed to :func:`propagation.trace_links`.
    tags : scenes.TagSet, optional
        The tags this tour can read (e.g. only the training or only the held-out
        layout); default ``scene.tags``.
    frequency_hz : float, optional
        Carrier frequency [Hz] (default: :class:`propagation.LinkBudget`'s): the traces
        and their materials are made there; each attempt's gain, phase and Doppler are
        those of its channel (``reader.region``).
    slot_channels_hz : dict, optional
        (cycle, antenna) -> the channel [Hz] a recording reported in that slot: the
        attempts use it (:func:`pipeline.acquisition.channels.reported_channels`: a slot
        without a read takes its nearest reported neighbour's within half the dwell), the
        hop sequence only where neither is known; counted in ``metadata["channels"]``.

    Returns
    -------
    ReadLog
        One row per (attempt, tag) with columns :data:`READ_COLUMNS`; rows of untraced
        (out-of-range) pairs have ``in_range`` False, ``read`` False, ``gain_db`` -inf.
        ``metadata`` counts the traced pairs (``n_pairs_traced``) and records the hop
        sequence (``channels``), the tag population drawn (``tag_population``, each tag's
        own phase offset ``phase_offset_rad`` included), the (antenna, channel) phase
        offsets (``phase_offsets_rad``) and the Gen2 slot counts (``gen2``). The reported
        phase also carries the chip's power-dependent term
        (:func:`pipeline.acquisition.phase.power_phase_rad`).

    Notes
    -----
    ``rng`` itself gives exactly the draws of a reader without channels, phase, tag
    spreads or Gen2 (the RSSI noise and fixed-mode misses); everything else comes from
    one child stream (``rng.spawn``), so ``region = "none"`` with zero spreads and
    detuning draws the same RSSI noise and misses as that reader did.
    """
    trk = as_pose_track(track)

    trace = TraceOptions() if trace is None else trace
    if not isinstance(trace, TraceOptions):
        raise TypeError(f"simulate_reads: trace must be a propagation.TraceOptions, got {type(trace).__name__}")
    budget = reader.link_budget(frequency_hz)
    aux = rng.spawn(1)[0]  # everything new draws here: rng's own stream is the old reader's
    mounts = list(robot.antennas)
    plan = hop_sequence(reader.channel_plan(budget.frequency_hz), aux)
    _check_eirp(reader, budget, plan)
    att = read_attempts(trk, mounts, reader, plan=plan)
    recorded_channels = None
    if slot_channels_hz is not None:  # a recording's own channels where it knows them
        index, freq, recorded_channels = reported_channels(att.time_s, att.cycle, att.antenna, plan,
                                                           slot_channels_hz)
        use = index >= 0
        att = dataclasses.replace(att, channel_index=np.where(use, index, att.channel_index),
                                  frequency_hz=np.where(use, freq, att.frequency_hz))
    tags = scene.tags if tags is None else tags
    n, m = len(att.time_s), len(tags)
    pop = draw_population(tags, reader, aux, surface_materials(scene, tags))
    offsets = phase_offsets(len(mounts), len(plan.channels_hz), aux)
    d_true = antenna_frame_angles(att.true_antenna, tags.positions_m).d_m
    # the lowest channel reaches farthest; a more sensitive tag too, and an antenna whose
    # cable loss is negative (a calibrated antenna stronger than nominal)
    loss = np.array([float(getattr(a, "cable_loss_db", 0.0)) for a in mounts])
    extra_db = (np.maximum(0.0, -pop.sensitivity_offset_db)[None, :]
                + np.maximum(0.0, -loss[att.antenna])[:, None])
    mask = in_range_mask(d_true, reader, float(plan.channels_hz.min()), extra_db)
    links = _trace_gains(scene, tags, att.true_antenna, mask, budget.frequency_hz, trace,
                         cache_dir=cache_dir, progress=progress, channel_hz=att.frequency_hz)
    info: dict = {}
    gain = links.gain_db
    if np.any(loss != 0.0):  # the gain from the reader port: the antenna's cable loss off
        gain = np.where(links.traced, gain - loss[att.antenna][:, None], gain)
    reads = reads_from_gains(att, tags, gain, links.traced, reader, rng, h=links.h,
                             dh_dpos=links.dh_dpos, population=pop, offsets_rad=offsets,
                             aux_rng=aux, info=info)
    excess_db = _check_margin(links.gain_db, links.traced, d_true, reader.range_margin_db, budget)
    meta = {
        "scene": scene.name,
        "scene_hash": scene.content_hash(),
        "antennas": [getattr(a, "name", str(i)) for i, a in enumerate(mounts)],
        "tag_ids": [str(i) for i in tags.ids],
        "reader": reader_metadata(reader, budget),
        "trace": dataclasses.asdict(trace),
        "n_slots": int(n),  # (cycle, active antenna) slots; rows = n_slots * n_tags
        "n_pairs": int(n * m),
        "n_pairs_in_range": int(mask.sum()),
        "n_pairs_traced": int(links.n_traced),
        "max_range_m": float(budget.max_range_m(margin_db=reader.range_margin_db)),
        "range_margin_db": float(reader.range_margin_db),
        "max_excess_over_free_space_db": excess_db,
        "channels": {"region": plan.region.name, "hop_sequence_hz": plan.channels_hz.tolist(),
                     "dwell_s": plan.dwell_s if np.isfinite(plan.dwell_s) else None,
                     "max_eirp_dbm": plan.region.max_eirp_dbm,
                     **({} if recorded_channels is None else {"recorded": recorded_channels})},
        "tag_population": pop.to_dict(),
        **info,
    }
    logger.info(
        "simulate_reads: %d antenna slots x %d tags, %d pairs in range (%d unique traced, %d "
        "antenna positions traced afresh), %d reads",
        n,
        m,
        int(mask.sum()),
        links.n_traced,
        links.n_traced_sources,
        int(reads["read"].sum()),
    )
    return ReadLog(reads=reads, poses=_poses_frame(trk), metadata=meta,
                   n_sources_traced=int(links.n_traced_sources))


def _check_eirp(reader: ReaderConfig, budget, plan) -> None:
    """Log a warning when the budget radiates more than the region allows."""
    limit = plan.region.max_eirp_dbm
    eirp = reader.tx_power_dbm + budget.reader_antenna_gain_dbi
    if limit is not None and eirp > limit + 1e-6:
        logger.warning("reader EIRP %.2f dBm (tx_power_dbm %.2f + %.1f dBi) exceeds the %s limit of "
                       "%.2f dBm", eirp, reader.tx_power_dbm, budget.reader_antenna_gain_dbi,
                       plan.region.name, limit)


def _check_margin(gain_db, traced, d_m, range_margin_db: float, budget) -> float | None:
    """Largest excess of a traced gain over free space with maximum pattern gains [dB].

    Links beyond ``max_range_m(range_margin_db)`` are not traced; an excess above the
    margin on the traced links says some of them might have been readable. The value is
    recorded in the read log's metadata and reported (metrics ``reads.range_margin``,
    report); the log says so at INFO level. None when nothing was traced.
    """
    if not traced.any():
        return None

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
