"""Stage ``calibration``: the simulated reader and building fitted to the recording
(``calibration.json``, ``calibrated.toml``).

The fit and its intervals are :func:`pipeline.evaluation.calibration.calibrate`'s, on the
traced twins of the recorded attempts (``sim_vs_real/attempts.parquet``): training tags
to fit, held-out tags to score before and after. With ``recording.calibrate_constructions``
> 0 the permittivity and conductivity of the constructions that carry most of the traced
path power are fitted too (:func:`construction_model`: the recorded links traced once,
their paths re-fielded per trial by :mod:`propagation.refield`). Writes into the run
directory

- ``calibration.json``: each parameter with its 95 % interval, what is fixed, and the
  held-out residuals before and after with paired intervals;
- ``calibrated.toml``: the study's config with the fitted values laid over it and no
  ``[recording]``, so that a simulated study (a placement study) runs with the calibrated
  reader in the calibrated building: each antenna's ``cable_loss_db`` less its gain
  offset, ``reader.tag_sensitivity_dbm`` plus the sensitivity offset,
  ``reader.rssi_noise_db`` the fitted spread less the quantisation's
  (``rssi_resolution_db^2 / 12``; the Student-t's scale: the spread of the bulk of the
  reads, its heavy tails, the poses' error, left out), and a ``[[materials]]`` table per fitted construction's
  material (its permittivity and conductivity), where the constructions beat the reader's
  parameters alone out of fold on the training tags and none is on the edge of its range
  (:func:`_overlay_refusal`: by tag-fold cross-validation within the training tags; else
  the reader's parameters fitted alone, the building as traced; every number is in ``calibration.json`` either way). The RSSI offset, the detection spread and
  the miss probability, the t's degrees of freedom and the stray-read share are reported
  only: the simulated reader has no key for them (its truth is the received power, so an
  offset key would bias every model against it).
"""

from __future__ import annotations

import dataclasses
import logging

import numpy as np
import pandas as pd

from pipeline import runfiles
from pipeline.config import config_to_toml
from pipeline.engine.runstore import atomic_write_json
from pipeline.engine.study import Stage
from pipeline.evaluation.calibration import MIN_TAGS, MaterialModel, calibrate
from pipeline.evaluation.calibration_cv import crossvalidate_constructions
from pipeline.recording.config import CALIBRATION_FIELDS, RecordingConfig
from pipeline.runfiles import STAGE_OUTPUTS
from pipeline.sceneconfig import MaterialConfig
from pipeline.stages.common import TRACING_KEYS, load_scene
from pipeline.studyscene import link_budget, trace_options
from propagation.refield import freeze_paths, material_shares, refield_gains_db
from propagation.tracing import tag_dipole_axes
from scenes import resolve_material_name
from scenes.export import material_of_bsdf_id
from scenes.fileio import atomic_write_text

__all__ = ["MIN_POWER_SHARE", "STAGE", "calibrated_config", "construction_model", "heldout_worse",
           "stage_calibration"]

log = logging.getLogger(__name__)

#: Smallest share of the traced path power a construction must carry to be fitted.
MIN_POWER_SHARE = 0.02
#: A link that loses every path at a trial value counts as this much weaker [dB].
VANISHED_DB = 100.0
#: Above this conductivity [S/m] a material is a conductor (metal): nothing to fit.
_CONDUCTOR_S_PER_M = 1e3


def construction_model(ctx, att: pd.DataFrame, n_constructions: int):
    """The :class:`~pipeline.evaluation.calibration.MaterialModel` of the recorded links
    (module doc), or None where no construction carries :data:`MIN_POWER_SHARE`.

    The antenna positions of the traced attempts (``ant_*`` columns) are traced once to
    their tags with the direct tracer at the study's ``[tracing]`` depth, rays and seed
    (:func:`propagation.refield.freeze_paths`); ``delta_db(theta)`` re-fields them and
    gives each attempt's gain change against the re-fielded gain as traced, added to the
    study tracer's gain (0 where the re-trace found no path; :data:`VANISHED_DB` down where
    a trial value leaves none; ``info`` reports how far the two tracers' gains are). Radio material names are ``uhf-<material>-t<thickness>``."""
    cfg = ctx.config
    sc = load_scene(ctx)
    rows = np.flatnonzero(np.isfinite(att["gain_db"].to_numpy(np.float64)))
    xyz = att[["ant_x_m", "ant_y_m", "ant_z_m"]].to_numpy(np.float64)[rows]
    uniq, pos_index = np.unique(xyz, axis=0, return_inverse=True)
    col = {str(t): i for i, t in enumerate(sc.tags.ids)}
    tag_index = att["tag_id"].astype(str).map(col).to_numpy()[rows].astype(np.int64)
    need = np.zeros((len(uniq), len(col)), bool)
    need[pos_index.reshape(-1), tag_index] = True
    opts = dataclasses.replace(trace_options(cfg), method="direct")
    frozen = freeze_paths(sc, uniq, sc.tags.positions_m, need, frequency_hz=cfg.frequency_hz, options=opts)
    shares = material_shares(frozen)
    chosen = [n for n, v in sorted(shares.items(), key=lambda kv: -kv[1])
              if v >= MIN_POWER_SHARE and frozen.materials[n][1] < _CONDUCTOR_S_PER_M][:n_constructions]
    info = {"power_share": {k: round(v, 4) for k, v in shares.items()},
            "n_positions_traced": len(uniq), "n_links_traced": int(need.sum())}
    if not chosen:
        return None, info
    tilt = np.deg2rad([a.tilt_deg for a in cfg.robot.antennas])
    ant = att["antenna"].to_numpy(np.int64)[rows]
    yaw = att["ant_yaw_rad"].to_numpy(np.float64)[rows]
    poses = np.column_stack([xyz, yaw, tilt[ant], np.zeros(len(rows))])
    freq = att["frequency_hz"].to_numpy(np.float64)[rows]
    axes = tag_dipole_axes(sc.tags.normals, len(col))

    def gains(materials):
        return refield_gains_db(frozen, materials, pos_index.reshape(-1), tag_index, poses,
                                frequency_hz=freq, options=opts, tag_axes=axes)

    g0 = gains(None)
    names, nominal, lower, upper, keys = [], [], [], [], []
    for n in chosen:
        eps, sigma = frozen.materials[n]
        names.append(f"{n}.relative_permittivity")
        nominal.append(eps)
        lower.append(max(np.log(1.0 / eps), np.log(0.25)))  # eps_r >= 1
        upper.append(np.log(4.0))
        keys.append((n, 0))
        if sigma > 0.0:
            names.append(f"{n}.conductivity")
            nominal.append(sigma)
            lower.append(np.log(0.1))
            upper.append(np.log(10.0))
            keys.append((n, 1))

    def delta_db(theta):
        mats = {n: list(frozen.materials[n]) for n in chosen}
        for (n, j), t, v in zip(keys, theta, nominal, strict=True):
            mats[n][j] = v * float(np.exp(t))
        g = gains({n: tuple(v) for n, v in mats.items()})
        out = np.zeros(len(att))
        ok = np.isfinite(g0)
        # a link whose every path vanishes at a trial value (a reflection at eps 1, sigma
        # 0 is exactly zero) counts as VANISHED_DB weaker, not as unchanged
        out[rows[ok]] = np.maximum(g[ok] - g0[ok], -VANISHED_DB)  # -inf - finite: -inf
        return out

    # attempts the direct re-trace found no path for keep their study gain (change 0)
    info["n_attempts_without_path"] = int((~np.isfinite(g0)).sum())
    study = att["gain_db"].to_numpy(np.float64)[rows]
    both = np.isfinite(g0)
    # the change is added to the study tracer's gain: how far the two traces' gains are
    info["median_abs_gain_difference_db"] = (float(np.median(np.abs(g0[both] - study[both])))
                                             if both.any() else None)
    return MaterialModel(tuple(names), np.asarray(nominal), np.asarray(lower), np.asarray(upper),
                         delta_db, info), info


def calibrated_config(cfg, fit, constructions: dict | None = None):
    """``cfg`` with ``fit`` (:class:`~pipeline.evaluation.calibration.CalibrationFit`) laid
    over it and the recording removed (module doc); ``constructions`` {radio material name
    ``uhf-<material>-t<thickness>``: (relative permittivity, conductivity or None)}, in
    order of their power share, become ``[[materials]]`` tables. The overlay is per
    material: a material fitted in two thicknesses takes the first (larger share)
    construction's values; a conductivity not fitted (None) keeps the study's own."""
    antennas = tuple(dataclasses.replace(a, cable_loss_db=float(a.cable_loss_db - d))
                     for a, d in zip(cfg.robot.antennas, fit.antenna_offsets_db, strict=True))
    r = cfg.reader
    noise = float(np.sqrt(max(fit.rssi_noise_db ** 2 - r.rssi_resolution_db ** 2 / 12.0, 0.0)))
    reader = dataclasses.replace(
        r, tag_sensitivity_dbm=float(r.tag_sensitivity_dbm + fit.tag_sensitivity_offset_db),
        rssi_noise_db=noise)
    mats = {resolve_material_name(m.name): m for m in cfg.materials}
    laid: set = set()
    for name, (eps, sigma) in (constructions or {}).items():
        material = material_of_bsdf_id(name)
        if material in laid:
            continue
        laid.add(material)
        own = mats.get(material)
        mats[material] = MaterialConfig(
            name=material, relative_permittivity=float(eps),
            conductivity_s_per_m=float(sigma) if sigma is not None
            else (own.conductivity_s_per_m if own is not None else -1.0))
    return dataclasses.replace(cfg, robot=dataclasses.replace(cfg.robot, antennas=antennas),
                               reader=reader, recording=RecordingConfig(),
                               materials=tuple(mats.values()))


def _fitted_constructions(report: dict) -> dict:
    """{radio material: (permittivity, conductivity or None)} of the fitted construction
    parameters, in the report's order (descending power share)."""
    out: dict = {}
    for key, p in report["parameters"].items():
        name, _, what = key.rpartition(".")
        if what in ("relative_permittivity", "conductivity"):
            out.setdefault(name, {})[what] = p["value"]
    return {k: (v["relative_permittivity"], v.get("conductivity")) for k, v in out.items()}


def _overlay_refusal(report: dict) -> str | None:
    """Why the fitted constructions are not laid over ``calibrated.toml`` (None: they are).

    They are where they beat the reader's parameters alone out of fold on the training tags
    (:func:`~pipeline.evaluation.calibration_cv.crossvalidate_constructions`: one of RSSI
    MAE and Brier score better by its interval, neither worse, every fold's refits
    converged), none sits on the edge of its range, and the fit laid over is the one the
    folds tested: converged, each value inside its own interval. The choice sees no held-out tag, so the held-out comparison
    (``heldout_against_reader_only``) is an honest check of it, not part of it."""
    cons = report.get("constructions", {})
    cv = cons.get("crossvalidated_against_reader_only")
    edge = [k for k in cons.get("parameters", []) if "past" in report["parameters"][k].get("note", "")]
    if edge:
        return f"{', '.join(edge)} on the edge of its range: a misfit, not a wall"
    if cons.get("converged") is False:
        # the folds refit to the linearised optimum; the point estimate stopped short of it,
        # so what they endorse is not the value that would be laid over
        return f"the constructions' fit did not converge ({cons.get('ended')})"
    outside = [k for k in cons.get("parameters", [])
               if "outside its own interval" in report["parameters"][k].get("note", "")]
    if outside:
        return f"{', '.join(outside)} outside its own interval: not the fit its resamples found"
    if cv is None:
        return (f"{report.get('n_train_tags')} training tags: cross-validating the choice needs "
                f"at least {MIN_TAGS}")
    if not cv.get("all_folds_converged", False):
        return "a cross-validation fold's refit did not converge"
    verdicts = [v.get("difference", {}).get("verdict") for v in cv.values()
                if isinstance(v, dict) and "difference" in v]
    if not ("better" in verdicts and "worse" not in verdicts):
        return ("out of fold on the training tags they did not beat the reader's parameters "
                "alone (one verdict better, none worse, is asked for); the recorded poses' "
                "error, or too few attempts, can make them absorb what is not the building")
    return None


def stage_calibration(ctx) -> dict:
    """Fit the reader (and constructions) to the recording; write ``calibration.json`` and
    ``calibrated.toml``."""
    cfg = ctx.config
    att = pd.read_parquet(ctx.input(runfiles.SIM_VS_REAL.format(name="attempts.parquet")))
    model, info = None, None
    if cfg.recording.calibrate_constructions:
        model, info = construction_model(ctx, att, cfg.recording.calibrate_constructions)
    budget = link_budget(cfg)
    fit, report = calibrate(att, budget, len(cfg.robot.antennas),
                            miss_probability=att["miss_probability"].to_numpy(np.float64),
                            seed=cfg.seed, n_boot=cfg.recording.calibration_resamples,
                            materials=model)
    if model is None and info is not None:
        report["constructions"] = {**info, "note": f"no construction other than a conductor "
                                   f"carries {MIN_POWER_SHARE:.0%} of the traced path power"}
    report["antennas"] = [a.name for a in cfg.robot.antennas]
    overlay, reader_fit = {}, fit
    if model is not None:
        if report["n_train_tags"] >= MIN_TAGS:
            report["constructions"]["crossvalidated_against_reader_only"] = crossvalidate_constructions(
                att, budget, len(cfg.robot.antennas), fit, model,
                rng=np.random.default_rng([int(cfg.seed), 55]), seed=cfg.seed)
        why = _overlay_refusal(report)
        if why is None:
            overlay = _fitted_constructions(report)
        else:  # the building as traced, and the reader fitted to it
            reader_fit = fit.reader_only
        report["constructions"]["in_calibrated_toml"] = True if why is None else f"no: {why}"
    worse = heldout_worse(report)
    if worse:
        report["warning"] = worse
        log.warning("calibration: %s", worse)
    atomic_write_json(ctx.out(runfiles.CALIBRATION), report)
    head = "# the study's config with the reader calibrated to the recording (calibration.json)\n"
    if worse:
        head += f"# WARNING: {worse}\n"
    atomic_write_text(ctx.out(runfiles.CALIBRATED_CONFIG),
                      head + config_to_toml(calibrated_config(cfg, reader_fit, overlay)))
    mae = report["heldout"]["rssi_mae_db"]
    return {"parameters": {k: round(v["value"], 3) for k, v in report["parameters"].items()},
            "heldout_rssi_mae_db": {"before": mae["before"]["estimate"], "after": mae["after"]["estimate"]},
            **({"warning": worse} if worse else {})}


def heldout_worse(report: dict) -> str | None:
    """A sentence when the calibrated reader predicts the held-out tags worse than the
    uncalibrated one (a verdict ``worse`` by its interval), else None: the fit then
    absorbed what its model does not hold (links the tracer misses, more pose error than
    its heavy tails and stray reads take up), and ``calibrated.toml`` says so."""
    bad = [f"{v.get('label', k)} {v['before']['estimate']:.3g} -> {v['after']['estimate']:.3g}"
           for k, v in report.get("heldout", {}).items()
           if isinstance(v, dict) and v.get("difference", {}).get("verdict") == "worse"]
    if not bad:
        return None
    return ("the calibrated reader predicts the held-out tags worse than the uncalibrated one ("
            + "; ".join(bad) + "): check the recorded poses and calibration.json before using "
            "this config")


STAGE = Stage("calibration", stage_calibration,
              ("seed", "reader", "robot", *(f"recording.{f}" for f in CALIBRATION_FIELDS))
              + TRACING_KEYS,
              ("scene", "sim_vs_real"), version=4,  # each version's change: CHANGELOG.md
              description="calibrate the reader and building to the recording",
              outputs=STAGE_OUTPUTS["calibration"])
