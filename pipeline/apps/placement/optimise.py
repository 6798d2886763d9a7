"""An optimiser over continuous mount ranges: Optuna's TPE or CMA-ES, a study per trial.

The search is Optuna's (T. Akiba et al., "Optuna: a next-generation hyperparameter
optimization framework", KDD 2019) ask-and-tell interface: :class:`optuna.samplers.TPESampler`
(tree-structured Parzen estimator) or :class:`optuna.samplers.CmaEsSampler`, seeded, so
that a rerun proposes the same trials and finds their studies done (each trial is a
candidate whose replicate run directories are a cache). Each trial's value is the
primary objective's estimate over all its replicates' units; the trials' intervals
come with the summary like every candidate's.

Constraints (``[[constraint]]``) go to the sampler, not only to the ranking: with TPE,
Optuna's constrained TPE (``Trial.set_constraint``; S. Watanabe and F. Hutter, "c-TPE:
tree-structured Parzen estimator with inequality constraints", IJCAI 2023, as Optuna
implements it: infeasible trials are ranked below every feasible one when the sampler
splits good from bad trials) receives each trial's violation per
constraint (``min - estimate`` or ``estimate - max``; <= 0 is met). Optuna's CMA-ES has no
constraint handling, so a placement file with constraints and ``sampler = "cmaes"`` is
refused at its checks.

Cost structure: a trial that changes only yaw or tilt traces no new antenna
position (the propagation cache is keyed by position); trials at heights already
traced reuse them; every trial shares the scene.
"""

from __future__ import annotations

import logging
from collections.abc import Callable

from pipeline.apps.placement.candidates import MOUNT_FIELDS, Candidate, candidate_from_trial
from pipeline.apps.placement.objectives import OBJECTIVES, load_candidate_data, objective_estimate
from pipeline.apps.placement.results import complete_dirs
from pipeline.studyscene import link_budget

__all__ = ["optimise", "search"]

log = logging.getLogger(__name__)


def search(ranges: dict, evaluate: Callable[[dict], float | tuple], *, n_trials: int,
           sampler: str = "tpe", seed: int = 0, minimise: bool = True,
           constrained: bool = False) -> list[tuple[dict, float]]:
    """Ask-and-tell search of ``evaluate`` over the box ``ranges``.

    Parameters
    ----------
    ranges : dict[str, tuple[float, float]]
        Parameter -> (low, high).
    evaluate : callable
        ``evaluate(values) -> float``; NaN marks a failed trial (told as failed). With
        ``constrained``, ``evaluate(values) -> (float, violations)``: one number per
        constraint, <= 0 where it is met (NaN counts as violated).
    n_trials : int
    sampler : {"tpe", "cmaes"}
    seed : int
        Seeds the sampler: the same told values give the same proposals.
    minimise : bool
    constrained : bool
        Hand the violations to Optuna's constrained TPE (``sampler = "tpe"`` only).

    Returns
    -------
    list of (dict, float)
        Each trial's values (as ``evaluate`` got them) and value, in trial order.
    """
    import math

    import optuna
    from optuna.distributions import FloatDistribution
    from optuna.trial import TrialState

    optuna.logging.set_verbosity(optuna.logging.WARNING)
    if constrained and sampler != "tpe":
        raise ValueError("constraints need sampler = 'tpe' (Optuna's CMA-ES has none)")
    if sampler == "cmaes":
        samp = optuna.samplers.CmaEsSampler(seed=int(seed), warn_independent_sampling=False)
    else:
        # a few random trials first, then the Parzen estimators (Optuna's default is 10,
        # too many for a budget of about ten studies)
        samp = optuna.samplers.TPESampler(seed=int(seed),
                                          n_startup_trials=max(2, min(10, n_trials // 3)))
    study = optuna.create_study(direction="minimize" if minimise else "maximize", sampler=samp)
    dists = {k: FloatDistribution(float(lo), float(hi)) for k, (lo, hi) in ranges.items()}
    out = []
    for _ in range(int(n_trials)):
        trial = study.ask(dists)
        values = dict(trial.params)
        result = evaluate(values)
        if constrained:
            value, violations = float(result[0]), list(result[1])
            for i, v in enumerate(violations):
                # a constraint that could not be evaluated counts as violated, worse than
                # any measured miss (Optuna refuses NaN and ranks infeasible trials by the
                # sum of their violations)
                trial.set_constraint(f"c{i}", float(v) if math.isfinite(float(v)) else 1e9)
        else:
            value = float(result)
        if math.isfinite(value):
            study.tell(trial, value)
        else:
            study.tell(trial, state=TrialState.FAIL)
        out.append((values, value))
    return out


def violations(estimates: dict, constraints) -> list[float]:
    """Per constraint, how far ``estimates[objective]`` misses it (<= 0: met; NaN: not
    evaluated). Both bounds of one constraint give the larger violation."""
    import math

    out = []
    for c in constraints:
        v = estimates.get(c.objective)
        v = float("nan") if v is None else float(v)
        if not math.isfinite(v):
            out.append(float("nan"))
            continue
        parts = []
        if c.min is not None:
            parts.append(float(c.min) - v)
        if c.max is not None:
            parts.append(v - float(c.max))
        out.append(max(parts) if parts else 0.0)
    return out


def optimise(spec, runner, out) -> list:
    """Run the placement file's ``[optimise]`` trials with ``runner`` (each trial a
    candidate with every replicate); return the trials' candidates in trial order."""
    s = spec.settings
    opt = s.optimise
    ranges = {k: tuple(getattr(opt.ranges, k)) for k in MOUNT_FIELDS
              if k != "count" and getattr(opt.ranges, k)}
    budget = link_budget(spec.base)
    trials: list[Candidate] = []

    def evaluate(values: dict) -> float:
        cand = candidate_from_trial(spec, values)
        trials.append(cand)
        runner.run([cand])
        # the runs that hold what the ranking needs (a study may stop at its reads)
        dirs = complete_dirs(out, cand.name, s.replicates, runner.required)
        constraints = list(s.constraint)
        if not dirs:
            return (float("nan"), [float("nan")] * len(constraints)) if constraints \
                else float("nan")
        data = load_candidate_data(dirs, budget)
        value = objective_estimate(data, s.primary, min_reads=s.min_reads)
        if not constraints:
            return value
        est = {c.objective: objective_estimate(data, c.objective, min_reads=s.min_reads)
               for c in constraints}
        return value, violations(est, constraints)

    search(ranges, evaluate, n_trials=opt.n_trials, sampler=opt.sampler, seed=opt.seed,
           minimise=OBJECTIVES[s.primary].lower_is_better,
           constrained=bool(list(s.constraint)))
    return trials
