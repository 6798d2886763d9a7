"""The Gen2 reader's true miss probability: singulation in one antenna dwell against the
number of tags in the field, and the per-attempt (or per-pose) miss probability of the truth.

With ``[reader] inventory = "gen2"`` a tag whose link closes is read in an antenna dwell
when the Q algorithm singulates it before the dwell runs out
(:mod:`pipeline.acquisition.gen2`). Which of the ``n`` closing tags is singulated is
symmetric among them, and every dwell starts a fresh inventory, so the probability that
a given closing tag is read in a dwell depends only on ``n``, the link settings and the
dwell: ``p_singulated(n)``. It is estimated by Monte Carlo of the model itself
(:func:`singulation_curve`, :func:`~pipeline.acquisition.gen2.inventory` with every tag
powered and heard, stopped once every tag has been read: nothing later changes who was
read), repeated until the standard error is below ``se_target`` (default 0.005).

The truth (:mod:`pipeline.evaluation`) then misses a closing (slot, tag) attempt with
``1 - p_singulated(n_closed(slot))``, ``n_closed(slot)`` being the number of the read
log's tags whose noise-free link closes (``LinkBudget.detected`` of ``gain_db``) in
that antenna slot (same ``cycle`` and ``antenna``); a tag or site that is not in the log
(a held-out tag site, a point of the Fig. 6 plane) adds itself: ``n_closed(slot) + 1``.
Tags below the reader's sensitivity but powered take part and reply into slots the
reader hears as empty, so they do not change anyone's singulation: only closing tags
count. The nominal budget decides closure (the truth's convention: with the tag
population's spreads on, it is the nominal tag's truth). With ``inventory = "fixed"``
the miss probability is the constant ``anticollision_miss_probability``.

The study's tables come from one seeded generator per (Gen2 settings, dwell)
(:func:`p_singulated`, seed :data:`SINGULATION_SEED`), cached in memory and extended in
order of ``n``: the value for each ``n`` does not depend on which ``n`` were asked for
before, so the truth is reproducible run to run.
"""

from __future__ import annotations

import threading
from dataclasses import dataclass

import numpy as np

from pipeline.acquisition.config import ReaderConfig
from pipeline.acquisition.gen2 import Gen2Config, inventory, link_timing

__all__ = [
    "SINGULATION_SEED",
    "SingulationCurve",
    "closing_tags_per_slot",
    "miss_probability_at_poses",
    "miss_probability_of_attempts",
    "p_singulated",
    "reader_dwell_s",
    "singulation_curve",
]

#: Seed of the generator behind the cached tables of :func:`p_singulated`.
SINGULATION_SEED = 20_100_010


@dataclass(frozen=True)
class SingulationCurve:
    """Probability that a closing tag is singulated in one dwell, by tags in the field.

    Attributes
    ----------
    n_tags : numpy.ndarray
        Tags whose link closes, ``1 .. n_max``, shape (k,), int64.
    p_singulated : numpy.ndarray
        Probability that one given tag of them is read at least once in the dwell,
        shape (k,), float64.
    standard_error : numpy.ndarray
        Monte Carlo standard error of ``p_singulated`` (over repetitions), shape (k,).
    n_repetitions : numpy.ndarray
        Simulated dwells behind each value, shape (k,), int64.
    dwell_s : float
        Inventory time of the dwell [s].
    """

    n_tags: np.ndarray
    p_singulated: np.ndarray
    standard_error: np.ndarray
    n_repetitions: np.ndarray
    dwell_s: float


def _one_n(n: int, cfg: Gen2Config, dwell_s: float, rng: np.random.Generator, timing,
           se_target: float, min_repetitions: int, max_repetitions: int):
    """(p, standard error, repetitions) for ``n`` closing tags (adaptive Monte Carlo)."""
    on = np.ones(n, bool)
    frac = []
    batch = max(1, int(min_repetitions))
    while True:
        for _ in range(batch):
            c = inventory(on, on, dwell_s, cfg, rng, timing=timing, until_all_read=True)
            frac.append(np.count_nonzero(c) / n)
        f = np.asarray(frac)
        se = float(f.std(ddof=1) / np.sqrt(len(f))) if len(f) > 1 else float("inf")
        if se <= se_target or len(f) >= max_repetitions:
            return float(f.mean()), se, len(f)


def singulation_curve(cfg: Gen2Config, dwell_s: float, n_max: int, rng: np.random.Generator, *,
                      se_target: float = 0.005, min_repetitions: int = 200,
                      max_repetitions: int = 20_000) -> SingulationCurve:
    """Monte Carlo ``p_singulated(n)`` for ``n = 1 .. n_max`` (module doc), not cached.

    Parameters
    ----------
    cfg : Gen2Config
        Link timing and Q algorithm.
    dwell_s : float
        Inventory time of one antenna dwell [s] (:func:`reader_dwell_s`).
    n_max : int
        Largest number of closing tags (>= 1).
    rng : numpy.random.Generator
        Slot counters of the simulated inventories; consumed for ``n = 1, 2, ...`` in turn.
    se_target : float
        Dwells are added in batches of ``min_repetitions`` until the standard error of the
        estimate is at most this (or ``max_repetitions`` is reached).
    min_repetitions, max_repetitions : int
        Bounds on the simulated dwells per ``n``.

    Returns
    -------
    SingulationCurve
    """
    if int(n_max) < 1:
        raise ValueError(f"n_max must be >= 1, got {n_max!r}")
    if not dwell_s > 0:
        raise ValueError(f"dwell_s must be > 0, got {dwell_s!r}")
    tm = link_timing(cfg)
    rows = [_one_n(n, cfg, float(dwell_s), rng, tm, se_target, min_repetitions, max_repetitions)
            for n in range(1, int(n_max) + 1)]
    p, se, reps = (np.array(v) for v in zip(*rows, strict=True))
    return SingulationCurve(n_tags=np.arange(1, int(n_max) + 1, dtype=np.int64),
                            p_singulated=p.astype(np.float64), standard_error=se.astype(np.float64),
                            n_repetitions=reps.astype(np.int64), dwell_s=float(dwell_s))


_CACHE: dict = {}  # (Gen2Config, dwell_s) -> [generator, list of (p, se, reps)]
_LOCK = threading.Lock()


def p_singulated(n_tags, cfg: Gen2Config, dwell_s: float) -> np.ndarray:
    """``p_singulated(n)`` from the cached table of these Gen2 settings and dwell.

    The table is :func:`singulation_curve`'s with a generator seeded with
    :data:`SINGULATION_SEED`, computed once per ``(cfg, dwell_s)`` and process, extended
    when a larger ``n`` is asked for (same values for the ``n`` already there).

    Parameters
    ----------
    n_tags : array_like of int
        Numbers of closing tags, any shape; values below 1 are taken as 1.
    cfg : Gen2Config
    dwell_s : float
        Inventory time of one antenna dwell [s].

    Returns
    -------
    numpy.ndarray
        float64, the shape of ``n_tags``.
    """
    n = np.maximum(np.asarray(n_tags, dtype=np.int64), 1)
    if not dwell_s > 0:
        raise ValueError(f"dwell_s must be > 0, got {dwell_s!r}")
    need = int(n.max(initial=1))
    key = (cfg, float(dwell_s))
    with _LOCK:
        entry = _CACHE.setdefault(key, [np.random.default_rng(SINGULATION_SEED), []])
        rng, rows = entry
        tm = link_timing(cfg)
        for k in range(len(rows) + 1, need + 1):
            rows.append(_one_n(k, cfg, float(dwell_s), rng, tm, 0.005, 200, 20_000))
        table = np.array([r[0] for r in rows[:need]], dtype=np.float64)
    return table[n - 1]


def reader_dwell_s(reader: ReaderConfig, n_antennas: int = 1) -> float:
    """Inventory time of one antenna dwell of ``reader`` [s].

    The antenna slot is ``1 / read_rate_hz`` (``"round_robin"``) or that divided by
    ``n_antennas`` (``"all"``, :func:`~pipeline.acquisition.read_attempts`); the dwell is
    :meth:`Gen2Config.dwell_s` of it (switching time taken off).
    """
    return reader.gen2.dwell_s(reader.antenna_slot_s(n_antennas))


def _closed(gain_db: np.ndarray, budget) -> np.ndarray:
    g = np.asarray(gain_db, dtype=np.float64)
    if np.any(np.isnan(g)):
        raise ValueError("gain_db contains NaN (use -inf for links that were not traced)")
    out = np.zeros(g.shape, bool)
    fin = np.isfinite(g)
    if fin.any():
        out[fin] = np.asarray(budget.detected(g[fin]), dtype=bool)
    return out


def _slots(reads):
    """(slot index of each row, first row of each slot) over (cycle, antenna) pairs."""
    cyc = reads["cycle"].to_numpy(np.int64)
    ant = reads["antenna"].to_numpy(np.int64)
    key = cyc * (int(ant.max(initial=0)) + 1) + ant
    _, first, inv = np.unique(key, return_index=True, return_inverse=True)
    return inv.reshape(-1), first


def closing_tags_per_slot(reads, budget) -> np.ndarray:
    """Tags of the log whose noise-free link closes in each row's antenna slot.

    Parameters
    ----------
    reads : pandas.DataFrame
        ``reads.parquet``-format table (columns ``cycle``, ``antenna``, ``gain_db``).
    budget : propagation.LinkBudget
        Its ``detected`` decides closure.

    Returns
    -------
    numpy.ndarray
        int64, shape (rows,): the count in the row's (cycle, antenna) slot, the row's own
        tag included when its link closes.
    """
    if len(reads) == 0:
        return np.zeros(0, np.int64)
    slot, first = _slots(reads)
    closed = _closed(reads["gain_db"].to_numpy(np.float64), budget)
    return np.bincount(slot, weights=closed, minlength=len(first)).astype(np.int64)[slot]


def _n_antennas(reads, n_antennas):
    if n_antennas is not None:
        return int(n_antennas)
    return int(reads["antenna"].max()) + 1 if len(reads) else 1


def miss_probability_of_attempts(reads, reader: ReaderConfig, budget, *,
                                 n_antennas: int | None = None) -> np.ndarray:
    """True miss probability of every (slot, tag) attempt of a read log, given its link closes.

    Parameters
    ----------
    reads : pandas.DataFrame
        ``reads.parquet``-format table (``cycle``, ``antenna``, ``gain_db``).
    reader : ReaderConfig
        ``inventory = "fixed"``: ``anticollision_miss_probability`` everywhere;
        ``"gen2"``: ``1 - p_singulated(max(n_closed(slot), 1))`` (module doc).
    budget : propagation.LinkBudget
        The truth's budget (closure of the log's links).
    n_antennas : int, optional
        Antennas of the robot (dwell of the ``"all"`` antenna mode); default the log's
        largest antenna index plus one.

    Returns
    -------
    numpy.ndarray
        float64, shape (rows,), in [0, 1).
    """
    if reader.inventory == "fixed":
        return np.full(len(reads), float(reader.anticollision_miss_probability))
    dwell = reader_dwell_s(reader, _n_antennas(reads, n_antennas))
    return 1.0 - p_singulated(closing_tags_per_slot(reads, budget), reader.gen2, dwell)


def miss_probability_at_poses(reads, antenna_poses, reader: ReaderConfig, budget, *,
                              extra_tags: int = 1, n_antennas: int | None = None) -> np.ndarray:
    """True miss probability of a closing tag at antenna poses taken from a read log.

    Each pose is matched to the log's antenna slot whose TRUE antenna pose
    (``true_ant_x_m, _y_m, _z_m, _yaw_rad``) is nearest (exact for poses copied from
    the log, as the truth stage samples them); the tags in the field are that slot's
    closing tags plus ``extra_tags``.

    Parameters
    ----------
    reads : pandas.DataFrame
        ``reads.parquet``-format table.
    antenna_poses : array_like, shape (p, 4) or (p, 6)
        [x_m, y_m, z_m, yaw_rad, ...] (pitch and roll are not compared).
    reader : ReaderConfig
        As :func:`miss_probability_of_attempts`.
    budget : propagation.LinkBudget
    extra_tags : int
        Tags not in the log that join the field: 1 for a held-out tag site or a point
        (the site itself); 0 when the tag is one of the log's (a localisation candidate of
        a logged tag, counted already where its true link closes).
    n_antennas : int, optional
        As :func:`miss_probability_of_attempts`.

    Returns
    -------
    numpy.ndarray
        float64, shape (p,): ``1 - p_singulated(max(n_closed + extra_tags, 1))``, or
        ``anticollision_miss_probability`` for the ``"fixed"`` inventory.
    """
    poses = np.asarray(antenna_poses, dtype=np.float64).reshape(len(antenna_poses), -1)
    if reader.inventory == "fixed":
        return np.full(len(poses), float(reader.anticollision_miss_probability))
    if len(reads) == 0:
        raise ValueError("the read log is empty: no antenna slot to take the tags in the field from")
    slot, first = _slots(reads)
    closed = _closed(reads["gain_db"].to_numpy(np.float64), budget)
    n_slot = np.bincount(slot, weights=closed, minlength=len(first)).astype(np.int64)
    cols = ["true_ant_x_m", "true_ant_y_m", "true_ant_z_m", "true_ant_yaw_rad"]
    sp = reads[cols].to_numpy(np.float64)[first]  # (k, 4)
    d2 = ((poses[:, None, :3] - sp[None, :, :3]) ** 2).sum(-1)
    dyaw = np.angle(np.exp(1j * (poses[:, None, 3] - sp[None, :, 3])))
    nearest = np.argmin(d2 + dyaw ** 2, axis=1)
    dwell = reader_dwell_s(reader, _n_antennas(reads, n_antennas))
    return 1.0 - p_singulated(n_slot[nearest] + int(extra_tags), reader.gen2, dwell)
