"""Tag localisation: the posterior over candidate positions of every tag, per sensor model.

For a tag with outcomes ``z_s`` in the attempt slots s (antenna poses known, e.g. MCL),
the posterior over candidate positions c (e.g. :func:`scenes.tagsites.tag_sites` at a few
centimetres) is

    log p(c | z) = log prior(c) + sum_s log p(z_s | c) - log Z,

with the per-pair terms of :mod:`pipeline.localisation.likelihood`. The sum splits into
the misses, ``(attempted and not read) @ log_miss`` (one matrix product for all tags),
and the reads, evaluated only at the (few) slots where the tag was read. The per-pair
predictions (model outputs at the pairs' d and alpha, or the oracle's gains) do not
depend on the tag, so they are computed once per chunk of candidates and reused for
every tag; chunks bound the memory (``chunk_size`` candidates x S slots per array).

A tag never read has only misses: its posterior is broad (every position from which it
would have been read is unlikely) but finite and normalised, never an error. A tag with
no attempts at all keeps the prior.

Estimates: the MAP candidate, the posterior mean, and the *local* posterior mean (the
mean over the candidates within ``local_radius_m`` of the MAP; the global mean of a
posterior with modes on both walls of a corridor lies in the middle of the corridor).
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass

import numpy as np
from scipy.special import logsumexp

from pipeline.localisation.likelihood import ModelLikelihood
from pipeline.localisation.observations import Observations, pair_geometry
from pipeline.localisation.oracle_likelihood import OracleGains

__all__ = [
    "ESTIMATORS",
    "TagPosteriors",
    "as_tag_map",
    "combine_posteriors",
    "localisation_summary",
    "localise_tags",
    "read_region_mask",
    "tag_position_errors",
]

#: Point estimates a :class:`TagPosteriors` gives.
ESTIMATORS = ("map", "mean", "local_mean")


@dataclass(frozen=True)
class TagPosteriors:
    """Posteriors of T tags over C candidate positions from one likelihood source.

    Attributes
    ----------
    source : str
    tag_ids : tuple of str
    candidates_m : numpy.ndarray, shape (C, 3)
    log_posterior : numpy.ndarray, shape (T, C)
        Normalised (``logsumexp`` over candidates = 0 per tag).
    n_attempts, n_reads : numpy.ndarray, shape (T,), int64
    local_radius_m : float
        Radius of the local mean about the MAP [m].
    """

    source: str
    tag_ids: tuple
    candidates_m: np.ndarray
    log_posterior: np.ndarray
    n_attempts: np.ndarray
    n_reads: np.ndarray
    local_radius_m: float = 0.25

    @property
    def posterior(self) -> np.ndarray:
        """Probabilities (T, C), rows sum to 1."""
        return np.exp(self.log_posterior)

    @property
    def map_index(self) -> np.ndarray:
        return np.argmax(self.log_posterior, axis=1)

    @property
    def map_m(self) -> np.ndarray:
        """MAP candidate of every tag (T, 3) [m]."""
        return self.candidates_m[self.map_index]

    @property
    def mean_m(self) -> np.ndarray:
        """Posterior mean (T, 3) [m]."""
        return self.posterior @ self.candidates_m

    @property
    def local_mean_m(self) -> np.ndarray:
        """Posterior mean over the candidates within ``local_radius_m`` of the MAP (T, 3)."""
        out = np.empty((len(self.tag_ids), 3))
        c = self.candidates_m
        for t, i in enumerate(self.map_index):
            near = np.sum((c - c[i]) ** 2, axis=1) <= self.local_radius_m ** 2
            lp = self.log_posterior[t, near]
            w = np.exp(lp - logsumexp(lp))
            out[t] = w @ c[near]
        return out

    @property
    def spread_m(self) -> np.ndarray:
        """Posterior standard deviation of the position, sqrt(E|x - mean|^2) (T,) [m]."""
        p, mu = self.posterior, self.mean_m
        sq = np.sum(self.candidates_m ** 2, axis=1)
        var = p @ sq - np.sum(mu ** 2, axis=1)
        return np.sqrt(np.maximum(var, 0.0))

    def estimate(self, kind: str = "map") -> np.ndarray:
        """Point estimates (T, 3) [m]: ``"map"``, ``"mean"`` or ``"local_mean"``."""
        if kind == "map":
            return self.map_m
        if kind == "mean":
            return self.mean_m
        if kind == "local_mean":
            return self.local_mean_m
        raise ValueError(f"estimate kind must be one of {ESTIMATORS}, got {kind!r}")


def _check_candidates(candidates) -> np.ndarray:
    c = np.asarray(getattr(candidates, "positions_m", candidates), dtype=np.float64)
    if c.ndim != 2 or c.shape[1] != 3 or len(c) == 0:
        raise ValueError(f"candidates must be a non-empty (C, 3) array of positions [m], "
                         f"got shape {c.shape}")
    if not np.all(np.isfinite(c)):
        raise ValueError("candidates contain NaN or inf")
    return c


def _check_prior(log_prior, n_tags: int, n_cand: int) -> np.ndarray | None:
    if log_prior is None:
        return None
    lp = np.asarray(log_prior, dtype=np.float64)
    if lp.shape == (n_cand,):
        lp = np.broadcast_to(lp, (n_tags, n_cand))
    if lp.shape != (n_tags, n_cand):
        raise ValueError(f"log_prior must have shape ({n_cand},) or ({n_tags}, {n_cand}), "
                         f"got {lp.shape}")
    if np.any(np.isnan(lp)) or np.any(lp == np.inf):
        raise ValueError("log_prior contains NaN or +inf")
    if n_cand and np.any(np.all(np.isneginf(lp), axis=1)):
        raise ValueError("log_prior excludes every candidate of some tag")
    return lp


def localise_tags(obs: Observations, candidates, sources, *, log_prior=None,
                  chunk_size: int = 2048, local_radius_m: float = 0.25) -> dict:
    """Posterior of every tag of `obs` over `candidates`, for each likelihood source.

    Parameters
    ----------
    obs : Observations
        Outcomes (T tags x S slots) with the slots' antenna poses.
    candidates : array_like (C, 3) or TagSites
        Candidate positions [m] (world frame).
    sources : Mapping[str, ModelLikelihood | OracleGains] or a single one
        Likelihood sources; an :class:`OracleGains` holds the true gains (S, C) of
        exactly these slots and candidates.
    log_prior : array_like (C,) or (T, C), optional
        Log prior (uniform by default); -inf excludes candidates (e.g.
        ``np.where(read_region_mask(...), 0, -inf)``).
    chunk_size : int
        Candidates per chunk: memory is about ``10 * 8 * chunk_size * S`` bytes per source.
    local_radius_m : float
        Radius of :attr:`TagPosteriors.local_mean_m` [m].

    Returns
    -------
    dict[str, TagPosteriors]
        One per source, in the order given.
    """
    if isinstance(sources, (ModelLikelihood, OracleGains)):
        sources = {sources.name: sources}
    if not isinstance(sources, Mapping) or not sources:
        raise ValueError("sources must be a non-empty mapping name -> ModelLikelihood | "
                         "OracleGains")
    cand = _check_candidates(candidates)
    T, S, C = obs.n_tags, obs.n_slots, len(cand)
    for name, src in sources.items():
        if isinstance(src, OracleGains):
            if src.gain_db.shape != (S, C):
                raise ValueError(f"source {name!r}: oracle gains have shape {src.gain_db.shape}, "
                                 f"expected (slots, candidates) = ({S}, {C})")
        elif not isinstance(src, ModelLikelihood):
            raise ValueError(f"source {name!r}: expected a ModelLikelihood or OracleGains, got "
                             f"{type(src).__name__}")
    lp = _check_prior(log_prior, T, C)
    chunk = max(1, int(chunk_size))
    models = {k: s for k, s in sources.items() if isinstance(s, ModelLikelihood)}
    alpha_within = max((m.alpha_needed_within_m for m in models.values()), default=0.0)
    miss = (obs.attempted & ~obs.read).astype(np.float64)  # (T, S)
    r_tag, r_slot = np.nonzero(obs.read)  # every read (tag, slot)
    r_rssi = obs.rssi_dbm[r_tag, r_slot][:, None]
    # (T, R) indicator: sums each tag's read terms with one matrix product
    read_ind = np.zeros((T, len(r_tag)))
    read_ind[r_tag, np.arange(len(r_tag))] = 1.0
    ll = {name: np.zeros((T, C)) for name in sources}
    order = _spatial_order(cand)  # compact chunks: few slots within d_max of a chunk
    for c0 in range(0, C if S else 0, chunk):
        cols = order[c0:c0 + chunk]
        for name, src in sources.items():
            if isinstance(src, OracleGains):
                terms = src.terms_for(cols)
                out = miss @ terms.log_miss
                if len(r_tag):
                    out += read_ind @ terms.read_loglik(r_rssi, r_slot)
                ll[name][:, cols] = out
        if not models:
            continue
        d = pair_geometry(obs.slot_poses, cand[cols], alpha_within_m=0.0)[0]  # (S, Cc)
        far = {}  # (d_max, d_far) -> slots within d_max of the chunk, far-pair counts
        for src in models.values():
            key = (src.d_max_m, src.d_far_m)
            if key not in far:
                far[key] = _far_counts(d, key, miss, read_ind, r_slot, r_rssi)
        need = np.zeros(S, dtype=bool)
        for f in far.values():
            need |= f["active"]
        rows = np.flatnonzero(need)  # slots whose geometry the models need
        pos = np.full(S, -1)
        pos[rows] = np.arange(len(rows))
        alpha = pair_geometry(obs.slot_poses[rows], cand[cols], alpha_within_m=alpha_within)[1]
        for name, src in models.items():
            f = far[(src.d_max_m, src.d_far_m)]
            act = f["active"]
            ia = np.flatnonzero(act)
            # a model using the tag's height gets each candidate's above the slot's antenna
            dz = (cand[cols, 2][None, :] - obs.slot_poses[ia, 2][:, None]
                  if src.uses_height else None)
            terms = src.terms(d[ia], alpha[pos[ia]], dz)
            out = miss[:, ia] @ terms.log_miss
            if src.d_max_m is not None:  # pairs of the other slots: the far rule, by counts
                lm_band, lm_out = src.far_log_miss(np.array([0.0, np.inf]))
                lr_band, lr_out = np.log(src.far_probability(np.array([0.0, np.inf])))
                out += (lm_band * f["miss_band"] + lm_out * f["miss_out"]
                        + lr_band * f["read_band"] + lr_out * f["read_out"]
                        + src.flat_logpdf * f["read_rssi"])
            if len(r_tag):
                ra = act[r_slot]
                if ra.any():
                    loc = np.cumsum(act) - 1  # index of each slot within ia
                    out += read_ind[:, ra] @ terms.read_loglik(r_rssi[ra], loc[r_slot[ra]])
            ll[name][:, cols] = out
    result = {}
    for name, L in ll.items():
        post = L if lp is None else L + lp
        post = post - logsumexp(post, axis=1, keepdims=True)
        result[name] = TagPosteriors(str(name), obs.tag_ids, cand, post,
                                     obs.attempted.sum(axis=1).astype(np.int64),
                                     obs.read.sum(axis=1).astype(np.int64),
                                     float(local_radius_m))
    return result


def _far_counts(d, key, miss, read_ind, r_slot, r_rssi) -> dict:
    """Slots of a chunk within d_max of some candidate, and per (tag, candidate) counts of
    the other slots' misses and reads in the band d < d_far and beyond it."""
    d_max, d_far = key
    S, cc = d.shape
    T = miss.shape[0]
    if d_max is None:
        return {"active": np.ones(S, dtype=bool)}
    active = np.any(d < d_max, axis=1)
    ii = np.flatnonzero(~active)
    band = (d[ii] < d_far).astype(np.float64)  # (n_ii, Cc)
    m = miss[:, ii]
    miss_band = m @ band
    out = {"active": active, "miss_band": miss_band,
           "miss_out": m.sum(axis=1, keepdims=True) - miss_band}
    ri = ~active[r_slot] if len(r_slot) else np.zeros(0, dtype=bool)
    if ri.any():
        rb = read_ind[:, ri] @ (d[r_slot[ri]] < d_far).astype(np.float64)
        out["read_band"] = rb
        out["read_out"] = read_ind[:, ri].sum(axis=1, keepdims=True) - rb
        out["read_rssi"] = read_ind[:, ri] @ np.isfinite(r_rssi[ri]).astype(np.float64)
    else:
        out["read_band"] = out["read_out"] = np.zeros((T, cc))
        out["read_rssi"] = np.zeros((T, 1))
    return out


def _spatial_order(cand: np.ndarray, cell_m: float = 1.0) -> np.ndarray:
    """Candidate order by 1 m cells along the longer horizontal extent, so that a chunk of
    consecutive candidates is compact (its slots within d_max are few)."""
    ext = np.ptp(cand[:, :2], axis=0)
    major, minor = (0, 1) if ext[0] >= ext[1] else (1, 0)
    cells = np.floor((cand[:, :2] - cand[:, :2].min(axis=0)) / cell_m).astype(np.int64)
    return np.lexsort((cand[:, major], cells[:, minor], cells[:, major]))


def read_region_mask(obs: Observations, candidates, radius_m: float) -> np.ndarray:
    """(T, C) bool: candidates within `radius_m` of the antenna of some slot that read the tag.

    A tag never read keeps every candidate. Use as a prior
    (``np.where(mask, 0.0, -np.inf)``) or to choose which candidates to ray trace for the
    oracle (the union over tags).
    """
    cand = _check_candidates(candidates)
    out = np.ones((obs.n_tags, len(cand)), dtype=bool)
    r2 = float(radius_m) ** 2
    for t in range(obs.n_tags):
        s = np.flatnonzero(obs.read[t])
        if len(s) == 0:
            continue
        ant = obs.slot_poses[s, :3]
        hit = np.zeros(len(cand), dtype=bool)
        for i0 in range(0, len(s), 256):
            diff = cand[None, :, :] - ant[i0:i0 + 256, None, :]
            hit |= np.any(np.sum(diff * diff, axis=2) <= r2, axis=0)
        out[t] = hit
    return out


def as_tag_map(tags) -> tuple[tuple, np.ndarray]:
    """``(ids, positions (M, 3))`` of a tag map: a ``scenes.TagSet`` (``ids``,
    ``positions_m``), a mapping ``id -> (x, y, z)``, or a pair ``(ids, positions)``."""
    if hasattr(tags, "ids") and hasattr(tags, "positions_m"):
        ids, pos = tags.ids, tags.positions_m
    elif isinstance(tags, Mapping):
        ids, pos = list(tags.keys()), [tags[k] for k in tags]
    else:
        try:
            ids, pos = tags
        except (TypeError, ValueError):
            raise ValueError("tag map must be a TagSet, a mapping id -> position or a pair "
                             "(ids, positions)") from None
    ids = tuple(str(i) for i in ids)
    pos = np.asarray(pos, dtype=np.float64).reshape(len(ids), -1) if len(ids) else np.zeros((0, 3))
    if pos.shape != (len(ids), 3):
        raise ValueError(f"tag map positions must be ({len(ids)}, 3), got {pos.shape}")
    if len(set(ids)) != len(ids):
        raise ValueError("tag map has duplicate ids")
    if not np.all(np.isfinite(pos)):
        raise ValueError("tag map positions contain NaN or inf")
    return ids, pos


def tag_position_errors(post: TagPosteriors, truth, estimate: str = "map",
                        horizontal: bool = False) -> np.ndarray:
    """Distance of each tag's estimate from its true position (T,) [m].

    `truth` is a tag map (:func:`as_tag_map`) holding exactly the tags of `post`: an id of
    `post` missing from the map, or an id of the map `post` lacks, raises ValueError
    naming it. ``horizontal``: (x, y) distance only.
    """
    ids, pos = as_tag_map(truth)
    lut = dict(zip(ids, pos, strict=True))
    missing = [t for t in post.tag_ids if t not in lut]
    if missing:
        raise ValueError(f"tag id(s) {missing} have no true position in the tag map")
    extra = [t for t in ids if t not in set(post.tag_ids)]
    if extra:
        raise ValueError(f"tag map id(s) {extra} are unknown to the read log / posteriors")
    true = np.array([lut[t] for t in post.tag_ids]).reshape(-1, 3)
    diff = post.estimate(estimate) - true
    if horizontal:
        diff = diff[:, :2]
    return np.sqrt(np.sum(diff * diff, axis=1))


def localisation_summary(errors_m) -> dict:
    """Median, p90, RMSE [m], shares within 0.5 m and 1 m, and the count of position errors.

    Keys ``median_m, p90_m, rmse_m, within_0_5m, within_1m, n_tags`` (NaN when empty).
    """
    e = np.asarray(errors_m, dtype=np.float64).reshape(-1)
    if np.any(~np.isfinite(e)):
        raise ValueError("position errors contain NaN or inf")
    if len(e) == 0:
        nan = float("nan")
        return {"median_m": nan, "p90_m": nan, "rmse_m": nan, "within_0_5m": nan,
                "within_1m": nan, "n_tags": 0}
    return {"median_m": float(np.median(e)), "p90_m": float(np.percentile(e, 90)),
            "rmse_m": float(np.sqrt(np.mean(e * e))),
            "within_0_5m": float(np.mean(e <= 0.5)), "within_1m": float(np.mean(e <= 1.0)),
            "n_tags": int(len(e))}


def combine_posteriors(*posteriors: TagPosteriors, name: str) -> TagPosteriors:
    """The posterior of independent evidence: the sum of log posteriors, renormalised.

    Valid when every input has the same (uniform) prior over the same candidates and
    their evidence is conditionally independent given the position (e.g. the reads'
    phases and their read / miss outcomes with RSSI). A candidate one input excludes
    (-inf) stays excluded; if the inputs exclude every candidate of a tag between them,
    that tag falls back to the first input's posterior.
    """
    if not posteriors:
        raise ValueError("combine_posteriors needs at least one posterior")
    first = posteriors[0]
    for p in posteriors[1:]:
        if p.tag_ids != first.tag_ids:
            raise ValueError(f"combine_posteriors: tags differ ({p.source!r} has {p.tag_ids}, "
                             f"{first.source!r} has {first.tag_ids})")
        if p.candidates_m.shape != first.candidates_m.shape or not np.array_equal(
                p.candidates_m, first.candidates_m):
            raise ValueError(f"combine_posteriors: {p.source!r} and {first.source!r} are over "
                             "different candidates")
    lp = np.sum([p.log_posterior for p in posteriors], axis=0)
    z = logsumexp(lp, axis=1, keepdims=True)
    bad = ~np.isfinite(z[:, 0])
    lp = np.where(bad[:, None], first.log_posterior, lp - np.where(bad[:, None], 0.0, z))
    return TagPosteriors(str(name), first.tag_ids, first.candidates_m, lp,
                         np.maximum.reduce([p.n_attempts for p in posteriors]),
                         np.maximum.reduce([p.n_reads for p in posteriors]),
                         first.local_radius_m)
