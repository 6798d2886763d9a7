"""The downstream benchmark of a study: localise held-out tags, then the robot, per model.

Chapter outlook (Cicirelli, Milella & Di Paola 2011, Sec. 6): "automatic localization of
tags displaced in unknown positions and, successively, absolute robot localization" with
the learned sensor model. Here every sensor model of the study and the ray-traced
oracle answer both questions on the evaluation tour's reads of the held-out tags:

- **tag localisation**: each held-out tag's posterior over candidate sites on the
  scene's surfaces (:func:`~.tags.localise_tags`), from the tour's read / not-read
  outcomes and RSSI with the MCL antenna poses; the MAP estimate's 3-D error;
- **phase**: where the read log has the reads' backscatter phases, the synthetic-aperture
  estimator (:func:`~.phase.localise_tags_phase`) alone (``phase``) and times the learned
  model's read / RSSI likelihood (``phase_anfis``, :func:`phase_posteriors`);
- **robot localisation**: an RFID-only particle filter (odometry and reads, no laser)
  with the held-out tags as the known map, from an unknown start and once more after a
  kidnapping (:func:`~.robot.run_rfid_mcl`).

The oracle's likelihood needs the true gain of every (slot, candidate) pair, which only
the ray tracer gives; tracing every candidate is out of reach (about 10^7 pairs), so the
oracle searches coarse to fine (:mod:`~.global_oracle`): a specular image-method model
over the large planes finds each tag's likely regions, the study's tracer scores windows
around them, never looking at the truth. The robot filter needs gains at every particle:
its oracle is the traced local-mean gain field on a grid of robot poses
(:mod:`~.robot_oracle`).
"""

from __future__ import annotations

import numpy as np
import pandas as pd

from pipeline.localisation.likelihood import ModelLikelihood, fit_far_detection, rssi_residual_std
from pipeline.localisation.observations import Observations
from pipeline.localisation.phase import (
    PhaseColumnsMissing,
    combine_posteriors,
    localise_tags_phase,
    phase_reads_from_table,
)
from pipeline.localisation.robot import RfidMCLConfig, filter_metrics, kidnap_index, run_rfid_mcl
from pipeline.localisation.tags import localisation_summary, tag_position_errors
from pipeline.parallel import map_forked

__all__ = [
    "DetectionOnly",
    "RobotRuns",
    "model_sources",
    "phase_posteriors",
    "robot_localisation",
    "tag_localisation_scores",
]


class DetectionOnly:
    """A sensor model's detection part alone (``predicts_rssi`` False): Hähnel et al.
    2004 localise with detection counts only."""

    predicts_rssi = False

    def __init__(self, model):
        self._m = model
        self.rssi_range_dbm = model.rssi_range_dbm

    def fT(self, d, alpha):  # noqa: N802 - the chapter's name
        return self._m.fT(d, alpha)

    def fs_dbm(self, d, alpha):
        return np.full(np.broadcast(np.asarray(d), np.asarray(alpha)).shape, np.nan)

    def fs(self, d, alpha):
        return np.ones(np.broadcast(np.asarray(d), np.asarray(alpha)).shape)

    def rho(self, d, alpha):
        return self.fT(d, alpha)


def model_sources(models: dict, train_reads: pd.DataFrame, d_max_m: float) -> dict:
    """A :class:`~.likelihood.ModelLikelihood` per model, fitted on TRAINING reads only.

    The RSSI spread of a model without its own (``rssi_sigma_db`` / ``log_likelihood``)
    is its residual std on the training reads; beyond ``d_max_m`` every model uses the
    same far rule (:func:`~.likelihood.fit_far_detection` on the training reads).
    """
    p_far, d_far = fit_far_detection(train_reads, d_max_m)
    out = {}
    for name, m in models.items():
        needs_sigma = (getattr(m, "predicts_rssi", True)
                       and not callable(getattr(m, "rssi_sigma_db", None))
                       and not callable(getattr(m, "log_likelihood", None)))
        sigma = rssi_residual_std(m, train_reads, d_max_m) if needs_sigma else None
        out[name] = ModelLikelihood(m, sigma_rssi_db=sigma, d_max_m=d_max_m, p_far=p_far,
                                    d_far_m=d_far, name=name)
    return out


def phase_posteriors(reads: pd.DataFrame, tag_ids, candidates, *, reach_m: float | None,
                     combine_with=None, combined_name: str = "phase_anfis",
                     **kwargs) -> tuple[dict, dict]:
    """The phase estimator's posteriors of the tags of a read table, or why there are none.

    Parameters
    ----------
    reads : pandas.DataFrame
        ``eval_reads.parquet`` (MCL antenna poses ``est_ant_*``), with ``frequency_hz`` and
        ``phase_rad`` where the reader simulation wrote them.
    tag_ids : sequence of str
        The tags, in the order of the other sources' posteriors.
    candidates : array_like (C, 3) or TagSites
    reach_m : float or None
        The reader's range [m] (:func:`~.phase.localise_tags_phase`).
    combine_with : TagPosteriors, optional
        A read / RSSI model's posteriors over the same tags and candidates (uniform
        prior): also returns their product with the phase posterior as
        `combined_name` (:func:`~.tags.combine_posteriors`). Why: the range to a
        straight track, all the phase measures, is the same on a circle about it, so
        phase alone can take a tag for a point on the opposite wall; which antenna read
        it and how strongly tell the walls apart, and the two are independent evidence.
    **kwargs
        Passed to :func:`~.phase.localise_tags_phase`.

    Returns
    -------
    posteriors : dict of str -> TagPosteriors
        ``{"phase": ..., combined_name: ...}``; empty when the table has no phases.
    info : dict
        ``run`` (bool); ``reason`` when not run; else the phase reads used, tags without
        any, the concentration kappa, ``reach_m``.
    """

    try:
        rd = phase_reads_from_table(reads, "est", tag_ids=list(tag_ids))
    except PhaseColumnsMissing as exc:
        return {}, {"run": False, "reason": str(exc)}
    post = localise_tags_phase(rd, candidates, reach_m=reach_m, **kwargs)
    out = {"phase": post}
    if combine_with is not None:
        out[combined_name] = combine_posteriors(post, combine_with, name=combined_name)
    info = {"run": True, "n_reads_with_phase": int(rd.n_reads.sum()),
            "tags_without_phase": int(np.sum(rd.n_reads == 0)),
            "kappa": round(float(post.kappa), 3),
            "reach_m": None if reach_m is None else round(float(reach_m), 3)}
    return out, info


def tag_localisation_scores(posteriors: dict, tag_map) -> dict:
    """Per source: the 3-D MAP error summary (``median_m``, ``p90_m``, ``rmse_m``,
    ``within_0_5m``, ``within_1m``, ``n_tags``) plus ``horizontal_median_m`` (a model of
    (d, alpha) cannot tell heights mirrored about the antenna's) and per-tag errors."""
    out = {}
    for name, post in posteriors.items():
        e3 = tag_position_errors(post, tag_map, estimate="map")
        e2 = tag_position_errors(post, tag_map, estimate="map", horizontal=True)
        s = localisation_summary(e3)
        s["horizontal_median_m"] = float(np.median(e2)) if len(e2) else float("nan")
        s["per_tag_m"] = {str(t): float(v) for t, v in zip(post.tag_ids, e3, strict=True)}
        out[name] = s
    return out


class RobotRuns:
    """The RFID-only robot filter runs of :func:`robot_localisation`, one task each.

    Built from the same arguments as :func:`robot_localisation` (less ``workers``), so
    that a caller can run the filter runs where it likes, e.g. in one pool of forked
    processes with other independent work: ``len(runs)`` tasks, :meth:`run` computes
    one, :meth:`scores` turns the results of every task, in task order, into the
    scores :func:`robot_localisation` returns. Run k has its own random stream, so the
    scores do not depend on where or in which order the runs are computed, and it is the
    *same* stream for every model (common random numbers: the same initial particles and
    the same draws as far as the filters agree), so that two models' run k are a pair and
    their difference is not swamped by the filters' own sampling noise.
    """

    def __init__(self, sources: dict, obs: Observations, tag_map, eval_poses: pd.DataFrame,
                 mounts, free_space, rng: np.random.Generator, *,
                 config: RfidMCLConfig | None = None, n_runs: int = 1) -> None:
        if int(n_runs) < 1:
            raise ValueError(f"n_runs must be >= 1, got {n_runs!r}")
        self.sources, self.obs, self.tag_map = sources, obs, tag_map
        self.mounts, self.free_space, self.config = mounts, free_space, config
        self.t_s = eval_poses["time_s"].to_numpy(float)
        self.odometry = eval_poses[["odom_x_m", "odom_y_m", "odom_theta_rad"]].to_numpy(float)
        self.true = eval_poses[["true_x_m", "true_y_m", "true_theta_rad"]].to_numpy(float)
        t, true = self.t_s, self.true
        self.kidnap_time_s = float(t[0] + 0.5 * (t[-1] - t[0]))
        # the filter is moved 3 m along the corridor's long axis, towards its middle
        mid = np.asarray(true[:, :2].mean(axis=0))
        k = int(np.searchsorted(t, self.kidnap_time_s))
        p = true[min(k, len(true) - 1), :2]
        axis = 0 if np.ptp(true[:, 0]) >= np.ptp(true[:, 1]) else 1
        self.kidnap_offset = np.zeros(3)
        self.kidnap_offset[axis] = 3.0 if p[axis] < mid[axis] else -3.0
        # one seed per run, shared by the models: a fresh generator per job from it
        seeds = [g.bit_generator.seed_seq for g in rng.spawn(int(n_runs))]
        self.jobs = [(name, seeds[k]) for name in sources for k in range(int(n_runs))]

    def __len__(self) -> int:
        return len(self.jobs)

    def run(self, i: int):
        """Filter run `i` (:func:`~.robot.run_rfid_mcl`): model ``jobs[i][0]``, its own stream."""
        name, seed = self.jobs[i]
        return run_rfid_mcl(self.sources[name], self.obs, self.tag_map, self.odometry, self.t_s,
                            self.mounts, self.free_space, np.random.default_rng(seed),
                            config=self.config,
                            initial_pose=None, kidnap_time_s=self.kidnap_time_s,
                            kidnap_offset=self.kidnap_offset)

    def scores(self, results: list) -> dict:
        """The scores of :func:`robot_localisation` from every run's result, in task order."""
        if len(results) != len(self.jobs):
            raise ValueError(f"expected {len(self.jobs)} filter results, got {len(results)}")
        t, true, t_kid = self.t_s, self.true, self.kidnap_time_s
        out = {}
        for name in self.sources:
            runs, traces = [], []
            for (job_name, _), res in zip(self.jobs, results, strict=True):
                if job_name != name:
                    continue
                true_at = np.column_stack([np.interp(res.t_s, t, true[:, j]) for j in range(2)]
                                          + [np.interp(res.t_s, t, np.unwrap(true[:, 2]))])
                runs.append(filter_metrics(res.t_s, res.est_poses, true_at, kidnap_time_s=t_kid))
                err = np.hypot(res.est_poses[:, 0] - true_at[:, 0],
                               res.est_poses[:, 1] - true_at[:, 1])
                traces.append({"t_s": np.round(np.asarray(res.t_s, float) - t[0], 3).tolist(),
                               "error_m": np.round(err, 4).tolist(),
                               "after_kidnap": (np.arange(len(err))
                                                >= kidnap_index(res.t_s, t_kid)).tolist()})
            m = _median_over_runs(runs)
            pooled = np.concatenate([x["error_m"] for x in traces])
            after = np.concatenate([x["after_kidnap"] for x in traces])
            # one definition: the median over every step of every run (module robot doc)
            m["median_m"] = float(np.median(pooled))
            m["p90_m"] = float(np.percentile(pooled, 90))
            m["median_before_kidnap_m"] = float(np.median(pooled[~after])) if (~after).any() else None
            m["median_after_kidnap_m"] = float(np.median(pooled[after])) if after.any() else None
            fig = traces[int(np.argmin([abs(x["median_m"] - float(np.median(m["median_m_runs"])))
                                        for x in runs]))]
            m.update({"t_s": fig["t_s"], "error_m": fig["error_m"]})
            m["runs_steps"] = [{**x, "converge_s": r["converge_s"], "recover_s": r.get("recover_s")}
                               for x, r in zip(traces, runs, strict=True)]
            m["kidnap_s"] = t_kid - t[0]
            out[name] = m
        return out


def robot_localisation(sources: dict, obs: Observations, tag_map, eval_poses: pd.DataFrame,
                       mounts, free_space, rng: np.random.Generator, *,
                       config: RfidMCLConfig | None = None, n_runs: int = 1,
                       workers: int | None = 1) -> dict:
    """RFID-only global localisation with a kidnapping halfway, per model.

    One particle-filter run is one draw: its error and convergence times move with the
    particles' random stream by more than the models differ (ANFIS median 0.52 vs 0.86 m
    in two runs of one study). Each model therefore runs ``n_runs`` times on independent
    streams. ``median_m`` / ``p90_m`` are over every step of every run (one definition,
    whether a run converged or not; :func:`~.robot.filter_metrics`), and
    ``median_before_kidnap_m`` / ``median_after_kidnap_m`` over the steps before / from
    the kidnapping; convergence and recovery are summarised over runs
    (``converged_runs``, ``recovered_runs``; ``converge_s`` / ``recover_s`` the median
    over runs, a run that never converges or recovers counting as infinitely late, so
    NaN when at least half never do; ``converged`` means that most runs converged), with
    each run's own all-step median (``median_m_runs``, ``_min``, ``_max``). The error
    trace (for the figure) is that of the run whose median is the median run's; every
    run's steps are in ``runs_steps``.

    Parameters
    ----------
    sources : dict of str -> ModelLikelihood
    obs : Observations
        The evaluation tour's outcomes (slot times, antennas, reads).
    tag_map : TagSet
        The held-out tags' true positions (the known map).
    eval_poses : pandas.DataFrame
        ``eval_poses.parquet``: time_s, odom_x_m/_y_m/_theta_rad, true_x_m/_y_m/_theta_rad.
    mounts : sequence of AntennaMount
    free_space : see :func:`~.robot.run_rfid_mcl`
    rng : numpy.random.Generator
        Split into one stream per model, then one per run.
    config : RfidMCLConfig, optional
    n_runs : int
        Filter runs per model (independent particle streams).
    workers : int or None
        Filter runs side by side in forked processes (:func:`pipeline.parallel.map_forked`;
        None: one per CPU). The scores do not depend on it: every run has its own stream.

    Returns
    -------
    dict
        Per model ``median_m``, ``p90_m``, ``median_before_kidnap_m``,
        ``median_after_kidnap_m`` (all runs' steps pooled), ``converge_s``, ``converged``,
        ``recover_s``, ``converged_runs``, ``recovered_runs``, ``heading_median_deg``,
        ``n_runs``, ``median_m_runs`` / ``_min`` / ``_max``, the median run's ``error_m``
        / ``t_s`` lists for the figure, and ``runs_steps`` (per run: ``t_s``,
        ``error_m``, ``after_kidnap``, ``converge_s``, ``recover_s``).
    """
    runs = RobotRuns(sources, obs, tag_map, eval_poses, mounts, free_space, rng,
                     config=config, n_runs=n_runs)
    return runs.scores(map_forked(runs.run, len(runs), workers))


def _median_over_runs(runs: list) -> dict:
    """Per filter run statistics summarised over runs: ``converged_runs`` /
    ``recovered_runs`` counts; ``converge_s`` / ``recover_s`` medians over runs, a run
    that never converges or recovers counting as infinitely late (NaN when at least half
    never do); ``heading_median_deg`` median of the runs'; ``median_m_runs`` each run's
    median over all its steps, with their min and max."""
    out = {"n_runs": len(runs)}
    out["heading_median_deg"] = float(np.median([r["heading_median_deg"] for r in runs]))
    for key in ("converge_s", "recover_s"):
        if key in runs[0]:
            v = float(np.median([np.inf if np.isnan(r[key]) else r[key] for r in runs]))
            out[key] = v if np.isfinite(v) else float("nan")
    out["converged"] = bool(np.isfinite(out["converge_s"]))
    out["converged_runs"] = int(sum(np.isfinite(r["converge_s"]) for r in runs))
    if "recover_s" in runs[0]:
        out["recovered_runs"] = int(sum(np.isfinite(r["recover_s"]) for r in runs))
    per_run = [round(r["median_m"], 4) for r in runs]
    out["median_m_runs"] = per_run
    out["median_m_min"], out["median_m_max"] = float(min(per_run)), float(max(per_run))
    return out
