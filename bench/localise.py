"""Benchmark of the downstream localisation (pipeline.localisation), no ray tracing.

Synthetic data of the default study's size: a 25 m x 2.4 m corridor, 16 held-out tags
on its walls, one evaluation pass with the two default antennas (``--cycles`` read
cycles; ``--mode all`` reads both antennas per cycle), candidates on both walls at
``--spacing`` (5 cm: ~29 000). Reads are sampled from a closed-form sensor
(:class:`tests.helpers.localisation.SyntheticSensor`); the four sensor models of a
study (the chapter's FCM + ANFIS model and the Joho 2009, Liu 2006 and Vorst 2008
competitors) are fitted on synthetic training attempts (d < 3 m) and used through
:class:`pipeline.localisation.ModelLikelihood` with the far rule beyond 3 m.

Prints: the fit time (not part of the target), tag localisation throughput (tags per
second over all models, one ``localise_tags`` call with the four sources; the target is
16 tags x 4 models in <= 30 s on 2 cores) with each model's median error, and the RFID
particle filter's throughput in particle-updates per second (one slot = one update).

    .venv/bin/python -m bench.localise [--cycles 400] [--mode round_robin|all]
"""

from __future__ import annotations

import argparse
import time

import numpy as np

from fuzzymodel import ANFIS, SensorModel, normalise_rssi
from pipeline.localisation import (
    ModelLikelihood,
    RfidMCLConfig,
    fit_far_detection,
    localisation_summary,
    localise_tags,
    pair_geometry,
    rssi_residual_std,
    run_rfid_mcl,
    tag_position_errors,
)
from pipeline.robot.kinematics import default_antennas
from pipeline.sensormodels import Attempts, fit_joho2009, fit_liu2006, fit_vorst2008
from tests.helpers.localisation import SyntheticSensor, corridor_scenario, sample_attempts

D_MAX_M = 3.0


def fit_models(truth: SyntheticSensor, rng: np.random.Generator, n: int = 20000):
    """The four study models fitted on `n` synthetic training attempts, as likelihoods."""
    att_all = sample_attempts(truth, n, rng)
    att = att_all.within(D_MAX_M)
    rr = truth.rssi_range_dbm
    has = att.has_rssi
    X = np.column_stack([att.d, att.alpha])
    ssm = ANFIS.from_fcm(X[has], normalise_rssi(att.rssi[has], rr), n_clusters=3, rng=rng)
    tdm = ANFIS.from_fcm(X, att.read.astype(float), n_clusters=3, rng=rng)
    models = {
        "anfis": SensorModel(ssm, tdm, rr),
        "joho2009": fit_joho2009(att, rr),
        "liu2006": fit_liu2006(att, rr, d_max_m=D_MAX_M),
        # the synthetic sensor is a function of (d, alpha): its tags in the antennas' plane
        "vorst2008": fit_vorst2008(Attempts(att.d, att.alpha, att.read, att.rssi, att.group,
                                            dz_m=0.0), rr, rng, d_max_m=D_MAX_M),
    }
    p_far, d_far = fit_far_detection(att_all, D_MAX_M)
    out = {}
    for name, m in models.items():
        sigma = None
        if getattr(m, "predicts_rssi", True) and not hasattr(m, "rssi_sigma_db"):
            sigma = rssi_residual_std(m, att, D_MAX_M)
        out[name] = ModelLikelihood(m, sigma_rssi_db=sigma, d_max_m=D_MAX_M, p_far=p_far,
                                    d_far_m=d_far, name=name)
    return out, (p_far, d_far)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--cycles", type=int, default=400)
    ap.add_argument("--mode", default="round_robin", choices=("round_robin", "all"))
    ap.add_argument("--spacing", type=float, default=0.05)
    ap.add_argument("--particles", type=int, default=2000)
    ap.add_argument("--pf-slots", type=int, default=0, help="slots of the filter run (0: all)")
    ap.add_argument("--seed", type=int, default=2011)
    args = ap.parse_args()
    rng = np.random.default_rng(args.seed)
    truth = SyntheticSensor()
    sc = corridor_scenario(rng, n_cycles=args.cycles, antenna_mode=args.mode,
                           candidate_spacing_m=args.spacing, lane_y_m=1.0)
    d, a = pair_geometry(sc.slot_poses, sc.tag_positions_m)
    gen = ModelLikelihood(truth)
    read, rssi = gen.sample(d.T, a.T, rng)
    obs = sc.observations(read, rssi)
    print(f"scenario: {obs.n_tags} tags, {obs.n_slots} slots ({args.mode}), "
          f"{len(sc.candidates_m)} candidates at {args.spacing} m, "
          f"{int(read.sum())} reads")
    t0 = time.perf_counter()
    sources, (p_far, d_far) = fit_models(truth, rng)
    print(f"fit 4 models: {time.perf_counter() - t0:.1f} s (p_far {p_far:.2f} up to "
          f"{d_far:.1f} m)")
    t0 = time.perf_counter()
    post = localise_tags(obs, sc.candidates_m, sources)
    dt = time.perf_counter() - t0
    n = obs.n_tags * len(sources)
    print(f"tag localisation: {n} tag posteriors ({obs.n_tags} tags x {len(sources)} models) "
          f"in {dt:.2f} s = {n / dt:.1f} tags/s (target: 64 in <= 30 s)")
    tmap = (sc.tag_ids, sc.tag_positions_m)
    print("  (accuracy: the ANFIS here is FCM-initialised, untrained; only its cost is real)")
    for name, p in post.items():
        s = localisation_summary(tag_position_errors(p, tmap))
        h = localisation_summary(tag_position_errors(p, tmap, horizontal=True))
        print(f"  {name:10s} median {s['median_m']:.2f} m, p90 {s['p90_m']:.2f} m "
              f"(horizontal median {h['median_m']:.2f} m)")
    # particle filter: tracking from the known start over the slots
    k = obs.n_slots if args.pf_slots <= 0 else min(args.pf_slots, obs.n_slots)
    sub = type(obs)(obs.tag_ids, obs.slot_time_s[:k], obs.slot_antenna[:k],
                    obs.slot_poses[:k], obs.read[:, :k], obs.rssi_dbm[:, :k],
                    obs.attempted[:, :k])
    cfg = RfidMCLConfig(n_particles=args.particles)
    for name, lk in sources.items():
        t0 = time.perf_counter()
        res = run_rfid_mcl(lk, sub, tmap, sc.robot_poses[:k], sc.slot_time_s[:k],
                           default_antennas(), sc.free_space_boxes(), rng, config=cfg,
                           initial_pose=sc.robot_poses[0])
        dt = time.perf_counter() - t0
        err = np.hypot(*(res.est_poses[:, :2] - sc.robot_poses[:k, :2]).T)
        print(f"particle filter {name:10s}: {args.particles} particles x {k} updates in "
              f"{dt:.2f} s = {args.particles * k / dt:,.0f} particle-updates/s "
              f"(median error {np.median(err):.2f} m)")


if __name__ == "__main__":
    main()
