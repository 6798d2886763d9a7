"""Calibration of the simulated reader to a recording: link-budget offsets by maximum likelihood.

The ray tracer gives every recorded attempt its traced one-way gain ``g``
(:mod:`pipeline.stages.sim_vs_real`). The reader around it has parameters no drawing
of the building knows; this module fits them on the *training* tags' attempts and
scores the result on the held-out tags':

==========================  ===========================================================
parameter                   meaning
==========================  ===========================================================
antenna_offsets_db[a]       one-way gain of antenna a relative to antenna 0 [dB] (cable,
                            connectors, the panel's own gain); enters the tag's power
                            once and the backscatter RSSI twice
tag_sensitivity_offset_db   the tags' wake-up threshold relative to reader.tag_sensitivity_dbm
rssi_offset_db              the reader's reported RSSI relative to the received power
rssi_noise_db               spread (Student-t scale) of the reported RSSI about the
                            prediction: the bulk of the reads, not their tails
rssi_dof                    the Student-t's degrees of freedom (1: Cauchy tails; its
                            upper bound, 200: Gaussian within any recording's resolution)
detection_spread_db         spread of the read threshold (probit), fading the tracer
                            does not resolve
miss_probability            share of closing attempts the reader still misses (slot
                            collisions, a dwell too short for the tag population, a
                            pose on the dark side of a shadow the trace lights)
stray_read_probability      share of attempts read whatever their traced margin (a pose
                            on the lit side of a shadow the trace puts it behind, a path
                            the tracer misses)
==========================  ===========================================================

The model of an attempt of antenna a with traced gain g: ``g' = g + delta_a + dg(theta)``;
``P(read) = (1 - q) (s + (1 - s) Phi(m / sigma_t))`` with the margin ``m = min(P_tag(g') -
(S_tag + delta_s), P_rx(g') - S_reader)`` (:class:`propagation.LinkBudget`), q the
reader's miss probability (fitted: the simulated reader's own estimate missed 13 % of the
closing attempts of a simulated Gen2 log, which a threshold shift would otherwise
absorb) and s the stray-read share. A read's RSSI is ``P_rx(g') + r + sigma_r T_nu``, T_nu
Student's t with nu degrees of freedom (``scipy.stats.t.logpdf``'s density). The likelihood
of every attempt (read or not) and every read's RSSI is maximised with
``scipy.optimize.minimize`` (L-BFGS-B, with the likelihood's analytic gradient: one pass
over the attempts per step where finite differences took one per parameter; the link
budget's powers are affine in the gain, so the margins at the traced gains are computed
once per fit and each parameter only shifts them).

**Robust to the poses' error** (q and s each a share of the attempts the probit need not
explain, nu how heavy the RSSI's tails are). A recorded pose that is off puts some
attempts on the wrong side of a shadow: a read the traced margin says cannot close, a
miss where it surely closes, a read's RSSI 10-20 dB from its traced prediction. Under a
Gaussian RSSI term and a bare probit those few attempts pull every offset and widen both
spreads (the bundled warehouse with MCL poses: RSSI spread 12.9 dB, detection spread 9.3
dB, held-out RSSI MAE worse after calibration than before). The two-sided mixture of the
detection term (q on the miss side, s on the read side) gives such attempts a floor of
probability that the probit's tails do not; the t's log density falls with ``log`` of the
squared residual, not the squared residual itself, so a read's pull on the offsets falls
to zero as its residual grows, weighted ``(nu + 1) / (nu + e^2)``, e its residual over
sigma_r (Lange, Little & Taylor 1989, "Robust statistical modeling using the t
distribution", JASA 84(408), 881-896, with nu fitted by maximum likelihood as there,
within [1, 200]). ``fit_calibration(robust=False)`` is the earlier Gaussian likelihood
(nu infinite, s 0), kept to compare.

**What the data cannot tell apart** (and so what is fixed): where the tag's side limits
the link (the usual UHF case), a gain common to every antenna is the same, in the reads,
as a tag sensitivity offset plus twice that in the reader's RSSI offset (``delta_a + t``,
``delta_s + t``, ``r - 2t`` give the same likelihood), so antenna 0's offset is 0 and the
others are relative to it. Attempts the tracer found no path for have no gain to offset
and are left out (counted).

**Constructions** (:class:`MaterialModel`): the relative permittivity and conductivity of
the few radio materials that carry most of the traced path power, each as ``theta``, the
log of its ratio to the traced value. ``dg(theta)``, each attempt's gain change, comes
from the traced paths re-fielded at ``theta`` (:mod:`propagation.refield`: the geometry
kept, no ray shot again). The likelihood sees it linearised,
``dg(theta) ~ dg(theta_0) + J (theta - theta_0)`` (J by forward differences of
:data:`MATERIAL_STEP`); the linearised fit proposes a step (within :data:`MATERIAL_TRUST`),
taken when the exact likelihood (re-fielded gains, the reader refitted) improves, halved
otherwise, until theta moves by less than :data:`MATERIAL_TOL` (damped Gauss-Newton): the
point estimate is that of the exact re-fielded gains, the bootstrap refits use the last
linearisation. A construction's value on the edge of its range (permittivity x4 or /4,
at least 1; conductivity x10 or /10) is reported as not identified, not refused: few
recordings see a wall's conductivity (it matters through the wall, little off it).

Intervals: every parameter's 95 % percentile interval from refits on the training tags
resampled with replacement (the tag the unit, :data:`N_BOOT` resamples by default, the
study's ``recording.calibration_resamples``, each from the point estimate; none below
:data:`MIN_TAGS` tags). A percentile interval, not BCa: each
resample is a whole maximum-likelihood fit, so the jackknife's n more fits are not spent. The held-out comparison, before (the uncalibrated hard threshold of
:mod:`.simreal`) and after, is :func:`.simreal.sim_vs_real`'s on the same tags.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass

import numpy as np
import pandas as pd
from scipy.optimize import minimize

from pipeline.evaluation.calibration_model import (
    Attempts,
    CalibrationFit,
    MaterialTerms,
    nll,
    predict,
)
from pipeline.evaluation.simreal import sim_vs_real
from pipeline.parallel import map_forked, one_blas_thread

__all__ = ["MIN_TAGS", "N_BOOT", "CalibrationFit", "MaterialModel", "MaterialTerms", "calibrate",
           "fit_calibration", "linearise", "predict"]

#: Bootstrap resamples of the training tags behind each interval (5 per tail at 95 %; the
#: default of ``recording.calibration_resamples``).
N_BOOT = 200
#: Fewest training tags an interval is drawn from.
MIN_TAGS = 5
#: Range of the RSSI's Student-t degrees of freedom (module doc).
DOF_RANGE = (1.0, 200.0)
#: Largest stray-read share fitted (its logit's bound).
MAX_STRAY = 0.5
#: Forward-difference step of the construction parameters' Jacobian (log ratio: 5 %).
MATERIAL_STEP = 0.05
#: The Gauss-Newton iteration stops when no construction parameter moves more (1 %).
MATERIAL_TOL = 0.01
#: Largest move of a construction parameter per iteration (log ratio: x1.5).
MATERIAL_TRUST = float(np.log(1.5))
#: Most Gauss-Newton iterations (each: 1 + k re-fields for the Jacobian, 1-5 for the step).
MATERIAL_ITERATIONS = 8


@dataclass(frozen=True)
class MaterialModel:
    """Construction parameters and how they move each attempt's gain (module doc).

    Attributes
    ----------
    names : tuple of str
        ``<radio material>.relative_permittivity`` / ``.conductivity``, one per parameter.
    nominal : numpy.ndarray
        (k,) the traced values (dimensionless / S/m).
    lower, upper : numpy.ndarray
        (k,) range of ``theta`` (log ratio to ``nominal``).
    delta_db : callable
        ``delta_db(theta)`` -> (n,) each attempt's gain change [dB] at ``theta`` against
        the traced gain, for the rows of the attempts given to :func:`calibrate`.
    info : dict
        What chose the constructions (their power shares), reported as is.
    """

    names: tuple
    nominal: np.ndarray
    lower: np.ndarray
    upper: np.ndarray
    delta_db: object
    info: dict


def _remembering(model: MaterialModel) -> MaterialModel:
    """``model`` whose ``delta_db`` keeps its last ``k + 2`` results (k parameters): the
    Gauss-Newton iteration asks again for the gains at the theta it accepted (the next
    linearisation's base, the reported fit, the held-out tags'), each a re-field of every
    recorded link."""
    kept: dict = {}

    def delta_db(theta):
        key = np.asarray(theta, np.float64).tobytes()
        if key not in kept:
            if len(kept) >= len(model.names) + 2:
                kept.pop(next(iter(kept)))
            kept[key] = np.asarray(model.delta_db(theta), np.float64)
        return kept[key]

    return dataclasses.replace(model, delta_db=delta_db)


def linearise(model: MaterialModel, at: np.ndarray, rows: np.ndarray) -> MaterialTerms:
    """``model``'s gain change of attempts ``rows`` linearised at ``at`` (forward differences
    of :data:`MATERIAL_STEP`), fitted within :data:`MATERIAL_TRUST` of ``at`` (the bootstrap's
    and the cross-validation's refits take the same terms over each parameter's whole
    range: :func:`_fit_materials`)."""
    base = np.asarray(model.delta_db(at), np.float64)[rows]
    jac = np.empty((len(base), len(at)))
    for j in range(len(at)):
        step = np.zeros(len(at))
        step[j] = MATERIAL_STEP if at[j] + MATERIAL_STEP <= model.upper[j] else -MATERIAL_STEP
        jac[:, j] = (np.asarray(model.delta_db(at + step), np.float64)[rows] - base) / step[j]
    lo = np.maximum(model.lower, at - MATERIAL_TRUST)
    hi = np.minimum(model.upper, at + MATERIAL_TRUST)
    return MaterialTerms(at.copy(), base, jac, lo, hi)


def fit_calibration(att: pd.DataFrame, budget, n_antennas: int, *, miss_probability=0.05,
                    weight=None, start=None, strict: bool = True,
                    terms: MaterialTerms | None = None, robust: bool = True) -> CalibrationFit:
    """Maximum-likelihood :class:`CalibrationFit` on attempts ``att`` (``gain_db`` finite,
    ``antenna``, ``read``, ``rssi_dbm``); ``weight`` per row (a bootstrap's multiplicities);
    ``miss_probability`` the start of its fit; ``terms`` the construction parameters' gain
    change for these rows (fitted within ``terms.lower``/``upper``); ``robust`` false: the
    Gaussian RSSI term and no stray reads (module doc), to compare.

    Raises
    ------
    ValueError
        (``strict``) The optimiser did not converge, or an offset or spread ended on the
        edge of its range (+-30 dB; 30 dB): a failed fit, not a calibration.
    """
    if not np.all(np.isfinite(att["gain_db"].to_numpy(np.float64))):
        raise ValueError("calibration: attempts without a traced gain cannot be fitted "
                         "(drop them first: calibrate() does)")
    gain = att["gain_db"].to_numpy(np.float64)
    antenna = att["antenna"].to_numpy(np.int64)
    read = att["read"].to_numpy(bool)
    rssi = att["rssi_dbm"].to_numpy(np.float64)
    w = np.ones(len(att)) if weight is None else np.asarray(weight, np.float64)
    q0 = float(np.clip(miss_probability, 0.01, 0.5))
    theta0 = np.zeros(0) if terms is None else terms.at
    x0 = (np.r_[np.zeros(n_antennas - 1), 0.0, 0.0, np.log(2.0), np.log(2.0), np.log(q0 / (1 - q0)),
                np.log(10.0), np.log(0.01 / 0.99), theta0]
          if start is None else np.r_[start[:n_antennas + 6], theta0])
    k = n_antennas - 1
    # offsets within +-30 dB, spreads within [0.05, 30] dB, misses within [1e-4, 0.9]: a
    # value on such a bound is a failed fit; the t's dof within DOF_RANGE and the stray
    # share within [1e-4, MAX_STRAY] (their bounds are where the data say "none": not a
    # failure); without ``robust`` both fixed (L-BFGS-B keeps a variable with equal bounds)
    logit = (np.log(1e-4 / (1 - 1e-4)), np.log(MAX_STRAY / (1 - MAX_STRAY)))
    robust_bounds = ([tuple(np.log(DOF_RANGE)), logit] if robust
                     else [(x0[k + 5], x0[k + 5]), (x0[k + 6], x0[k + 6])])
    bounds = ([(-30.0, 30.0)] * (k + 2) + [(np.log(0.05), np.log(30.0))] * 2
              + [(np.log(1e-4 / (1 - 1e-4)), np.log(0.9 / 0.1))] + robust_bounds
              + ([] if terms is None else list(zip(terms.lower, terms.upper, strict=True))))
    x0 = np.clip(x0, [b[0] for b in bounds], [b[1] for b in bounds])
    data = Attempts.of(gain, antenna, read, rssi, w, budget)
    with one_blas_thread():  # ten parameters: BLAS threads only wait on each other
        res = minimize(nll, x0, args=(data, budget.reader_sensitivity_dbm, n_antennas, terms, robust),
                       jac=True, method="L-BFGS-B", bounds=bounds)
    fit = CalibrationFit.from_vector(res.x, n_antennas, robust)
    if strict:
        if not res.success or not np.isfinite(res.fun):
            raise ValueError(f"calibration: the maximum-likelihood fit did not converge "
                             f"({str(res.message)[:80]}); the recording may hold too few reads")
        edge = [name for name, v, hi in
                [(f"antenna_offset_db[{i + 1}]", abs(x), 30.0) for i, x in enumerate(res.x[:k])]
                + [("tag_sensitivity_offset_db", abs(res.x[k]), 30.0),
                   ("rssi_offset_db", abs(res.x[k + 1]), 30.0),
                   ("rssi_noise_db", float(np.exp(res.x[k + 2])), 30.0),
                   ("detection_spread_db", float(np.exp(res.x[k + 3])), 30.0)]
                if v >= hi * (1 - 1e-6)]
        if edge:
            raise ValueError(f"calibration: {', '.join(edge)} ended on the edge of its range "
                             "(30 dB): the traced building and the recording disagree beyond "
                             "what the reader's parameters can explain (check the mounts, "
                             "the poses' frame, recording.antenna_ports)")
    object.__setattr__(fit, "_x", res.x)
    object.__setattr__(fit, "_nll", float(res.fun))
    object.__setattr__(fit, "_converged", bool(res.success) and bool(np.isfinite(res.fun)))
    return fit


def _bootstrap(att, budget, n_ant, point, rng, n_boot, terms):
    """``n_boot`` refits on the training tags resampled with replacement, in forked
    processes (:func:`pipeline.parallel.map_forked`); the resamples are drawn here first, so
    the result does not depend on the number of workers."""
    tags = att["tag_id"].astype(str).to_numpy()
    units, code = np.unique(tags, return_inverse=True)
    mult = [np.bincount(rng.integers(0, len(units), len(units)), minlength=len(units))
            for _ in range(n_boot)]

    def refit(i):
        return fit_calibration(att, budget, n_ant, weight=mult[i][code], strict=False,
                               start=point._x, terms=terms).as_dict()  # noqa: SLF001 - our own start

    return pd.DataFrame(map_forked(refit, n_boot))


def _fit_materials(train, budget, n_antennas, q, model: MaterialModel, rows: np.ndarray):
    """Damped Gauss-Newton on the re-fielded gains (module doc).

    A step (the linearised fit's theta) is taken when the exact likelihood at it, the
    reader's parameters refitted, beats the current one; else it is halved, up to four
    times. The iteration has converged when the *undamped* proposal moves no parameter more
    than MATERIAL_TOL; it also ends when no halving improves (settled along the linearised
    direction) or after MATERIAL_ITERATIONS (reported as not converged).

    Returns
    -------
    fit : CalibrationFit
        At the last accepted theta, the reader's parameters fitted to the exact gains there
        (strictly checked: a reader offset on its range's edge stops the stage).
    terms : MaterialTerms
        The linearisation there, over each parameter's whole range (the bootstrap's: its
        refits are not held in the trust region).
    how : dict
        ``steps`` (the accepted thetas), ``converged``, ``ended`` (why it stopped).
    """
    gain = train["gain_db"].to_numpy(np.float64)

    def exact(theta, strict=False):  # the reader fitted to the gains re-fielded at theta
        g = gain + np.asarray(model.delta_db(theta), np.float64)[rows]
        return fit_calibration(train.assign(gain_db=g), budget, n_antennas, miss_probability=q,
                               strict=strict)

    at = np.zeros(len(model.names))
    best = exact(at)
    steps, converged, ended, terms = [at.tolist()], False, "iterations", None
    for _ in range(MATERIAL_ITERATIONS):
        terms = linearise(model, at, rows)
        proposal = fit_calibration(train, budget, n_antennas, miss_probability=q, terms=terms,
                                   start=best._x, strict=False)  # noqa: SLF001 - our own vectors
        step = proposal.material_log_ratios - at
        if np.max(np.abs(step), initial=0.0) < MATERIAL_TOL:
            converged, ended = True, "the linearised fit stays where it is"
            break
        for _ in range(5):
            trial = exact(at + step)
            if trial._nll < best._nll:  # noqa: SLF001
                break
            step = step / 2.0
        else:
            ended = "no step along the linearised fit's direction improves the exact likelihood"
            break
        at, best, terms = at + step, trial, None
        steps.append(at.tolist())
    if terms is None or not np.array_equal(terms.at, at):
        terms = linearise(model, at, rows)
    best = exact(at, strict=True)  # the reported reader: its own checks apply
    if not np.isfinite(best._nll):  # noqa: SLF001
        raise ValueError("calibration: the likelihood is not finite at the fitted construction "
                         "parameters; the recording may hold too few reads")
    fit = dataclasses.replace(best, material_log_ratios=at.copy())
    object.__setattr__(fit, "_x", np.r_[best._x, at])  # noqa: SLF001
    whole = MaterialTerms(terms.at, terms.base_db, terms.jac_db, model.lower, model.upper)
    return fit, whole, {"steps": steps, "converged": converged, "ended": ended}


def renamed(cmp: dict, ours: str, theirs: str) -> dict:
    """:func:`.simreal.sim_vs_real`'s sections with its two predictions renamed."""
    for sec in cmp.values():
        if isinstance(sec, dict) and "ray_tracer" in sec:
            sec[ours], sec[theirs] = sec.pop("ray_tracer"), sec.pop("baseline")
            sec["difference"]["compares"] = f"{ours} - {theirs}" + (
                " (|bias|)" if sec["difference"].get("compares") == "|bias|" else "")
    return cmp


def _material_entry(model: MaterialModel, j: int, entry: dict) -> dict:
    """A construction parameter's report entry in its own units (module doc)."""
    nom = float(model.nominal[j])
    out = {k: (None if entry[k] is None else nom * float(np.exp(entry[k])))
           for k in ("value", "low", "high")}
    out.update(traced=nom, unit="S/m" if model.names[j].endswith(".conductivity") else "")
    rng = f"range x{np.exp(model.lower[j]):.3g} to x{np.exp(model.upper[j]):.3g}"
    edge = [k for k in ("value", "low", "high") if entry[k] is not None
            and min(entry[k] - model.lower[j], model.upper[j] - entry[k]) < 1e-3]
    if "value" in edge:
        # the likelihood pushes past the range: a misfit the construction absorbs (the
        # poses' error, a missing path), not a measurement of it
        out["note"] = f"on the edge of its range ({rng}): the recording pushes it past what a wall can be"
    elif edge:
        out["note"] = f"its interval reaches the edge of its range ({rng}): weakly determined"
    return out


_UNITLESS = ("miss_probability", "rssi_dof", "stray_read_probability")


def calibrate(att: pd.DataFrame, budget, n_antennas: int, *, miss_probability=0.0,
              seed: int, n_boot: int = N_BOOT,
              materials: MaterialModel | None = None) -> tuple[CalibrationFit, dict]:
    """Fit on the training attempts, intervals by resampling training tags, and the held-out
    residual before and after (module doc).

    Parameters
    ----------
    att : pandas.DataFrame
        Attempts within the traced range: ``split`` ("train"/"eval"), ``tag_id``,
        ``antenna``, ``read``, ``rssi_dbm``, ``gain_db`` (finite), ``p_sim`` and
        ``rssi_sim_dbm`` (the uncalibrated prediction).
    miss_probability : array_like
        The simulated reader's miss probability of each attempt: its mean starts the fit.
    seed : int
    materials : MaterialModel, optional
        Construction parameters to fit too; its ``delta_db`` gives a value per row of ``att``.

    Returns
    -------
    fit : CalibrationFit
    report : dict
        ``parameters`` (each: value, low, high, unit), ``fixed`` (what the data cannot
        separate), ``heldout`` (:func:`.simreal.sim_vs_real` with ``after`` the calibrated
        and ``before`` the uncalibrated prediction), ``n_train_tags``, ``n_boot``;
        with ``materials`` also ``constructions`` (what chose them, the Gauss-Newton steps).
    """
    q = float(np.mean(miss_probability))
    traced = np.isfinite(att["gain_db"].to_numpy(np.float64))
    # an attempt the tracer found no path for has no gain to offset: left out, counted
    n_untraced = int((~traced).sum())
    n_untraced_reads = int((~traced & att["read"].to_numpy(bool)).sum())
    split = att["split"].to_numpy()
    is_train, is_held = traced & (split == "train"), traced & (split == "eval")
    att = att[traced]
    train = att[att["split"] == "train"].reset_index(drop=True)
    held = att[att["split"] == "eval"].reset_index(drop=True)
    terms = held_terms = None
    if materials is None or not len(materials.names):
        fit = fit_calibration(train, budget, n_antennas, miss_probability=max(q, 0.05))
    else:
        materials = _remembering(materials)
        fit, terms, how = _fit_materials(train, budget, n_antennas, max(q, 0.05), materials,
                                         np.flatnonzero(is_train))
        base = np.asarray(materials.delta_db(fit.material_log_ratios), np.float64)[is_held]
        held_terms = MaterialTerms(fit.material_log_ratios, base, np.zeros((len(base), len(materials.names))),
                                   materials.lower, materials.upper)
    n_tags = int(train["tag_id"].nunique())
    boot = (_bootstrap(train, budget, n_antennas, fit, np.random.default_rng([int(seed), 53]),
                       int(n_boot), terms) if n_tags >= MIN_TAGS and n_boot > 0 else None)
    params = {}
    for key, value in fit.as_dict().items():
        lo, hi = (np.percentile(boot[key].to_numpy(np.float64), [2.5, 97.5]) if boot is not None
                  else (None, None))
        entry = {"value": value, "low": None if lo is None else float(lo),
                 "high": None if hi is None else float(hi),
                 "unit": "" if key in _UNITLESS else "dB"}
        if key.startswith("theta["):
            j = int(key[6:-1])
            key, entry = materials.names[j], _material_entry(materials, j, entry)
        elif key == "rssi_dof" and value <= DOF_RANGE[0] * (1 + 1e-6):
            entry["note"] = ("on its lower bound (1, Cauchy): the RSSI's tails are heavier still; "
                             "rssi_noise_db is the spread of the bulk of the reads")
        elif key == "rssi_dof" and value >= DOF_RANGE[1] * (1 - 1e-6):
            entry["note"] = "on its upper bound: the RSSI's spread is Gaussian as far as the reads tell"
        if entry["low"] is not None and not entry["low"] <= entry["value"] <= entry["high"]:
            # the refits start from the point estimate and end at their own optimum; a value
            # outside all but 5 % of them is one the fit stopped short of (constructions:
            # the Gauss-Newton's iterations ran out) or a bootstrap distribution skewed by a
            # range's edge
            entry["note"] = "; ".join(filter(None, [entry.get("note"), (
                "outside its own interval: the fit stopped before its optimum (see "
                "constructions.converged), the resampled fits pile up on a range's edge, or "
                "(constructions) the refits' linearised gains part from the exact ones")]))
        params[key] = entry
        if boot is None:
            why = (f"{n_tags} training tags: an interval needs at least {MIN_TAGS}"
                   if n_boot > 0 else "no interval asked for (n_boot = 0)")
            params[key]["note"] = "; ".join(filter(None, [params[key].get("note"), why]))
    params["antenna_offset_db[0]"].update(low=0.0, high=0.0, note="fixed: the reference antenna")
    p_after, rssi_after = predict(fit, held["gain_db"], held["antenna"], budget, held_terms)
    rx_before = np.asarray(budget.reader_rssi_dbm(held["gain_db"].to_numpy(np.float64)), np.float64)
    cmp_att = held.assign(p_base=held["p_sim"], rssi_base_dbm=rx_before,
                          p_sim=p_after, rssi_sim_dbm=rssi_after)
    heldout = renamed(sim_vs_real(cmp_att, seed=seed), "after", "before")
    extra = {}
    if terms is not None:
        # the same held-out tags under the reader's parameters alone: did the constructions help?
        alone = fit_calibration(train, budget, n_antennas, miss_probability=max(q, 0.05))
        x = fit._x  # noqa: SLF001 - our own vector, not a field
        fit = dataclasses.replace(fit, reader_only=alone)
        object.__setattr__(fit, "_x", x)
        # the training attempts' gains linearised at the fit over the whole range: what
        # the bootstrap refits and the cross-validation's (calibration_cv) use
        object.__setattr__(fit, "_terms", terms)
        p_alone, rssi_alone = predict(alone, held["gain_db"], held["antenna"], budget)
        against = renamed(sim_vs_real(cmp_att.assign(p_base=p_alone, rssi_base_dbm=rssi_alone),
                                       seed=seed), "with_constructions", "reader_only")
        extra = {"constructions": {
            **materials.info, "parameters": list(materials.names),
            "gauss_newton_log_ratios": how["steps"], "converged": how["converged"],
            "ended": how["ended"],
            # dB of gain per unit log ratio, RMS over the training attempts: ~0 = unseen
            "sensitivity_db": {n: float(np.sqrt(np.mean(terms.jac_db[:, j] ** 2)))
                               for j, n in enumerate(materials.names)},
            "heldout_against_reader_only": {k: against[k] for k in ("rssi_mae_db", "brier") if k in against},
            # what calibrated.toml holds when the constructions are not laid over
            "reader_only_parameters": alone.as_dict(),
            "how": "each parameter the log of its ratio to the traced value; the traced paths "
                   "re-fielded (propagation.refield), linearised, a step taken where the "
                   "exact likelihood improves"}}
    return fit, {
        **extra,
        "parameters": params,
        "fixed": "antenna 0's offset is 0: a gain common to all antennas equals a tag "
                 "sensitivity offset plus twice that in the RSSI offset",
        "heldout": heldout, "n_train_tags": n_tags, "n_boot": int(n_boot) if boot is not None else 0,
        "n_attempts_untraced": n_untraced, "n_reads_untraced": n_untraced_reads,
        "simulated_miss_probability": q,
    }
