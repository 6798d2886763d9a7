"""Regional channel plans and the reader's frequency hopping.

A UHF RFID reader does not transmit on one frequency: the regulations of its region
give it a set of channels and how long it may stay on one. :data:`REGIONS` holds the two
plans a European or North American robot would run under:

- ``"ETSI"``: ETSI EN 302 208 (v3.1.1, 2016), the four high-power channels of the
  865-868 MHz band at 865.7, 866.3, 866.9 and 867.5 MHz (200 kHz wide), 2 W ERP
  (35.15 dBm EIRP); an interrogator may stay on a channel for at most 4 s.
- ``"FCC"``: FCC 47 CFR 15.247, a frequency-hopping system in 902-928 MHz with at least
  50 channels (here 902.75-927.25 MHz in 500 kHz steps, as Impinj readers use), 1 W
  conducted into at most 6 dBi (4 W, 36 dBm EIRP), an average occupancy of at most
  0.4 s per channel within 20 s, channels visited in a pseudo-random order.
- ``"none"``: no plan; every attempt at the study's carrier ``frequency_hz`` (or at the
  explicit ``channels_hz``): a reader that does not hop.

The reader visits its channels in a hop sequence (a permutation drawn once per reader,
:func:`hop_sequence`), staying ``channel_dwell_s`` on each (:func:`channel_schedule`).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from pipeline.configschema import ConfigError

__all__ = ["REGIONS", "ChannelPlan", "RegionProfile", "channel_plan", "channel_schedule",
           "hop_sequence", "reported_channels"]


@dataclass(frozen=True)
class RegionProfile:
    """A regulatory region's UHF RFID rules.

    Attributes
    ----------
    name : str
        ``"ETSI"``, ``"FCC"`` or ``"none"``.
    band_hz : tuple of float or None
        Lowest and highest allowed channel centre [Hz]; None: any positive frequency.
    channels_hz : tuple of float
        The region's channel centres [Hz] (empty for ``"none"``).
    max_eirp_dbm : float or None
        Highest radiated power allowed, EIRP [dBm] (2 W ERP = 35.15 dBm EIRP).
    max_dwell_s : float or None
        Longest stay on one channel [s]; the default ``channel_dwell_s``.
    """

    name: str
    band_hz: tuple[float, float] | None
    channels_hz: tuple[float, ...]
    max_eirp_dbm: float | None
    max_dwell_s: float | None


#: The regions a reader can be configured for (see the module docstring for sources).
REGIONS: dict[str, RegionProfile] = {
    "ETSI": RegionProfile("ETSI", (865.0e6, 868.0e6), (865.7e6, 866.3e6, 866.9e6, 867.5e6),
                          35.15, 4.0),
    "FCC": RegionProfile("FCC", (902.0e6, 928.0e6),
                         tuple(902.75e6 + 0.5e6 * np.arange(50)), 36.0, 0.4),
    "none": RegionProfile("none", None, (), None, None),
}


@dataclass(frozen=True)
class ChannelPlan:
    """The channels one reader hops over, in its hop order.

    Attributes
    ----------
    region : RegionProfile
        The region the plan follows.
    channels_hz : numpy.ndarray
        Channel centres in hop order, shape (k,), float64, Hz.
    dwell_s : float
        Time on one channel before the next hop [s] (inf: never hops).
    """

    region: RegionProfile
    channels_hz: np.ndarray
    dwell_s: float


def channel_plan(region: str, channels_hz=(), channel_dwell_s: float | None = None,
                 carrier_hz: float | None = None) -> ChannelPlan:
    """Check a reader's regional settings and build its channel list (unordered).

    Parameters
    ----------
    region : str
        A key of :data:`REGIONS`.
    channels_hz : sequence of float
        Explicit channel centres [Hz] replacing the region's; each must lie in the
        region's band.
    channel_dwell_s : float, optional
        Time per channel [s]; default: the region's maximum (inf for ``"none"``). Must be
        > 0 and, for a region, at most its maximum.
    carrier_hz : float, optional
        The study's carrier, the one channel of ``"none"`` without ``channels_hz``.

    Returns
    -------
    ChannelPlan
        Channels in the listed order (:func:`hop_sequence` orders them).

    Raises
    ------
    ConfigError
        Naming ``region``, ``channels_hz`` or ``channel_dwell_s``.
    """
    if region not in REGIONS:
        raise ConfigError(f"reader.region must be one of {sorted(REGIONS)}, got {region!r}")
    prof = REGIONS[region]
    ch = np.asarray(channels_hz if len(channels_hz) else prof.channels_hz, dtype=float).reshape(-1)
    if len(ch) == 0:
        ch = np.array([865e6 if carrier_hz is None else float(carrier_hz)])
    if not np.all(np.isfinite(ch) & (ch > 0)):
        raise ConfigError(f"reader.channels_hz must be positive and finite, got {ch.tolist()}")
    if len(np.unique(ch)) != len(ch):
        raise ConfigError(f"reader.channels_hz has repeated channels: {ch.tolist()}")
    if prof.band_hz is not None:
        lo, hi = prof.band_hz
        out = ch[(ch < lo) | (ch > hi)]
        if len(out):
            raise ConfigError(f"reader.channels_hz: {out.tolist()} Hz outside the {region} band "
                              f"[{lo:.0f}, {hi:.0f}] Hz")
    if channel_dwell_s is None:
        dwell = prof.max_dwell_s if prof.max_dwell_s is not None else np.inf
    else:
        dwell = float(channel_dwell_s)
        if not dwell > 0:
            raise ConfigError(f"reader.channel_dwell_s must be > 0, got {channel_dwell_s!r}")
        if prof.max_dwell_s is not None and dwell > prof.max_dwell_s:
            raise ConfigError(f"reader.channel_dwell_s = {dwell} s exceeds the {region} maximum of "
                              f"{prof.max_dwell_s} s per channel")
    return ChannelPlan(prof, ch, float(dwell))


def hop_sequence(plan: ChannelPlan, rng: np.random.Generator | None) -> ChannelPlan:
    """The plan with its channels in a pseudo-random hop order drawn from ``rng``.

    A reader's hop table is fixed for a session: one permutation per reader. With
    ``rng`` None the listed order is kept.
    """
    if rng is None or len(plan.channels_hz) < 2:
        return plan
    return ChannelPlan(plan.region, plan.channels_hz[rng.permutation(len(plan.channels_hz))],
                       plan.dwell_s)


def channel_schedule(time_s, plan: ChannelPlan, t0_s: float = 0.0) -> np.ndarray:
    """Index into ``plan.channels_hz`` of the channel in use at each time.

    Parameters
    ----------
    time_s : array_like
        Times [s], any shape.
    plan : ChannelPlan
        Hop order and dwell.
    t0_s : float
        Start of the first dwell [s].

    Returns
    -------
    numpy.ndarray
        int64, shape of ``time_s``: hop ``k = floor((t - t0) / dwell)`` uses channel
        ``k mod n_channels``.
    """
    t = np.asarray(time_s, dtype=float)
    if not np.isfinite(plan.dwell_s):
        return np.zeros(t.shape, np.int64)
    k = np.floor((t - t0_s) / plan.dwell_s + 1e-9).astype(np.int64)
    return np.mod(k, len(plan.channels_hz))


def reported_channels(time_s, cycle, antenna, plan: ChannelPlan, reported: dict):
    """Each attempt slot's channel as a reader reported it: ``(channel_index, frequency_hz,
    counts)``, shapes (n,), (n,) and a dict.

    ``reported`` maps (cycle, antenna) to the channel [Hz] of a read in that slot (a
    recording's). A slot without a read takes the channel of the nearest reported slot in
    time when it lies within half the plan's dwell (a reader stays on a channel for the
    dwell; where the dwell is unbounded, any reported slot); else it keeps NaN, index -1:
    the caller keeps its own hop there. Each channel is matched to the plan's nearest
    (the recording stage checked that they are the plan's, within 1 kHz).
    """
    t = np.asarray(time_s, np.float64)
    f = np.array([reported.get((int(c), int(a)), np.nan) for c, a in zip(cycle, antenna, strict=True)],
                 np.float64)
    have = np.flatnonzero(np.isfinite(f))
    n_reported = len(have)
    if n_reported and n_reported < len(f):
        tk = t[have]
        pos = np.clip(np.searchsorted(tk, t), 1, len(tk)) if len(tk) > 1 else np.ones(len(t), np.int64)
        left, right = have[np.maximum(pos - 1, 0)], have[np.minimum(pos, len(have) - 1)]
        near = np.where(np.abs(t[left] - t) <= np.abs(t[right] - t), left, right)
        reach = np.inf if not np.isfinite(plan.dwell_s) else plan.dwell_s / 2.0
        fill = ~np.isfinite(f) & (np.abs(t[near] - t) <= reach)
        f[fill] = f[near[fill]]
    ok = np.isfinite(f)
    chans = np.asarray(plan.channels_hz, np.float64)
    index = np.where(ok, np.argmin(np.abs(np.where(ok, f, 0.0)[:, None] - chans[None, :]), axis=1), -1)
    freq = np.where(ok, chans[np.maximum(index, 0)], np.nan)
    return index, freq, {"n_slots": int(len(f)), "reported": n_reported,
                         "filled_within_dwell": int(ok.sum()) - n_reported,
                         "hop_sequence": int((~ok).sum())}
