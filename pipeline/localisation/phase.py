"""Tag localisation from backscatter phase: a synthetic-aperture (holographic) estimator.

A UHF reader reports, with every read, the phase of the tag's backscatter. For a read
i of a tag at position c, from the reader antenna at p_i on channel f_i,

    phase_i = mod(4 pi f_i |p_i - c| / c0 + offset(antenna, channel) + n_i + pi B_i, 2 pi)

(in free space; the ray-traced channel h gives ``-angle(h**2)`` instead of the first
term), with an unknown constant ``offset`` per (antenna, channel) and tag (cables and reader
per antenna and channel, each tag's own reflection phase), noise ``n_i`` and the reader's
pi ambiguity ``B_i`` in {0, 1}. The simulated reader also shifts a read's phase with the
power its tag's chip absorbs (:mod:`pipeline.acquisition.phase`, up to 100 degrees):
this estimator does not model that term; it varies within a group as the antenna moves,
so it lowers the concentration the data show (kappa, estimated from the data by
default) and biases the range where it changes fastest. Two steps make the
unknowns drop out:

* **pi ambiguity**: the doubled phase ``2 phase_i`` is the same for B = 0 and 1, so the
  estimator works with ``exp(j 2 phase_i)``; the doubled range term
  ``psi_i(c) = 8 pi f_i |p_i - c| / c0`` wraps every lambda / 4 (8.7 cm at 866 MHz) of
  range;
* **offsets**: within one group g of reads sharing (antenna, channel) the offset is one
  common phase factor, so the magnitude of the group's coherent sum
  ``R_g(c) = |sum_{i in g} exp(j (2 phase_i - psi_i(c)))|`` does not depend on it.

With von Mises noise of concentration kappa on the doubled phase and each group's
offset uniform on [0, 2 pi), the marginal likelihood of a group's phases is
proportional to ``I0(kappa R_g(c))`` (integrate ``prod_i exp(kappa cos(...))`` over the
offset), so

    log p(phases | c) = sum_g log I0(kappa R_g(c)) + const,

whose large-kappa limit is ``kappa sum_g R_g(c)``: the classic holographic score (sum
of the groups' magnitudes), here with a calibrated scale. A candidate stands for its
cell (the square of the grid's spacing about it on its face, for candidates with
surface normals such as :class:`scenes.tagsites.TagSites`; the cube of that side for
bare positions): its likelihood is the point likelihood averaged over the cell, the tag
uniform within it, ``p(phases | cell) = mean over the cell of p(phases | x)``, by the
midpoint rule on 3 x 3 sub-cells in the face's (horizontal, vertical) plane (3 x 3 x 3
for bare positions; a log-mean-exp of the sub-points' log likelihoods).

Approximation: only the ``refine_top`` candidates of highest holographic score per tag
get that cell mean; every other candidate keeps its centre's point likelihood, which
stands in for its cell's mean (higher where the centre sits on a lobe, lower where a
lobe narrower than the cell passes beside it). The posterior thus mixes the two
quantities; it is exactly the posterior over cells only with ``refine_top`` >= the
candidates in reach (every cell refined; 9 times the work), and close to it where the
unrefined candidates' likelihood is far below the refined ones' (a few nats per group
below the main lobe). :attr:`PhasePosteriors.refined` says which candidates carry the
cell mean. The result is a likelihood (with every cell refined, the posterior over
cells is what the posterior over the sub-points sums to per cell), so that
:func:`combine_posteriors` may multiply it with another source's. kappa comes from the
phase noise std given (``phase_sigma_rad``: the wrapped-normal std sigma of one phase
gives the doubled phase a mean resultant length ``exp(-2 sigma^2)``) or, by default,
from the data: the pooled, bias-corrected resultant length of every group at each
tag's best candidate (:func:`estimate_kappa`), which also absorbs what the noise alone
does not (pose error, multipath).

Geometry. A straight antenna track leaves the range to the track as the only
constraint: a group's score is the same on a circle about the track, so phase alone
cannot tell a tag from its mirror about the antenna's height (as a model of (d, alpha)
cannot) and, where the corridor is narrow enough, from a point on the opposite wall.
Candidates are therefore restricted to the reader's range of some antenna pose that
read the tag (a passive tag is not read beyond it: the simulated reader does not even
attempt it), and :func:`combine_posteriors` multiplies the phase likelihood with a
read / RSSI model's (independent evidence of the same position), which tells the
walls apart. Resolution: across the track about ``(lambda / 4) d / L`` for a tag at
distance d read over an aperture L (3 cm at d = 1.2 m, L = 3 m); a group sampled
coarser than lambda / 8 along the track (about 4 cm) has grating lobes, which the
near-field curvature and the several groups smear out but do not remove.

The robot's antenna poses (MCL) enter the range term directly: a pose error of
lambda / 8 = 4.3 cm along the line of sight turns the doubled phase by pi, so what
matters is the pose error's variation over a tag's aperture (a constant offset shifts
the image by as much, white errors of that size scramble it). ``segment_m`` splits each
group into sub-apertures of at most that much antenna travel, trading resolution for
robustness to slowly drifting poses.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
import pandas as pd
from scipy.special import i0e, logsumexp

from pipeline.localisation.phase_cells import _grid_step, cell_points
from pipeline.localisation.tags import (
    TagPosteriors,
    _check_candidates,
    _check_prior,
    combine_posteriors,
)
from propagation.constants import SPEED_OF_LIGHT

__all__ = [
    "PHASE_COLUMNS",
    "PhaseColumnsMissing",
    "PhasePosteriors",
    "PhaseReads",
    "combine_posteriors",
    "estimate_kappa",
    "kappa_from_sigma",
    "localise_tags_phase",
    "cell_points",
    "phase_reads_from_table",
    "simulate_phase_rad",
]

#: Columns of a read table the phase estimator needs beyond the pose columns.
PHASE_COLUMNS = ("frequency_hz", "phase_rad")
_POSE_COLS = ("x_m", "y_m", "z_m")
#: Largest kappa used (mean resultant length 1 - 1/(2 kappa)); keeps log I0 finite.
_KAPPA_MAX = 1e4


@dataclass(frozen=True)
class PhasePosteriors(TagPosteriors):
    """:class:`~.tags.TagPosteriors` of the phase estimator, with the concentration used.

    Attributes
    ----------
    kappa : float
        Von Mises concentration of the doubled phase the likelihood used (given or
        estimated; 0: the phases carried no position).
    refined : numpy.ndarray, shape (T, C), bool, or None
        The candidates whose likelihood is their cell's mean (the ``refine_top`` of each
        tag); the others carry their centre's point likelihood (module doc).
    """

    kappa: float = float("nan")
    refined: np.ndarray | None = None


class PhaseColumnsMissing(ValueError):
    """The read table carries no phase (``phase_rad``) or channel (``frequency_hz``)."""


@dataclass(frozen=True)
class PhaseReads:
    """The phase reads of T tags, one entry per read (tags concatenated).

    Attributes
    ----------
    tag_ids : tuple of str
        The T tags.
    tag_index : numpy.ndarray, shape (N,), int64
        Tag (row of ``tag_ids``) of each read.
    time_s : numpy.ndarray, shape (N,), float64
        Time of each read [s].
    antenna : numpy.ndarray, shape (N,), int64
        Reader antenna index.
    frequency_hz : numpy.ndarray, shape (N,), float64
        Channel of the read [Hz].
    phase_rad : numpy.ndarray, shape (N,), float64
        Reported phase [rad], in [0, 2 pi) (any real value is accepted).
    antenna_xyz_m : numpy.ndarray, shape (N, 3), float64
        Antenna phase centre of each read [m] (world frame; MCL or true).
    n_attempts : numpy.ndarray, shape (T,), int64
        Read attempts of each tag (read or not).
    """

    tag_ids: tuple
    tag_index: np.ndarray
    time_s: np.ndarray
    antenna: np.ndarray
    frequency_hz: np.ndarray
    phase_rad: np.ndarray
    antenna_xyz_m: np.ndarray
    n_attempts: np.ndarray

    def __post_init__(self) -> None:
        ids = tuple(str(t) for t in self.tag_ids)
        if len(set(ids)) != len(ids):
            raise ValueError(f"PhaseReads: duplicate tag ids {sorted(ids)}")
        object.__setattr__(self, "tag_ids", ids)
        n = len(np.asarray(self.tag_index).reshape(-1))
        for name, dtype in (("tag_index", np.int64), ("time_s", np.float64),
                            ("antenna", np.int64), ("frequency_hz", np.float64),
                            ("phase_rad", np.float64)):
            v = np.asarray(getattr(self, name), dtype=dtype).reshape(-1)
            if v.shape != (n,):
                raise ValueError(f"PhaseReads: {name} has {v.size} entries, expected {n}")
            object.__setattr__(self, name, v)
        xyz = np.asarray(self.antenna_xyz_m, dtype=np.float64).reshape(-1, 3)
        if xyz.shape != (n, 3):
            raise ValueError(f"PhaseReads: antenna_xyz_m has shape {xyz.shape}, expected ({n}, 3)")
        object.__setattr__(self, "antenna_xyz_m", xyz)
        if n and (self.tag_index.min() < 0 or self.tag_index.max() >= len(ids)):
            raise ValueError(f"PhaseReads: tag_index outside [0, {len(ids)})")
        finite = [np.isfinite(self.time_s).all(), np.isfinite(self.phase_rad).all(),
                  np.isfinite(xyz).all(), np.isfinite(self.frequency_hz).all()]
        if not all(finite):
            raise ValueError("PhaseReads: times, phases, frequencies and poses must be finite")
        if n and np.any(self.frequency_hz <= 0):
            raise ValueError("PhaseReads: frequencies must be positive [Hz]")
        att = np.asarray(self.n_attempts, dtype=np.int64).reshape(-1)
        if att.shape != (len(ids),):
            raise ValueError(f"PhaseReads: n_attempts has {att.size} entries, expected {len(ids)}")
        object.__setattr__(self, "n_attempts", att)

    @property
    def n_tags(self) -> int:
        return len(self.tag_ids)

    @property
    def n_reads(self) -> np.ndarray:
        """Reads per tag (T,), int64."""
        return np.bincount(self.tag_index, minlength=self.n_tags).astype(np.int64)


def phase_reads_from_table(reads: pd.DataFrame, pose: str = "est", *,
                           tag_ids: Sequence | None = None,
                           table: str = "eval_reads") -> PhaseReads:
    """The phase reads of a ``reads.parquet``-format table (one row per attempt).

    Parameters
    ----------
    reads : pandas.DataFrame
        Columns ``time_s, antenna, tag_id, read, frequency_hz, phase_rad`` and
        ``<pose>_ant_x_m, _y_m, _z_m``. Rows not read, or read with a NaN phase, are
        attempts only.
    pose : {"est", "true"}
        Antenna positions: the MCL estimate (what the robot knows) or the ground truth.
    tag_ids : sequence of str, optional
        Tags, in this order; default every tag of the table (categories order if
        ``tag_id`` is categorical, else of first attempt). A tag the table does not
        have gets no reads (its posterior is the prior).
    table : str
        Name of the table in error messages.

    Returns
    -------
    PhaseReads

    Raises
    ------
    PhaseColumnsMissing
        The table has no ``phase_rad`` or ``frequency_hz`` column (a read log written
        without phases).
    ValueError
        Other missing columns, or a bad ``pose``.
    """
    if pose not in ("est", "true"):
        raise ValueError(f"pose must be 'est' or 'true', got {pose!r}")
    if not isinstance(reads, pd.DataFrame):
        raise ValueError(f"{table}: expected a pandas DataFrame, got {type(reads).__name__}")
    lacking = [c for c in PHASE_COLUMNS if c not in reads.columns]
    if lacking:
        raise PhaseColumnsMissing(
            f"{table}: no {' / '.join(repr(c) for c in lacking)} column(s): the read table "
            "carries no backscatter phase, so the phase estimator cannot run")
    pcols = [f"{pose}_ant_{c}" for c in _POSE_COLS]
    need = ["time_s", "antenna", "tag_id", "read", *pcols]
    missing = [c for c in need if c not in reads.columns]
    if missing:
        raise ValueError(f"{table}: missing column(s) {missing}")
    tags_col = reads["tag_id"].astype(str).to_numpy()
    if tag_ids is None:
        if isinstance(reads["tag_id"].dtype, pd.CategoricalDtype):
            seen = set(tags_col)
            ids = [str(c) for c in reads["tag_id"].cat.categories if str(c) in seen]
        else:
            order = np.argsort(reads["time_s"].to_numpy(np.float64), kind="stable")
            ids = list(pd.unique(tags_col[order]))
    else:
        ids = [str(t) for t in tag_ids]
    row_of = {t: i for i, t in enumerate(ids)}
    tag_row = np.array([row_of.get(t, -1) for t in tags_col], dtype=np.int64)
    phase = reads["phase_rad"].to_numpy(np.float64)
    keep = (tag_row >= 0) & reads["read"].to_numpy(bool) & np.isfinite(phase)
    attempts = np.bincount(tag_row[tag_row >= 0], minlength=len(ids))
    return PhaseReads(tuple(ids), tag_row[keep], reads["time_s"].to_numpy(np.float64)[keep],
                      reads["antenna"].to_numpy(np.int64)[keep],
                      reads["frequency_hz"].to_numpy(np.float64)[keep], phase[keep],
                      np.column_stack([reads[c].to_numpy(np.float64)[keep] for c in pcols]),
                      attempts)


def simulate_phase_rad(antenna_xyz_m, tag_xyz_m, frequency_hz, offset_rad, rng: np.random.Generator,
                       *, noise_std_rad: float = 0.1, pi_ambiguity: bool = True) -> np.ndarray:
    """Free-space reader phases of reads (the read-table contract), for tests and benchmarks.

    Parameters
    ----------
    antenna_xyz_m : array_like, shape (N, 3)
        Antenna positions of the reads [m] (the true ones).
    tag_xyz_m : array_like, shape (3,) or (N, 3)
        Tag position [m].
    frequency_hz, offset_rad : array_like, shape (N,) or scalar
        Channel [Hz] and the (antenna, channel) offset of each read [rad].
    rng : numpy.random.Generator
        Noise and ambiguity draws.
    noise_std_rad : float
        Gaussian phase noise std [rad].
    pi_ambiguity : bool
        Add pi with probability 1/2 per read.

    Returns
    -------
    numpy.ndarray, shape (N,), float64
        ``mod(4 pi f d / c0 + offset + noise + pi B, 2 pi)`` [rad].
    """
    p = np.asarray(antenna_xyz_m, dtype=np.float64).reshape(-1, 3)
    d = np.linalg.norm(p - np.asarray(tag_xyz_m, dtype=np.float64), axis=-1)
    n = len(p)
    ph = 4.0 * np.pi * np.asarray(frequency_hz, float) * d / SPEED_OF_LIGHT + offset_rad
    ph = ph + float(noise_std_rad) * rng.standard_normal(n)
    if pi_ambiguity:
        ph = ph + np.pi * rng.integers(0, 2, n)
    return np.mod(ph, 2.0 * np.pi)


def kappa_from_sigma(phase_sigma_rad: float) -> float:
    """Von Mises concentration of the doubled phase for a phase noise std [rad].

    Matches the mean resultant length of the doubled wrapped-normal noise,
    ``A(kappa) = exp(-2 sigma^2)`` (:func:`_inverse_a`).
    """
    s = float(phase_sigma_rad)
    if not s > 0:
        raise ValueError(f"phase_sigma_rad must be > 0, got {phase_sigma_rad}")
    return _inverse_a(np.exp(-2.0 * s * s))


def _inverse_a(rbar: float) -> float:
    """kappa with ``I1(kappa) / I0(kappa) = rbar`` (Best & Fisher 1981's approximation)."""
    r = float(np.clip(rbar, 0.0, 1.0))
    if r < 0.53:
        k = 2 * r + r ** 3 + 5 * r ** 5 / 6
    elif r < 0.85:
        k = -0.4 + 1.39 * r + 0.43 / (1 - r)
    else:
        k = 1.0 / (r ** 3 - 4 * r ** 2 + 3 * r) if r < 1.0 else np.inf
    return float(min(k, _KAPPA_MAX))


def estimate_kappa(resultants, group_sizes) -> float:
    """Doubled-phase concentration from groups' resultant lengths at their best candidates.

    With von Mises noise, ``E[R^2] = n + n (n - 1) A(kappa)^2`` for a group of n reads,
    so ``A^2 = sum_g (R_g^2 - n_g) / sum_g n_g (n_g - 1)`` (groups of one read carry
    nothing). The resultants at the maximising candidate are a little optimistic (the
    position is fitted), which makes kappa slightly large.

    Parameters
    ----------
    resultants, group_sizes : array_like, shape (G,)
        ``R_g`` and ``n_g`` of every group (all tags pooled).

    Returns
    -------
    float
        kappa >= 0 (0: the phases are uniform, they carry no position).
    """
    r = np.asarray(resultants, dtype=np.float64).reshape(-1)
    n = np.asarray(group_sizes, dtype=np.float64).reshape(-1)
    den = float(np.sum(n * (n - 1.0)))
    if den <= 0:
        return 0.0
    a2 = float(np.sum(r * r - n)) / den
    return _inverse_a(np.sqrt(np.clip(a2, 0.0, 1.0)))


def _groups(rd: PhaseReads, rows: np.ndarray, segment_m: float | None,
            frequency_tol_hz: float) -> tuple[np.ndarray, np.ndarray]:
    """Group index of each read of `rows` and the group sizes: one group per (antenna,
    channel), split every ``segment_m`` of antenna travel."""
    ant = rd.antenna[rows]
    ch = np.round(rd.frequency_hz[rows] / frequency_tol_hz).astype(np.int64)
    key = [ant, ch]
    if segment_m is not None:
        order = np.argsort(rd.time_s[rows], kind="stable")
        step = np.linalg.norm(np.diff(rd.antenna_xyz_m[rows][order], axis=0), axis=1)
        s = np.empty(len(rows))
        s[order] = np.concatenate([[0.0], np.cumsum(step)])
        key.append(np.floor(s / float(segment_m)).astype(np.int64))
    _, g, sizes = np.unique(np.stack(key, axis=1), axis=0, return_inverse=True,
                            return_counts=True)
    return g.reshape(-1), sizes


def _resultants(xyz, wavenum, phase2, group, n_groups, cand, chunk: int) -> np.ndarray:
    """``R_g(c)`` (G, C) float32: each group's coherent-sum magnitude at every candidate.

    ``wavenum`` is ``8 pi f / c0`` per read [rad/m]; the per-group sums are two real
    matrix products with the (G, n) group indicator. Single precision: coordinates
    relative to the reads' centroid keep the range error below a micrometre, the
    doubled phase's error below 1e-4 rad.
    """
    f32 = np.float32
    origin = xyz.mean(axis=0)
    p = (xyz - origin).astype(f32)
    ind = np.zeros((n_groups, len(xyz)), dtype=f32)
    ind[group, np.arange(len(xyz))] = 1.0
    k, ph = wavenum.astype(f32)[:, None], phase2.astype(f32)[:, None]
    out = np.empty((n_groups, len(cand)), dtype=f32)
    for c0 in range(0, len(cand), chunk):
        c = (cand[c0:c0 + chunk] - origin).astype(f32)
        d2 = np.square(c[None, :, 0] - p[:, None, 0])
        d2 += np.square(c[None, :, 1] - p[:, None, 1])
        d2 += np.square(c[None, :, 2] - p[:, None, 2])
        arg = ph - k * np.sqrt(d2)
        re, im = ind @ np.cos(arg), ind @ np.sin(arg)
        out[:, c0:c0 + chunk] = np.sqrt(re * re + im * im)
    return out


def localise_tags_phase(reads: PhaseReads, candidates, *, phase_sigma_rad: float | None = None,
                        reach_m: float | None = None, segment_m: float | None = None,
                        refine_top: int = 128, cell_m: float | None = None,
                        log_prior=None, chunk_size: int = 4096,
                        frequency_tol_hz: float = 1e3, local_radius_m: float = 0.25,
                        name: str = "phase") -> TagPosteriors:
    """Posterior of every tag's position over `candidates` from its reads' phases.

    Parameters
    ----------
    reads : PhaseReads
        E.g. :func:`phase_reads_from_table` of the evaluation tour's reads, MCL poses.
    candidates : array_like (C, 3) or TagSites
        Candidate positions [m].
    phase_sigma_rad : float, optional
        Phase noise std [rad] that sets kappa (:func:`kappa_from_sigma`); default: kappa
        estimated from the data, pooled over the tags (:func:`estimate_kappa`).
    reach_m : float, optional
        Only candidates within this distance of the antenna of some read of the tag
        (the reader's range) [m]; default every candidate. A tag without reads keeps
        every candidate.
    segment_m : float, optional
        Split each (antenna, channel) group every this much antenna travel [m]; default
        one group per (antenna, channel).
    refine_top : int
        Per tag, the candidates of the highest holographic score ``sum_g R_g`` whose
        likelihood is the mean of the point likelihood over their cell (the square of
        side ``cell_m`` on the candidate's face where the candidates carry ``normals``,
        else the cube; the midpoint rule, :func:`cell_points`, a log-mean-exp of the
        sub-points' log likelihoods) instead of its centre's value: the
        main lobe of a long aperture is a few centimetres wide, narrower than the
        candidate grid, so a tag between candidates would otherwise lose to a sidelobe
        or a mirror image that happens to fall on a candidate. 0: no refinement (every
        candidate its centre's value). The others keep their centre's value: an
        approximation (module doc; :attr:`PhasePosteriors.refined`).
    cell_m : float, optional
        Candidate spacing [m]; default the median nearest-neighbour distance of the
        candidates.
    log_prior : array_like (C,) or (T, C), optional
        Log prior, added to the phase log likelihood (uniform by default).
    chunk_size : int
        Candidates per chunk: memory about ``5 * 8 * chunk_size * n`` bytes for a tag of
        n reads.
    frequency_tol_hz : float
        Frequencies closer than this are one channel [Hz].
    local_radius_m : float
        Radius of :attr:`TagPosteriors.local_mean_m` [m].
    name : str
        ``source`` of the result.

    Returns
    -------
    PhasePosteriors
        ``n_reads`` counts the reads with a phase; the posterior of a tag without
        reads is the prior (uniform by default): finite and normalised.
    """
    if not isinstance(reads, PhaseReads):
        raise ValueError(f"reads must be PhaseReads (see phase_reads_from_table), got "
                         f"{type(reads).__name__}")
    cand = _check_candidates(candidates)
    normals = getattr(candidates, "normals", None)
    if normals is not None:
        normals = np.asarray(normals, dtype=np.float64).reshape(-1, 3)
        if len(normals) != len(cand):
            raise ValueError(f"candidates: {len(normals)} normals for {len(cand)} positions")
    T, C = reads.n_tags, len(cand)
    lp = _check_prior(log_prior, T, C)
    if reach_m is not None and not float(reach_m) > 0:
        raise ValueError(f"reach_m must be > 0, got {reach_m}")
    if segment_m is not None and not float(segment_m) > 0:
        raise ValueError(f"segment_m must be > 0, got {segment_m}")
    chunk = max(1, int(chunk_size))
    n_top = max(0, int(refine_top))
    cell = _grid_step(cand) if cell_m is None else float(cell_m)
    per_tag = []  # (columns, R (G, Cc), group sizes) of each tag with reads
    for t in range(T):
        rows = np.flatnonzero(reads.tag_index == t)
        if len(rows) == 0:
            per_tag.append(None)
            continue
        xyz = reads.antenna_xyz_m[rows]
        cols = np.arange(C)
        if reach_m is not None:
            near = _within(cand, xyz, float(reach_m))
            cols = np.flatnonzero(near) if near.any() else cols
        group, sizes = _groups(reads, rows, segment_m, float(frequency_tol_hz))
        wavenum = 8.0 * np.pi * reads.frequency_hz[rows] / SPEED_OF_LIGHT
        args = (xyz, wavenum, 2.0 * reads.phase_rad[rows], group, len(sizes))
        res = _resultants(*args, cand[cols], chunk)
        top, sub = (_refine(res, cand[cols], None if normals is None else normals[cols], args,
                            cell, n_top, chunk) if n_top and cell
                    else (np.zeros(0, np.int64), None))
        per_tag.append((cols, res, sizes, top, sub))
    if phase_sigma_rad is not None:
        kappa = kappa_from_sigma(phase_sigma_rad)
    else:
        best = [(_best_resultants(r, sub), n) for _, r, n, _, sub in filter(None, per_tag)]
        kappa = estimate_kappa(np.concatenate([b[0] for b in best]) if best else [],
                               np.concatenate([b[1] for b in best]) if best else [])
    ll = np.zeros((T, C))
    refined = np.zeros((T, C), dtype=bool)
    for t, item in enumerate(per_tag):
        if item is None:
            continue
        cols, res, _, top, sub = item
        row = np.full(C, -np.inf)
        row[cols] = _log_i0_sum(kappa, res)
        if sub is not None:  # the cell's mean likelihood: log-mean-exp over its sub-points
            lsub = _log_i0_sum(kappa, sub)  # (k, 9 or 27)
            row[cols[top]] = logsumexp(lsub, axis=1) - np.log(lsub.shape[1])
            refined[t, cols[top]] = True
        ll[t] = row
    post = ll if lp is None else ll + lp
    bad = ~np.isfinite(logsumexp(post, axis=1))
    if np.any(bad):  # the prior excludes every candidate in reach: drop the reach limit
        post[bad] = (np.where(np.isfinite(ll[bad]), ll[bad], 0.0)
                     + (0.0 if lp is None else lp[bad]))
    post = post - logsumexp(post, axis=1, keepdims=True)
    return PhasePosteriors(str(name), reads.tag_ids, cand, post, reads.n_attempts.copy(),
                           reads.n_reads, float(local_radius_m), kappa=float(kappa),
                           refined=refined)


def _refine(res: np.ndarray, cand: np.ndarray, normals, args: tuple, cell_m: float,
            n_top: int, chunk: int) -> tuple[np.ndarray, np.ndarray]:
    """The `n_top` candidates of highest holographic score and the resultants at the
    sub-points of their cells (:func:`cell_points`): ``(top (k,), sub (G, k, 9 or 27))``."""
    k = min(n_top, len(cand))
    top = np.argpartition(res.sum(axis=0), len(cand) - k)[len(cand) - k:]
    pts = cell_points(cand[top], cell_m, None if normals is None else normals[top])
    sub = _resultants(*args, pts.reshape(-1, 3), chunk).reshape(len(res), k, pts.shape[1])
    return top, sub


#: Columns per block of :func:`_log_i0_sum` (float64 temporaries ~G x 16,384 x 8 bytes).
_LOG_I0_COLUMNS = 1 << 14


def _log_i0_sum(kappa: float, res: np.ndarray) -> np.ndarray:
    """``sum_g log I0(kappa R_g)`` over the first axis of the resultants (G, ...), in blocks
    of columns: the same sums in bounded memory (whole, a warehouse's tag made GBs)."""
    flat, step = res.reshape(len(res), -1), _LOG_I0_COLUMNS
    out = np.empty(flat.shape[1])
    for c in range(0, flat.shape[1], step):
        x = kappa * flat[:, c:c + step].astype(np.float64)
        out[c:c + step] = np.sum(x + np.log(i0e(x)), axis=0)  # log I0(x) = x + log i0e(x)
    return out.reshape(res.shape[1:])


def _best_resultants(res: np.ndarray, sub: np.ndarray | None) -> np.ndarray:
    """Each group's resultant (G,) at the point of highest holographic score, cell centres
    and refined sub-points alike (where :func:`estimate_kappa` reads the data's
    concentration)."""
    j = int(np.argmax(res.sum(axis=0)))
    if sub is None or sub.size == 0:
        return res[:, j]
    score = sub.sum(axis=0)  # (k, 27)
    a, b = np.unravel_index(int(np.argmax(score)), score.shape)
    return sub[:, a, b] if score[a, b] > res[:, j].sum() else res[:, j]


def _within(cand: np.ndarray, xyz: np.ndarray, radius_m: float) -> np.ndarray:
    """(C,) bool: candidates within `radius_m` of some of the points `xyz` (n, 3)."""
    from scipy.spatial import cKDTree

    d, _ = cKDTree(np.unique(xyz, axis=0)).query(cand, distance_upper_bound=radius_m)
    return np.isfinite(d)
