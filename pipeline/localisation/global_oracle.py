"""The oracle over every candidate: a coarse-to-fine search with the ray-traced likelihood.

The oracle scores a candidate tag position by the reader's own likelihood of the tour's
reads given the true one-way gains there (:class:`~.oracle_likelihood.OracleLikelihood`). Tracing
the gain of every (slot, candidate) pair of a study is out of reach (the default study:
321 slots x 33 800 candidates at 5 cm, ~10^7 links, hours on two cores), so the search
goes coarse to fine, and never looks at the true tag position:

1. **Coarse** (:func:`coarse_posteriors`): the candidates are grouped into cells of
   ``anchor_spacing_m`` per surface (:func:`propagation.anchored.anchor_groups`); the
   *local mean* gain (paths summed in power, patterns applied) from every slot within
   ``reach_m`` to every cell's anchor comes from the specular model (line of sight and
   reflections of order <= ``specular_order`` over the large planes, Sionna's image
   method, no ray sampling: ~0.2 ms per link). The reader's likelihood given a local
   mean (:class:`~.fading.FadedLikelihood`: the small-scale fading the local mean
   averages out, Rician with ``coarse_k_factor``, Rayleigh by default, entering the RSSI
   twice) with its RSSI spread widened by ``coarse_sigma_db`` (the model's error: it
   misses transmissions and small surfaces, p95 10 dB against the full trace) gives a
   posterior over anchors.
2. **Fine**: its ``n_modes`` best anchors, at least ``mode_separation_m`` apart, and any
   ``extra_centres`` (e.g. the learned model's estimate) are traced with the study's own
   tracer (cached) from the slots that read the tag or whose coarse gain is within
   ``margin_db`` of the read threshold; every candidate within ``window_m`` of a centre
   (same surface orientation) gets its gain carried from the centre's paths by their
   unfolded geometry (:mod:`propagation.anchored`: p50 0.15-1 dB at 5-20 cm). The
   oracle's likelihood with its RSSI spread widened by ``fine_sigma_db`` scores them; the
   MAP over all windows is the oracle's estimate.

The search never uses the true tag positions; the one input that depends on them is a
Gen2 reader's per-slot miss probability (``miss_probability``, counting the tags whose
true links close in a slot, the localised one included), which is 0 at the default
dwells (a lone tag is always singulated up to 45 tags in the field).

With the true tag positions given, :func:`global_oracle` also reports per tag whether the
exactly traced truth scores better than the estimate (``truth_preferred``): a search
that missed the truth's basin, as opposed to reads that genuinely prefer another place.
"""

from __future__ import annotations

import copy
from dataclasses import dataclass

import numpy as np

from pipeline.localisation.fading import FadedLikelihood, FadingModel
from pipeline.localisation.observations import Observations
from pipeline.localisation.oracle_likelihood import OracleLikelihood
from pipeline.localisation.tags import TagPosteriors, localise_tags
from propagation.anchored import (
    anchor_groups,
    anchored_gains_db,
    specular_model_paths,
    trace_anchor_paths,
    window_gains_db,
)

__all__ = ["GlobalOracle", "OracleSearch", "coarse_posteriors", "global_oracle", "widened"]


@dataclass(frozen=True)
class OracleSearch:
    """Settings of the oracle's coarse-to-fine search (see the module doc)."""

    anchor_spacing_m: float = 0.4
    """Cell size of the coarse anchors on each surface [m]."""
    specular_order: int = 2
    """Highest reflection order of the coarse specular model."""
    reach_m: float = 16.0
    """Coarse links: slots whose antenna is within this distance of an anchor [m]."""
    coarse_sigma_db: float = 3.0
    """RSSI spread added to the reader's in the coarse pass (the model's error) [dB]."""
    coarse_k_factor: float = 0.0
    """Rician K of the fading about the coarse local mean (0: Rayleigh, :mod:`.fading`)."""
    n_modes: int = 5
    """Coarse modes traced per tag."""
    mode_separation_m: float = 0.5
    """Smallest distance between two coarse modes of a tag [m]."""
    window_m: float = 0.4
    """Radius of the candidates carried from each traced centre [m]."""
    fine_sigma_db: float = 3.0
    """RSSI spread added to the reader's in the fine pass (carrying error) [dB]."""
    margin_db: float = 20.0
    """Fine links: read slots, and slots whose coarse gain is within this of the threshold [dB]."""
    refine_rounds: int = 2
    """Rounds that trace each tag's estimate as a further centre while it lies more than
    ``refine_step_m`` from every traced centre."""
    refine_step_m: float = 0.05
    """A fine estimate this close to a traced centre ends the refinement [m]."""

    def __post_init__(self) -> None:
        for name in ("anchor_spacing_m", "reach_m", "mode_separation_m", "window_m"):
            if not float(getattr(self, name)) > 0:
                raise ValueError(f"OracleSearch.{name} must be > 0, got {getattr(self, name)!r}")
        for name in ("coarse_sigma_db", "fine_sigma_db", "margin_db", "coarse_k_factor"):
            if not float(getattr(self, name)) >= 0:
                raise ValueError(f"OracleSearch.{name} must be >= 0, got {getattr(self, name)!r}")
        if int(self.n_modes) < 1 or not 1 <= int(self.specular_order) <= 3:
            raise ValueError("OracleSearch: need n_modes >= 1 and 1 <= specular_order <= 3")


@dataclass(frozen=True)
class GlobalOracle:
    """Result of :func:`global_oracle`.

    Attributes
    ----------
    posteriors : TagPosteriors
        The fine posterior (source ``"oracle"``): each tag over its own windows (-inf on
        the other tags' candidates).
    coarse : TagPosteriors
        The coarse posterior over the anchors (source ``"oracle_coarse"``).
    centres_m : tuple of numpy.ndarray
        Per tag, the traced window centres (k_t, 3) [m].
    n_model_links, n_traced_links : int
        Links of the specular model (coarse) and of the study's tracer (fine centres).
    truth_preferred : numpy.ndarray (T,), bool or None
        Per tag, the exactly traced truth scores higher than the estimate (None without
        ``truth_m``).
    """

    posteriors: TagPosteriors
    coarse: TagPosteriors
    centres_m: tuple
    n_model_links: int
    n_traced_links: int
    truth_preferred: np.ndarray | None


def widened(oracle: OracleLikelihood, extra_sigma_db: float) -> OracleLikelihood:
    """A copy of ``oracle`` whose RSSI spread and link-closure width include
    ``extra_sigma_db`` in quadrature (a gain known only to that accuracy)."""
    out = copy.copy(oracle)
    out.sigma_db = float(np.hypot(oracle.sigma_db, extra_sigma_db))
    out.closure_sigma_db = float(np.hypot(oracle.closure_sigma_db, extra_sigma_db))
    return out


def _unique_positions(poses) -> tuple[np.ndarray, np.ndarray]:
    uniq, inv = np.unique(np.asarray(poses, float)[:, :3], axis=0, return_inverse=True)
    return uniq, inv.reshape(-1)


def coarse_posteriors(obs: Observations, true_poses, sites, scene, oracle: OracleLikelihood, *,
                      search: OracleSearch, frequency_hz: float, pattern_kw: dict,
                      miss_probability=None, cache_dir=None
                      ) -> tuple[TagPosteriors, np.ndarray, np.ndarray, np.ndarray, int]:
    """The coarse pass: posterior over anchors from the specular model's local means.

    Returns
    -------
    posteriors : TagPosteriors
        Over the anchors (source ``"oracle_coarse"``).
    anchors : numpy.ndarray (a,), int64
        Site index of each anchor.
    member_anchor : numpy.ndarray (K,), int64
        Per site, its anchor (position in ``anchors``; same surface orientation).
    gain_db : numpy.ndarray (S, a)
        Coarse local-mean gains [dB] (-inf beyond ``reach_m``).
    n_links : int
    """
    pos, nrm = np.asarray(sites.positions_m, float), np.asarray(sites.normals, float)
    anchors, member_anchor = anchor_groups(pos, nrm, search.anchor_spacing_m)
    a_pos = pos[anchors]
    uniq, inv = _unique_positions(true_poses)
    need = np.linalg.norm(uniq[:, None, :] - a_pos[None], axis=2) <= search.reach_m
    paths = specular_model_paths(scene, uniq, a_pos, need, frequency_hz, search.specular_order,
                                 cache_dir=cache_dir)
    s, a = np.nonzero(need[inv])
    gain = np.full((len(inv), len(anchors)), -np.inf)
    if len(s):
        gain[s, a] = anchored_gains_db(paths, inv[s], a_pos, a, a_pos[a], nrm[anchors][a],
                                       np.asarray(true_poses, float)[s], frequency_hz,
                                       incoherent=True, **pattern_kw)
    coarse = FadedLikelihood(oracle, FadingModel(search.coarse_k_factor),
                             extra_sigma_db=search.coarse_sigma_db).with_gains(gain, miss_probability)
    post = localise_tags(obs, a_pos, {"oracle_coarse": coarse})["oracle_coarse"]
    return post, anchors, member_anchor, gain, int(len(s))


def _modes(log_post: np.ndarray, pos: np.ndarray, n: int, sep_m: float) -> np.ndarray:
    """Indices of the ``n`` best entries at least ``sep_m`` apart (greedy)."""
    out: list[int] = []
    for i in np.argsort(-log_post, kind="stable"):
        if not np.isfinite(log_post[i]) and out:
            break
        if all(np.sum((pos[i] - pos[j]) ** 2) >= sep_m ** 2 for j in out):
            out.append(int(i))
            if len(out) == n:
                break
    return np.array(out, np.int64)


def global_oracle(obs: Observations, true_poses, sites, scene, oracle: OracleLikelihood, *,
                  search: OracleSearch | None = None, frequency_hz: float, trace,
                  pattern_kw: dict, cache_dir=None, miss_probability=None, extra_centres=None,
                  truth_m=None, truth_normals=None) -> GlobalOracle:
    """Localise every tag of ``obs`` with the oracle over all ``sites`` (coarse to fine).

    Parameters
    ----------
    obs : Observations
        The tour's outcomes (T tags x S slots).
    true_poses : array_like (S, 6)
        The slots' TRUE antenna poses: the gains are the physics, whatever the robot
        believes.
    sites : scenes.tagsites.TagSites
        Candidate tag positions with their normals.
    scene : scenes.Scene
    oracle : OracleLikelihood
        The reader's likelihood (budget, noise, misses).
    search : OracleSearch, optional
    frequency_hz : float
    trace : propagation.TraceOptions
        The study tracer's options (:func:`propagation.anchored.trace_anchor_paths`).
    pattern_kw : dict
        ``reader_pattern``, ``reader_polarization``, ``tag_pattern``.
    cache_dir : path, optional
        The propagation cache.
    miss_probability : array_like (S,), optional
        Per-slot miss probability of a closed link (Gen2); default the oracle's constant.
    extra_centres : array_like (T, 3), optional
        Further window centres per tag (snapped to the nearest site).
    truth_m, truth_normals : array_like (T, 3), optional
        True tag positions and their surface normals, for the ``truth_preferred``
        diagnostic only (the search never sees them).

    Returns
    -------
    GlobalOracle
    """
    search = search or OracleSearch()
    if obs.n_tags == 0 or len(sites.positions_m) == 0:
        raise ValueError("global_oracle: no tags or no candidate sites to localise over")
    pos, nrm = np.asarray(sites.positions_m, float), np.asarray(sites.normals, float)
    poses = np.asarray(true_poses, float)
    if poses.shape != (obs.n_slots, 6):
        raise ValueError(f"true_poses must be ({obs.n_slots}, 6), got {poses.shape}")
    coarse, anchors, member_anchor, coarse_gain, n_model = coarse_posteriors(
        obs, poses, sites, scene, oracle, search=search, frequency_hz=frequency_hz,
        pattern_kw=pattern_kw, miss_probability=miss_probability, cache_dir=cache_dir)
    a_pos = pos[anchors]
    threshold_db = oracle.budget.min_gain_db()

    # window centres per tag: coarse modes (anchor sites) and the extra centres (snapped)
    centres_of = []
    for t in range(obs.n_tags):
        idx = [int(i) for i in anchors[_modes(coarse.log_posterior[t], a_pos, search.n_modes,
                                              search.mode_separation_m)]]
        if extra_centres is not None:
            e = np.asarray(extra_centres, float)[t]
            j = int(np.argmin(np.sum((pos - e) ** 2, axis=1)))
            if all(np.sum((pos[j] - pos[i]) ** 2) > (search.window_m / 2) ** 2 for i in idx):
                idx.append(j)
        centres_of.append(idx)
    uniq, inv = _unique_positions(poses)
    fine = widened(oracle, search.fine_sigma_db)
    blocks: list = [None] * obs.n_tags
    changed = np.ones(obs.n_tags, bool)  # tags whose windows are (re)computed this round
    window_gains: dict = {}  # a centre's window gains, reused by later rounds (see below)
    for rnd in range(1 + int(search.refine_rounds)):
        centres = np.array([c for cs in centres_of for c in cs], np.int64)
        owner = np.repeat(np.arange(obs.n_tags), [len(cs) for cs in centres_of])
        # fine links: the owner's read slots and the slots whose coarse gain at one of
        # its centres' cells comes within margin_db of the threshold; every centre of a
        # tag on the same slots, so that its windows are scored alike (an unscored slot
        # would count as a certain miss, the best score a missed slot can give)
        near = coarse_gain[:, member_anchor[centres]] >= threshold_db - search.margin_db  # (S, F)
        slots_of = np.zeros((obs.n_tags, obs.n_slots), bool)
        np.logical_or.at(slots_of, owner, near.T)
        slots_of |= obs.read
        want = slots_of[owner].T
        need = np.zeros((len(uniq), len(centres)), bool)
        np.logical_or.at(need, inv, want)
        paths = trace_anchor_paths(scene, uniq, pos[centres], need, frequency_hz=frequency_hz,
                                   cache_dir=cache_dir, options=trace)
        for t in np.flatnonzero(changed):
            blocks[t] = _window_posterior(obs, t, np.flatnonzero(owner == t), centres, want, paths,
                                          inv, pos, nrm, poses, fine, search.window_m, frequency_hz,
                                          pattern_kw, miss_probability, window_gains)
        changed[:] = False
        if rnd == int(search.refine_rounds):
            break
        for t, (member, lp) in enumerate(blocks):
            best = int(member[np.argmax(lp.log_posterior[0])])
            step2 = min(np.sum((pos[best] - pos[c]) ** 2) for c in centres_of[t])
            if step2 > search.refine_step_m ** 2 and obs.read[t].any():  # carried: trace it
                centres_of[t].append(best)
                changed[t] = True
        if not changed.any():
            break
    cand = np.concatenate([b[0] for b in blocks])
    log_post = np.full((obs.n_tags, len(cand)), -np.inf)
    at = 0
    for t, (_, lp) in enumerate(blocks):
        log_post[t, at:at + lp.log_posterior.shape[1]] = lp.log_posterior[0]
        at += lp.log_posterior.shape[1]
    post = TagPosteriors("oracle", obs.tag_ids, pos[cand], log_post,
                         np.array([b[1].n_attempts[0] for b in blocks]),
                         np.array([b[1].n_reads[0] for b in blocks]))
    preferred = None
    if truth_m is not None:
        preferred = _truth_preferred(obs, poses, post, slots_of, truth_m, truth_normals, sites,
                                     scene, fine, frequency_hz, trace, pattern_kw, cache_dir,
                                     miss_probability)
    return GlobalOracle(post, coarse, tuple(pos[np.array(cs)] for cs in centres_of),
                        n_model, int(need[inv].sum()), preferred)


def _window_posterior(obs, t, mine, centres, need, paths, inv, pos, nrm, poses, fine, window_m,
                      frequency_hz, pattern_kw, miss_probability, window_gains: dict):
    """Tag ``t``'s fine posterior over the sites within ``window_m`` of its centres
    (``centres[mine]``, same orientation), each carried from its nearest centre;
    ``need`` (S, F): the (slot, centre) pairs scored; ``inv``: each slot's path set.

    ``window_gains`` holds, per (centre site, tag axis, scored slots), the gains of every
    site of that orientation within ``window_m`` of the centre: a refinement round that
    adds a centre to a tag only computes the new centre's window (the other windows'
    members are the same sites, scored on the same slots, with the same numbers).

    Returns (member site indices, TagPosteriors of one tag)."""
    c = pos[centres[mine]]
    d2 = np.sum((pos[:, None, :] - c[None]) ** 2, axis=2)  # (K, k_t)
    d2 = np.where(nrm @ nrm[centres[mine]].T > 0.9, d2, np.inf)
    member = np.flatnonzero(np.min(d2, axis=1) <= window_m ** 2)
    f = mine[np.argmin(d2[member], axis=1)]  # each member's centre (fine anchor)
    gain = np.full((obs.n_slots, len(member)), -np.inf)
    axis = np.round(nrm[member], 6)
    # one dense block per (centre, tag axis): its scored slots x its members
    _, block = np.unique(np.column_stack([f, axis]), axis=0, return_inverse=True)
    for b in range(int(block.max()) + 1 if len(block) else 0):
        m = np.flatnonzero(block.reshape(-1) == b)
        centre = int(centres[f[m[0]]])
        s = np.flatnonzero(need[:, f[m[0]]])
        if not len(s):
            continue
        key = (centre, axis[m[0]].tobytes(), s.tobytes())
        if key not in window_gains:
            same = np.all(np.round(nrm, 6) == axis[m[0]], axis=1)
            sites = np.flatnonzero(same & (np.sum((pos - pos[centre]) ** 2, axis=1) <= window_m ** 2))
            window_gains[key] = (sites, window_gains_db(paths, inv[s], poses[s], pos[centre], pos[sites],
                                                        nrm[sites[0]], frequency_hz, **pattern_kw))
        sites, g = window_gains[key]
        col = np.minimum(np.searchsorted(sites, member[m]), len(sites) - 1)
        if not np.array_equal(sites[col], member[m]):  # a member's centre is within window_m
            raise RuntimeError("global_oracle: a window member is missing from its centre's window")
        gain[np.ix_(s, m)] = g[:, col]
    lp = localise_tags(obs.select([obs.tag_ids[t]]), pos[member],
                       {"oracle": fine.with_gains(gain, miss_probability)})["oracle"]
    return member, lp


def _truth_preferred(obs, poses, post, slots_of, truth_m, truth_normals, sites, scene, fine,
                     frequency_hz, trace, pattern_kw, cache_dir, miss_probability) -> np.ndarray:
    """Per tag: the truth scores higher than the estimate, both traced exactly on the
    tag's fine slots (``slots_of`` (T, S)) and scored with the fine likelihood."""
    truth = np.asarray(truth_m, float).reshape(obs.n_tags, 3)
    est_site = np.argmin(np.sum((np.asarray(sites.positions_m)[None] - post.map_m[:, None]) ** 2,
                                axis=2), axis=1)
    points = np.vstack([truth, post.map_m])  # T truths, then T estimates
    normals = np.vstack([np.asarray(truth_normals, float).reshape(obs.n_tags, 3),
                         np.asarray(sites.normals, float)[est_site]])
    uniq, inv = _unique_positions(poses)
    want = np.vstack([slots_of, slots_of]).T  # (S, 2T)
    targets, col = np.unique(points, axis=0, return_inverse=True)  # an estimate may be the truth
    col = col.reshape(-1)
    need = np.zeros((len(uniq), len(targets)), bool)
    for j in range(len(points)):
        need[inv[want[:, j]], col[j]] = True
    paths = trace_anchor_paths(scene, uniq, targets, need, frequency_hz=frequency_hz,
                               cache_dir=cache_dir, options=trace)
    s, c = np.nonzero(want)
    gain = np.full((obs.n_slots, 2 * obs.n_tags), -np.inf)
    gain[s, c] = anchored_gains_db(paths, inv[s], targets, col[c], points[c], normals[c], poses[s],
                                   frequency_hz, **pattern_kw)
    out = np.zeros(obs.n_tags, bool)
    for k in range(obs.n_tags):
        g = gain[:, [obs.n_tags + k, k]]  # estimate, truth
        lp = localise_tags(obs.select([obs.tag_ids[k]]), points[[obs.n_tags + k, k]],
                           {"o": fine.with_gains(g, miss_probability)})["o"]
        out[k] = lp.log_posterior[0, 1] > lp.log_posterior[0, 0]
    return out
