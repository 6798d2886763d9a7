"""Inventory numbers of a tour: read rate, completeness per pass, coverage along the route.

What an engineer choosing an antenna mount asks of a tour is how well it inventories
the tags, counted where the tags are (their own positions on the shelf fronts and
walls at their own heights), not on a free-space plane. From a tour's read log
(``reads.parquet``), its pose track (``tour/train_track.npz``: times and
``pass_index``) and the tags, :func:`tour_tag_table` counts per (tag, pass):

- ``n_attempts``: read attempts of the tag during the pass (one per antenna per cycle);
- ``n_in_range``: those within the reader's range (the attempts the read rate counts);
- ``n_reads``: successful reads;
- ``n_cycles``: read rounds during the pass (a round is one dwell of every antenna: with
  the chapter's ``round_robin`` multiplexing, one antenna per read cycle, a round is
  ``n_antennas`` consecutive cycles; with ``all``, one cycle);
- ``n_cycles_closed``: rounds in which the tag's link closes for at least one antenna
  (:func:`link_closed`: tag powered and backscatter above the reader's sensitivity, for
  the nominal tag, from the ray-traced gain on the attempt's hopped channel, which holds
  the multipath but no reader noise or tag-to-tag spread): the share of the tour's
  *time* (stops and slow stretches weigh more) along which the tag can be read;
- ``best_margin_db``: the pass's best link margin, max over its in-range attempts of
  ``gain_db - budget.min_gain_db()`` (:func:`link_margin_db`) [dB]: how many dB the
  nominal tag's best moment of the pass has to spare (negative: short of a read);
  NaN where no attempt of the pass was in range.

Turn-arounds (``pass_index`` -1) belong to no pass and are left out.

The statistics (:data:`INVENTORY_METRICS`), each over (tag, pass) rows pooled per tag
(the unit of the intervals, :mod:`pipeline.evaluation.intervals`):

- ``read_rate``: sum of reads / sum of in-range attempts;
- ``completeness``: share of (tag, pass) with at least ``min_reads`` reads: the share
  of tags an inventory pass finds ``min_reads`` times;
- ``surface_coverage``: sum of closed cycles / sum of cycles: the share of the route,
  tag by tag, along which the link closes;
- ``reads_per_pass``: sum of reads / number of (tag, pass): how often an inventory
  pass reads a tag, on average;
- ``link_margin_db``: median over (tag, pass) of ``best_margin_db`` (passes never in
  range left out; they count in ``never_read``) [dB];
- ``never_read``: share of tags with no read in the whole tour (all passes) [share];
  a tag is one unit whatever its number of passes.

The last three are the engineer's units (a read rate of 0.05 says nothing a
mount can be changed by; "3.2 reads a pass", "6 dB to spare" and "4 tags never read"
do).
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np
import pandas as pd

from pipeline.evaluation.intervals import weighted_quantile

__all__ = [
    "INVENTORY_COLUMNS",
    "INVENTORY_METRICS",
    "inventory_statistic",
    "link_closed",
    "read_rounds",
    "tour_tag_table",
]

#: Columns of :func:`tour_tag_table`.
INVENTORY_COLUMNS = ("unit", "pass", "z_m", "n_attempts", "n_in_range", "n_reads", "n_cycles",
                     "n_cycles_closed", "best_margin_db")


#: The statistics :func:`inventory_statistic` computes.
INVENTORY_METRICS = ("read_rate", "completeness", "surface_coverage", "reads_per_pass",
                     "link_margin_db", "never_read")


def link_margin_db(gain_db, budget) -> np.ndarray:
    """Link margin of the nominal tag, ``gain_db - budget.min_gain_db()`` [dB].

    Parameters
    ----------
    gain_db : array_like, float64
        One-way reader-to-tag channel gain (as the read log's ``gain_db``) [dB].
    budget : propagation.LinkBudget

    Returns
    -------
    numpy.ndarray, float64, same shape
        dB above the smallest gain that still reads (both thresholds,
        :meth:`propagation.LinkBudget.min_gain_db`); NaN where ``gain_db`` is.
    """
    return np.asarray(gain_db, dtype=np.float64) - float(budget.min_gain_db())


def link_closed(gain_db, budget) -> np.ndarray:
    """Whether the backscatter link closes, per coherent gain (the attempt's ray-traced
    gain on its hopped channel, multipath included; not a local mean).

    Parameters
    ----------
    gain_db : array_like, float64
        One-way reader-to-tag channel gain, reader pattern and tag antenna pattern
        included (as the read log's ``gain_db``) [dB]; -inf or NaN where not traced.
    budget : propagation.LinkBudget
        Its ``detected`` applies both thresholds (tag sensitivity, reader sensitivity).

    Returns
    -------
    numpy.ndarray of bool, same shape
    """
    g = np.asarray(gain_db, dtype=np.float64)
    ok = np.isfinite(g)
    out = np.zeros(g.shape, dtype=bool)
    out[ok] = np.asarray(budget.detected(g[ok]), dtype=bool)
    return out


def tour_tag_table(reads: pd.DataFrame, t_s, pass_index, tags: pd.DataFrame, budget) -> pd.DataFrame:
    """Counts per (tag, pass) of one tour (see the module docstring).

    Parameters
    ----------
    reads : pandas.DataFrame
        The tour's read log: ``time_s``, ``cycle``, ``tag_id``, ``read``, ``in_range``,
        ``gain_db``, and ``antenna`` (without it each cycle is a round).
    t_s : array_like, float64, (n_poses,)
        Pose times of the tour [s], increasing.
    pass_index : array_like, int, (n_poses,)
        Pass of each pose, -1 while turning around.
    tags : pandas.DataFrame
        ``tag_id`` and ``z_m`` of (at least) the tags in ``reads``.
    budget : propagation.LinkBudget

    Returns
    -------
    pandas.DataFrame
        Columns :data:`INVENTORY_COLUMNS`, one row per (tag, pass) with at least one
        attempt; ``unit`` is the tag id.

    Raises
    ------
    ValueError
        A tag of the read log without a height, or ``t_s`` / ``pass_index`` of different
        lengths.
    """
    t = np.asarray(t_s, dtype=np.float64)
    passes = np.asarray(pass_index, dtype=np.int64)
    if t.shape != passes.shape:
        raise ValueError(f"t_s has {t.size} poses, pass_index {passes.size}")
    z = pd.Series(tags["z_m"].to_numpy(np.float64), index=tags["tag_id"].astype(str))
    tag = reads["tag_id"].astype(str).to_numpy()
    missing = sorted(set(tag) - set(z.index))
    if missing:
        raise ValueError(f"tags {missing[:5]} of the read log have no height in the tag table")
    pose = np.clip(np.searchsorted(t, reads["time_s"].to_numpy(np.float64), side="right") - 1,
                   0, len(t) - 1)
    df = pd.DataFrame({
        "unit": tag,
        "pass": passes[pose],
        "cycle": read_rounds(reads),
        "in_range": reads["in_range"].to_numpy(bool),
        "read": reads["read"].to_numpy(bool),
        "closed": link_closed(reads["gain_db"].to_numpy(np.float64), budget)
        & reads["in_range"].to_numpy(bool),
        "margin": np.where(reads["in_range"].to_numpy(bool),
                           link_margin_db(reads["gain_db"].to_numpy(np.float64), budget), np.nan),
    })
    # a gain of -inf (no path) is no margin at all, not an infinitely short one: -inf
    # stays (the median takes it), NaN only where no attempt was in range
    df = df[df["pass"] >= 0]
    per_cycle = df.groupby(["unit", "pass", "cycle"], sort=True)["closed"].any()
    cyc = per_cycle.groupby(level=["unit", "pass"]).agg(["size", "sum"])
    att = df.groupby(["unit", "pass"], sort=True).agg(
        n_attempts=("read", "size"), n_in_range=("in_range", "sum"), n_reads=("read", "sum"),
        best_margin_db=("margin", "max"))
    out = att.join(cyc.rename(columns={"size": "n_cycles", "sum": "n_cycles_closed"})).reset_index()
    out["z_m"] = z.reindex(out["unit"]).to_numpy()
    out = out.astype({"n_attempts": np.int64, "n_in_range": np.int64, "n_reads": np.int64,
                      "n_cycles": np.int64, "n_cycles_closed": np.int64, "pass": np.int64})
    return out[list(INVENTORY_COLUMNS)]


def read_rounds(reads: pd.DataFrame) -> np.ndarray:
    """The read round of each row: ``cycle // (antennas / antennas per cycle)``.

    Counted per read cycle, a round-robin reader (one active antenna per cycle) would
    make "closes for at least one antenna" the same as "closes for this attempt's
    antenna", and the route coverage the same number as the read rate wherever the
    reader reads every closing link."""
    cycle = reads["cycle"].to_numpy(np.int64)
    if "antenna" not in reads or len(reads) == 0:
        return cycle
    ant = reads["antenna"].to_numpy(np.int64)
    n_ant = len(np.unique(ant))
    per_cycle = int(pd.Series(ant).groupby(cycle).nunique().max())
    return cycle // max(1, n_ant // max(1, per_cycle))


Statistic = Callable[[np.ndarray], np.ndarray]


def inventory_statistic(key: str, rows: pd.DataFrame, codes: np.ndarray, n_units: int, *,
                        min_reads: int = 1) -> Statistic:
    """The weighted statistic of inventory metric ``key`` over ``n_units`` units.

    Parameters
    ----------
    key : str
        One of :data:`INVENTORY_METRICS`.
    rows : pandas.DataFrame
        :func:`tour_tag_table` rows (of any number of replicates and tags).
    codes : numpy.ndarray, int, (len(rows),)
        Unit index of each row, in [0, n_units).
    n_units : int
    min_reads : int
        Reads a tag needs in a pass to count as inventoried (``completeness``).

    Returns
    -------
    callable
        ``statistic(w)``, ``w`` the units' multiplicities (..., n_units), as
        :func:`pipeline.evaluation.intervals.unit_interval` takes it.
    """
    def sums(col) -> np.ndarray:
        return np.bincount(codes, weights=np.asarray(col, np.float64), minlength=n_units)

    if key == "read_rate":
        num, den = sums(rows["n_reads"]), sums(rows["n_in_range"])
    elif key == "completeness":
        num, den = sums(rows["n_reads"] >= int(min_reads)), sums(np.ones(len(rows)))
    elif key == "surface_coverage":
        num, den = sums(rows["n_cycles_closed"]), sums(rows["n_cycles"])
    elif key == "reads_per_pass":
        num, den = sums(rows["n_reads"]), sums(np.ones(len(rows)))
    elif key == "link_margin_db":
        m = rows["best_margin_db"].to_numpy(np.float64)
        keep = ~np.isnan(m)
        v, c = m[keep], np.asarray(codes)[keep]
        if v.size == 0:  # no pass in range at all: no margin to take a median of
            return lambda w: np.full(np.shape(w)[:-1], np.nan)
        return lambda w: weighted_quantile(v, np.asarray(w, np.float64)[..., c], 0.5)
    elif key == "never_read":
        # one indicator per unit (a tag of one replicate): no read in any pass
        num = (sums(rows["n_reads"]) == 0).astype(np.float64)
        den = (np.bincount(codes, minlength=n_units) > 0).astype(np.float64)
    else:
        raise KeyError(f"unknown inventory metric {key!r}; known: "
                       f"{', '.join(INVENTORY_METRICS)}")

    def stat(w):
        with np.errstate(invalid="ignore", divide="ignore"):
            return (w @ num) / (w @ den)
    return stat

