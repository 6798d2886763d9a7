"""EPC Gen2 inventory: the Q algorithm's slotted frames and their link timing.

A Gen2 reader does not read every tag at a fixed rate: it runs inventory rounds
(EPCglobal, "EPC Radio-Frequency Identity Protocols Generation-2 UHF RFID, Specification
for RFID Air Interface Protocol for Communications at 860 MHz - 960 MHz", version 2.0.1,
2015; section numbers below are that document's). A ``Query`` opens a round of ``2^Q``
slots; every participating tag draws a slot counter uniformly in ``[0, 2^Q - 1]``; each
``QueryRep`` closes a slot and decrements the counters; tags whose counter reaches 0
backscatter an RN16. A slot with no reply is *empty*, with two or more *collided*, with
one *single*: the reader ACKs the RN16 and the tag backscatters its PC + EPC + CRC (128
bits), is read, and flips its inventoried flag (it sits out the rest of the pass).

The Q algorithm (Annex D) adapts the frame to the population: ``Qfp`` falls by ``C`` on
an empty slot, rises by ``C`` on a collision; when ``round(Qfp)`` differs from ``Q`` the
reader sends ``QueryAdjust`` and a new round begins (tags redraw). When a round of one
slot (``Q = 0``) is empty the reader assumes the pass done and flips its target
(Impinj's "dual target" search mode): every powered tag takes part again. So the read
rate of a tag emerges from the number of tags in the field, and a tag is missed in an
antenna dwell when collisions and empty slots use up the dwell before it is singulated.

The link budget decides who takes part: a tag below its sensitivity is not powered and
never replies; a powered tag whose reply is below the reader's sensitivity replies into
slots the reader hears as empty (its RN16 is noise there, neither a read nor a
collision; the capture of a strong reply over a weak one is thus complete, and collisions
are counted among audible replies only).

Durations (6.3.1.2-6.3.1.6), with ``Tpri = 1 / BLF``: reader data-0 = Tari, data-1 =
1.5 Tari (the spec allows 1.5-2 Tari), a mean bit of 1.25 Tari; RTcal = data-0 + data-1;
TRcal = DR / BLF with DR = 64/3 (1.1 RTcal <= TRcal <= 3 RTcal is checked); delimiter
12.5 us; a Query carries the preamble (delimiter, data-0, RTcal, TRcal) and 22 bits,
QueryRep the frame-sync (delimiter, data-0, RTcal) and 4 bits, QueryAdjust 9, ACK 18.
A tag reply takes ``M`` subcarrier cycles per bit (FM0: M = 1) with a preamble of 6 bits
(FM0) or 10 symbols (Miller, TRext = 0) and a trailing dummy 1. Link turnarounds
(6.3.1.6 "Link timing", Table 6.16 "Link timing parameters"):

* T1, reader command to tag reply: nominal ``MAX(RTcal, 10 Tpri)`` (the table's limits
  are that times ``1 -+ |FT|`` -+ 2 us), used as is;
* T2, tag reply to the next reader command: 3.0-20.0 Tpri; 10 Tpri here;
* T3, the time a reader waits after T1 before it issues another command when no reply
  came: at least 0.0 Tpri; 10 Tpri here (the reader must let a late reply's preamble
  start before it declares the slot empty);
* T4, the minimum time between two reader commands: at least 2.0 RTcal.

So an empty slot lasts ``QueryRep + MAX(T1 + T3, T4)``: with the defaults T1 + T3 =
102.5 us falls short of T4 = 125 us, and T4 sets it. Collided and single slots end with
a tag reply plus T2, well beyond T4. The defaults (Tari 25 us, BLF 250 kHz, Miller 4:
Impinj's dense-reader mode for ETSI) give empty / collided / single slots of 0.35 /
0.76 / 3.7 ms, about 200 reads/s for a handful of tags.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from pipeline.configschema import ConfigError, option, section

__all__ = ["Gen2Config", "Gen2Timing", "InventoryStats", "ReadRateCurve", "inventory",
           "inventory_counts", "link_timing", "read_rate_curve"]

_DELIMITER_S = 12.5e-6
_DR = 64.0 / 3.0
_BITS = {"query": 22, "query_rep": 4, "query_adjust": 9, "ack": 18, "rn16": 16, "epc": 128}
_Q_MAX = 15


@section
class Gen2Config:
    """EPC Gen2 link timing and Q-algorithm inventory, used when reader.inventory = "gen2".

    :mod:`pipeline.acquisition.gen2` has the timing and its sources. Defaults: Impinj's dense-reader mode (Tari 25 us, BLF 250 kHz, Miller
    M = 4), Q starting at 4 with the spec's example step C = 0.3 (Annex D: 0.1 < C < 0.5).
    """

    tari_s: float = option(25e-6, "Reader data-0 symbol length Tari [s] (spec: 6.25-25 us).")
    blf_hz: float = option(250e3, "Tag backscatter link frequency BLF [Hz] (spec: 40-640 kHz).")
    miller_m: int = option(4, "Tag encoding: 1 (FM0) or Miller 2, 4, 8 subcarrier cycles per bit.")
    q_initial: int = option(4, "Q of the first round of each antenna dwell (0-15).")
    q_step: float = option(0.3, "Q algorithm step C (Annex D: 0.1 < C < 0.5).")
    antenna_dwell_s: float | None = option(
        None, "Inventory time per antenna slot [s]; default: the slot less antenna_switch_s.")
    antenna_switch_s: float = option(
        0.005, "Time lost switching antenna ports and restarting inventory per slot [s].")

    def __post_init__(self):
        if not 6.25e-6 <= self.tari_s <= 25e-6:
            raise ConfigError(f"reader.gen2.tari_s must be in [6.25e-6, 25e-6] s, got {self.tari_s!r}")
        if not 40e3 <= self.blf_hz <= 640e3:
            raise ConfigError(f"reader.gen2.blf_hz must be in [40e3, 640e3] Hz, got {self.blf_hz!r}")
        rtcal = 2.5 * self.tari_s
        trcal = _DR / self.blf_hz
        if not 1.1 * rtcal - 1e-12 <= trcal <= 3.0 * rtcal + 1e-12:
            raise ConfigError(f"reader.gen2.blf_hz = {self.blf_hz} Hz gives TRcal = {trcal * 1e6:.1f} us, "
                              f"outside [1.1, 3] RTcal = [{1.1 * rtcal * 1e6:.1f}, {3 * rtcal * 1e6:.1f}] "
                              "us for this tari_s (Gen2 6.3.1.2.8)")
        if self.miller_m not in (1, 2, 4, 8):
            raise ConfigError(f"reader.gen2.miller_m must be 1, 2, 4 or 8, got {self.miller_m!r}")
        if not 0 <= self.q_initial <= _Q_MAX:
            raise ConfigError(f"reader.gen2.q_initial must be in [0, 15], got {self.q_initial!r}")
        if not 0.1 <= self.q_step <= 0.5:  # EPC Gen2 Annex D: typical 0.1 < C < 0.5
            raise ConfigError(f"reader.gen2.q_step must be in [0.1, 0.5] (EPC Gen2 Annex D), "
                              f"got {self.q_step!r}")
        if not self.antenna_switch_s >= 0:
            raise ConfigError(f"reader.gen2.antenna_switch_s must be >= 0, got {self.antenna_switch_s!r}")
        if self.antenna_dwell_s is not None and not self.antenna_dwell_s > 0:
            raise ConfigError(f"reader.gen2.antenna_dwell_s must be > 0, got {self.antenna_dwell_s!r}")

    def dwell_s(self, slot_s: float) -> float:
        """Inventory time within an antenna slot of ``slot_s`` seconds.

        Raises
        ------
        ConfigError
            Naming ``antenna_dwell_s`` (or ``antenna_switch_s``) when dwell plus switching
            does not fit in the slot.
        """
        if self.antenna_dwell_s is None:
            dwell = slot_s - self.antenna_switch_s
            if not dwell > 0:
                raise ConfigError(f"reader.gen2.antenna_switch_s = {self.antenna_switch_s} s leaves no "
                                  f"antenna dwell in a {slot_s:.4g} s antenna slot")
            return float(dwell)
        if self.antenna_dwell_s + self.antenna_switch_s > slot_s * (1 + 1e-9):
            raise ConfigError(f"reader.gen2.antenna_dwell_s = {self.antenna_dwell_s} s plus "
                              f"antenna_switch_s = {self.antenna_switch_s} s exceeds the {slot_s:.4g} s "
                              "antenna slot (1 / read_rate_hz per antenna slot)")
        return float(self.antenna_dwell_s)


@dataclass(frozen=True)
class Gen2Timing:
    """Durations of the inventory's slots [s] (module docstring for the derivation).

    Attributes
    ----------
    empty_s, collided_s, single_s : float
        A slot opened by ``QueryRep``: no reply; colliding RN16s; RN16, ACK and EPC.
    query_extra_s : float
        Extra time when the slot is opened by ``Query`` instead of ``QueryRep``.
    adjust_extra_s : float
        Extra time when it is opened by ``QueryAdjust``.
    t1_s, t2_s, t3_s, t4_s : float
        The link turnarounds used (Gen2 Table 6.16, module doc).
    """

    empty_s: float
    collided_s: float
    single_s: float
    query_extra_s: float
    adjust_extra_s: float
    t1_s: float = 0.0
    t2_s: float = 0.0
    t3_s: float = 0.0
    t4_s: float = 0.0


def link_timing(cfg: Gen2Config) -> Gen2Timing:
    """Slot durations of a Gen2 link (Gen2 v2.0.1 6.3.1.2-6.3.1.6 and Table 6.16;
    assumptions in the module doc)."""
    tari = cfg.tari_s
    bit_r = 1.25 * tari
    rtcal = 2.5 * tari
    trcal = _DR / cfg.blf_hz
    tpri = 1.0 / cfg.blf_hz
    frame_sync = _DELIMITER_S + tari + rtcal
    preamble = frame_sync + trcal
    t1 = max(rtcal, 10.0 * tpri)  # Table 6.16: nominal T1
    t2 = 10.0 * tpri  # Table 6.16: 3.0-20.0 Tpri
    t3 = 10.0 * tpri  # Table 6.16: >= 0.0 Tpri
    t4 = 2.0 * rtcal  # Table 6.16: >= 2.0 RTcal between reader commands
    tag_pre = 6 if cfg.miller_m == 1 else 10

    def reply(bits):
        return (tag_pre + bits + 1) * cfg.miller_m * tpri

    rep = frame_sync + _BITS["query_rep"] * bit_r
    query = preamble + _BITS["query"] * bit_r
    adjust = frame_sync + _BITS["query_adjust"] * bit_r
    ack = frame_sync + _BITS["ack"] * bit_r
    rn16 = reply(_BITS["rn16"])
    epc = reply(_BITS["epc"])
    return Gen2Timing(empty_s=rep + max(t1 + t3, t4), collided_s=rep + t1 + rn16 + t2,
                      single_s=rep + t1 + rn16 + t2 + ack + t1 + epc + t2,
                      query_extra_s=query - rep, adjust_extra_s=adjust - rep,
                      t1_s=t1, t2_s=t2, t3_s=t3, t4_s=t4)


@dataclass
class InventoryStats:
    """Slot outcomes of one or more inventories (counts and time).

    Attributes
    ----------
    n_empty, n_single, n_collided : int
        Slots of each kind (a slot holding only inaudible replies is empty).
    time_s : float
        Time the slots took [s].
    """

    n_empty: int = 0
    n_single: int = 0
    n_collided: int = 0
    time_s: float = 0.0

    @property
    def n_slots(self) -> int:
        """All slots."""
        return self.n_empty + self.n_single + self.n_collided

    @property
    def efficiency(self) -> float:
        """Single slots per slot (the framed-ALOHA optimum is 1/e); NaN without slots."""
        return self.n_single / self.n_slots if self.n_slots else float("nan")


def inventory(powered, heard, dwell_s: float, cfg: Gen2Config, rng: np.random.Generator,
              timing: Gen2Timing | None = None, stats: InventoryStats | None = None,
              until_all_read: bool = False) -> np.ndarray:
    """Singulations of each tag in one antenna dwell of Q-algorithm inventory.

    Parameters
    ----------
    powered : array_like of bool, shape (m,)
        Tags whose forward link closes: they take part and reply.
    heard : array_like of bool, shape (m,)
        Tags whose reply the reader can decode (only meaningful where powered).
    dwell_s : float
        Inventory time [s]; a read counts when its slot ends within it.
    cfg : Gen2Config
    rng : numpy.random.Generator
        Source of the tags' slot counters.
    timing : Gen2Timing, optional
        Default ``link_timing(cfg)``.
    stats : InventoryStats, optional
        Accumulates the slot outcomes when given.
    until_all_read : bool
        Stop as soon as every powered, heard tag has been singulated once (the rest of
        the dwell cannot change which tags were read; ``stats.time_s`` then grows by the
        time used). The random stream up to that slot is the same as without it.

    Returns
    -------
    numpy.ndarray
        int64, shape (m,): times each tag was read (0 for tags never singulated).
    """
    tm = link_timing(cfg) if timing is None else timing
    st = InventoryStats() if stats is None else stats
    powered = np.asarray(powered, bool)
    heard = np.asarray(heard, bool) & powered
    counts = np.zeros(len(powered), np.int64)
    players = np.flatnonzero(powered)
    if len(players) == 0:  # nobody replies: every slot empty, nothing to simulate
        st.time_s += dwell_s
        return counts
    # plain Python over the few players: a dwell runs ~40 rounds of a handful of tags,
    # where NumPy's per-call cost dominated (the same draws, the same order)
    audible = heard[players].tolist()
    n_left = int(sum(audible))  # audible tags not yet read once (for until_all_read)
    if until_all_read and n_left == 0:
        return counts
    unread = [True] * len(players)
    qfp = float(cfg.q_initial)
    q = cfg.q_initial
    t = 0.0
    opener = tm.query_extra_s
    c = cfg.q_step
    while True:
        n_slots = 1 << q
        idx = [j for j, u in enumerate(unread) if u]
        slot_of = rng.integers(0, n_slots, size=len(idx)).tolist()
        # the audible repliers of each slot, in player order (a stable sort by slot)
        loud_in: dict[int, list[int]] = {}
        for j, sl in zip(idx, slot_of, strict=True):
            if audible[j]:
                loud_in.setdefault(sl, []).append(j)
        adjust = False
        for s in range(n_slots):
            loud = loud_in.get(s, ())
            if len(loud) == 0:
                dt, kind = tm.empty_s, 0
            elif len(loud) == 1:
                dt, kind = tm.single_s, 1
            else:
                dt, kind = tm.collided_s, 2
            dt += opener
            opener = 0.0
            if t + dt > dwell_s:
                st.time_s += dwell_s
                return counts
            t += dt
            if kind == 0:
                st.n_empty += 1
                qfp = max(0.0, qfp - c)
            elif kind == 1:
                st.n_single += 1
                counts[players[loud[0]]] += 1
                unread[loud[0]] = False
                if until_all_read and counts[players[loud[0]]] == 1:
                    n_left -= 1
                    if n_left == 0:
                        st.time_s += t
                        return counts
            else:
                st.n_collided += 1
                qfp = min(float(_Q_MAX), qfp + c)
            if kind == 0 and n_slots == 1:  # Q = 0 and silence: flip the target
                unread = [True] * len(players)
            new_q = math.floor(qfp + 0.5)
            if new_q != q:
                q, adjust = new_q, True
                break
        opener = tm.adjust_extra_s if adjust else tm.query_extra_s


def inventory_counts(powered, heard, dwell_s: float, cfg: Gen2Config,
                     rng: np.random.Generator, stats: InventoryStats | None = None) -> np.ndarray:
    """:func:`inventory` for every antenna slot of a schedule.

    Parameters
    ----------
    powered, heard : array_like of bool, shape (n, m)
        Per antenna slot (row) and tag.
    dwell_s : float
        Inventory time of each slot [s].
    cfg : Gen2Config
    rng : numpy.random.Generator
    stats : InventoryStats, optional
        Accumulates the slot outcomes of all rows.

    Returns
    -------
    numpy.ndarray
        int64, shape (n, m): singulations per slot and tag.
    """
    p = np.asarray(powered, bool)
    h = np.asarray(heard, bool)
    tm = link_timing(cfg)
    out = np.zeros(p.shape, np.int64)
    for i in range(p.shape[0]):
        out[i] = inventory(p[i], h[i], dwell_s, cfg, rng, timing=tm, stats=stats)
    return out


@dataclass(frozen=True)
class ReadRateCurve:
    """Read rate against the number of tags in the field (all powered and heard).

    Attributes
    ----------
    n_tags : numpy.ndarray
        Tag counts, shape (k,), int64.
    total_reads_per_s : numpy.ndarray
        Reads per second of the whole population, shape (k,), float64.
    reads_per_s_per_tag : numpy.ndarray
        Mean reads per second of one tag, shape (k,), float64.
    slot_efficiency : numpy.ndarray
        Single slots per slot, shape (k,), float64.
    """

    n_tags: np.ndarray
    total_reads_per_s: np.ndarray
    reads_per_s_per_tag: np.ndarray
    slot_efficiency: np.ndarray


def read_rate_curve(tag_counts, cfg: Gen2Config | None = None, rng: np.random.Generator | None = None,
                    duration_s: float = 2.0) -> ReadRateCurve:
    """Read rate of a Gen2 reader against the tag count: one uninterrupted dwell each.

    Parameters
    ----------
    tag_counts : sequence of int
        Numbers of tags in the field (all powered and heard).
    cfg : Gen2Config, optional
        Link and Q settings (default: :class:`Gen2Config`'s).
    rng : numpy.random.Generator, optional
        Slot counters (default: seeded with 0).
    duration_s : float
        Inventory time per tag count [s].

    Returns
    -------
    ReadRateCurve
    """
    cfg = Gen2Config() if cfg is None else cfg
    rng = np.random.default_rng(0) if rng is None else rng
    n = np.asarray(tag_counts, dtype=np.int64).reshape(-1)
    total = np.zeros(len(n))
    eff = np.zeros(len(n))
    for k, nt in enumerate(n):
        st = InventoryStats()
        on = np.ones(int(nt), bool)
        counts = inventory(on, on, duration_s, cfg, rng, stats=st)
        total[k] = counts.sum() / duration_s
        eff[k] = st.efficiency
    per_tag = np.where(n > 0, total / np.maximum(n, 1), 0.0)
    return ReadRateCurve(n_tags=n, total_reads_per_s=total, reads_per_s_per_tag=per_tag,
                         slot_efficiency=eff)
