"""Which (slot, candidate) pairs to ray trace for the oracle, so that its cost stays small.

The oracle (:class:`~pipeline.localisation.OracleLikelihood`) needs the true one-way gain
of every (antenna pose of a slot, candidate position) pair it scores. Tracing costs
about 5 ms per pair (3e4 rays) plus ~1 s per solver call, so the 33 800 tag sites at
5 cm x 321 slots of the default study (10.8 M pairs, ~15 h) are out of reach. The plan
here traces, per tag, a *window*: the candidate sites within ``window_m`` of one or more
centres, against the *informative* slots only: those that read the tag, and those whose
antenna is within ``reach_m`` of the window's centres. Every other pair stays untraced
(gain -inf: P(read) = eps): for a miss that is the same nearly-zero term for every
candidate of the window, so it does not move the posterior; reads are always traced.

All windows share one candidate array (their union) and one gain matrix (slots x union
candidates, -inf where untraced), and each tag's posterior is restricted to its window
by a log prior, so :func:`~pipeline.localisation.localise_tags` runs unchanged:

    plan = oracle_plan(obs, sites.positions_m, centres, window_m=0.5, reach_m=6.0)
    gains = <trace plan.pairs: antenna poses obs.slot_poses (true poses!), receivers
             sites[plan.site_index] with their normals; -inf elsewhere>
    post = localise_tags(obs, plan.candidates_m,
                         {"oracle": OracleLikelihood.from_reader(reader).with_gains(gains)},
                         log_prior=plan.log_prior)

Centres: the true tag positions give the oracle's local resolution (its error is at most
``window_m`` by construction: a bound on how sharply the reads pin a tag down, not on
gross ambiguity); adding each model's MAP as further centres lets the oracle weigh those
places too (each adds one window per tag).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from pipeline.localisation.observations import Observations

__all__ = ["OraclePlan", "oracle_plan"]


@dataclass(frozen=True)
class OraclePlan:
    """Candidates, pairs to trace and per-tag windows of an oracle run.

    Attributes
    ----------
    site_index : numpy.ndarray (C,), int64
        Index of each candidate in the `sites` given to :func:`oracle_plan` (for normals).
    candidates_m : numpy.ndarray (C, 3)
    pairs : numpy.ndarray (S, C), bool
        (slot, candidate) pairs to trace.
    log_prior : numpy.ndarray (T, C)
        0 inside each tag's window, -inf outside.
    """

    site_index: np.ndarray
    candidates_m: np.ndarray
    pairs: np.ndarray
    log_prior: np.ndarray

    @property
    def n_pairs(self) -> int:
        return int(self.pairs.sum())

    def cost_s(self, s_per_pair: float = 5e-3, s_per_call: float = 1.0, n_calls: int = 1) -> float:
        """Estimated tracing time [s] (defaults: 3e4 rays on the 2-core machine)."""
        return float(self.n_pairs * s_per_pair + n_calls * s_per_call)


def oracle_plan(obs: Observations, sites, centres, *, window_m: float = 0.5,
                reach_m: float = 6.0) -> OraclePlan:
    """The oracle's candidate windows and the (slot, candidate) pairs worth tracing.

    Parameters
    ----------
    obs : Observations
        The tour (T tags x S slots); its slot poses are those traced (pass the TRUE
        antenna poses to the tracer: the gains are the physics, whatever the robot
        believes; the oracle then scores them at ``obs.slot_poses``' slots).
    sites : array_like (K, 3)
        Candidate sites (e.g. ``tag_sites(scene, 0.05, None).positions_m``, every surface
        height; the study's held-out tags lie 2.5-3.5 cm from their nearest site).
    centres : array_like (T, 3) or sequence of T arrays (k_t, 3)
        Window centre(s) of each tag, in the order of ``obs.tag_ids``.
    window_m : float
        Window radius [m].
    reach_m : float
        Slots whose antenna is within this distance of a window centre are traced
        besides the tag's read slots [m] (the largest read distance of the tour is a
        safe choice; beyond it the tag is missed at every candidate alike).

    Returns
    -------
    OraclePlan
    """
    s = np.asarray(getattr(sites, "positions_m", sites), dtype=np.float64)
    if s.ndim != 2 or s.shape[1] != 3 or len(s) == 0:
        raise ValueError(f"sites must be a non-empty (K, 3) array, got shape {s.shape}")
    if isinstance(centres, np.ndarray) and centres.ndim == 2:
        cs = [centres[i:i + 1] for i in range(len(centres))]
    else:
        cs = [np.asarray(c, dtype=np.float64).reshape(-1, 3) for c in centres]
    if len(cs) != obs.n_tags:
        raise ValueError(f"centres: {len(cs)} entries for {obs.n_tags} tags")
    if not (window_m > 0 and reach_m > 0):
        raise ValueError("window_m and reach_m must be > 0")
    ant = obs.slot_poses[:, :3]
    members, slot_sets = [], []
    for t, c in enumerate(cs):
        d2 = np.sum((s[None, :, :] - c[:, None, :]) ** 2, axis=2)  # (k_t, K)
        idx = np.flatnonzero(np.any(d2 <= window_m ** 2, axis=0))
        near = np.any(np.sum((ant[:, None, :] - c[None, :, :]) ** 2, axis=2) <= reach_m ** 2,
                      axis=1)
        members.append(idx)
        slot_sets.append(near | obs.read[t])
    site_index = np.unique(np.concatenate(members)) if members else np.zeros(0, np.int64)
    col = {int(k): j for j, k in enumerate(site_index)}
    C = len(site_index)
    pairs = np.zeros((obs.n_slots, C), dtype=bool)
    log_prior = np.full((obs.n_tags, C), -np.inf)
    for t, (idx, slots) in enumerate(zip(members, slot_sets, strict=True)):
        if len(idx) == 0:
            raise ValueError(f"tag {obs.tag_ids[t]!r}: no site within {window_m} m of its "
                             "window centre(s)")
        j = np.array([col[int(k)] for k in idx])
        pairs[np.ix_(slots, j)] = True
        log_prior[t, j] = 0.0
    return OraclePlan(site_index.astype(np.int64), s[site_index], pairs, log_prior)
