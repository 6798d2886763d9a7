"""Benchmark of the global tag-localisation oracle (pipeline.localisation.global_oracle).

On a finished study run directory (its config, scene, evaluation reads), with the
propagation cache given (``--cache``, default the study's), it times the oracle's parts
in one run and prints them against the exhaustive oracle, which would trace every
(slot, candidate) pair with the study's tracer:

- coarse: the specular image-method model's local means over every candidate cell
  (cached after the first run);
- fine: the study tracer's links to the window centres (cached after the first run) and
  the scoring of the windows (always);
- the windows scored as dense blocks (``propagation.anchored.window_gains_db``) against
  the per-link form (``anchored_gains_db`` on every (slot, candidate) pair), one warm
  search each: the time ratio and the largest difference of the log posteriors;
- tags/s of the whole search, the traced links against the exhaustive count, and the
  exhaustive oracle's time estimated at this run's own tracing rate (links/s of the
  fine pass; only meaningful when the fine pass traced, i.e. from a cache without them).

Prints the oracle's tag errors (median, p90, within 0.5 m), the truth-preferred
diagnostic, and the parts' times. Run it once from a cache holding only the study's own
traces (cold oracle), once more for the warm cost:

    RFIDSTUDY_CACHE=... .venv/bin/python bench/oracle.py runs/default
"""

from __future__ import annotations

import argparse
import time

import numpy as np


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("run", help="a finished study run directory")
    ap.add_argument("--cache", default=None, help="propagation cache (default: the study's)")
    args = ap.parse_args()

    from pipeline.acquisition import read_table
    from pipeline.config import load_config
    from pipeline.localisation import OracleLikelihood, observations_from_reads
    from pipeline.localisation.global_oracle import OracleSearch, coarse_posteriors, global_oracle
    from pipeline.studyscene import (
        antenna_tilts,
        link_budget,
        resolve_cache_dir,
        select_backend,
        study_scene,
        tag_candidates,
        trace_options,
    )

    cfg = load_config(f"{args.run}/config.toml")
    select_backend(cfg)
    cache = args.cache or resolve_cache_dir(cfg)
    sc, split = study_scene(cfg)
    tags = sc.tags.subset(split == "eval")
    eval_reads, _ = read_table(f"{args.run}/eval_reads.parquet")
    train_reads, _ = read_table(f"{args.run}/reads.parquet")
    ids = list(tags.ids)
    obs = observations_from_reads(eval_reads, "est", tag_ids=ids, pitch_rad=antenna_tilts(cfg))
    true_obs = observations_from_reads(eval_reads, "true", tag_ids=ids, pitch_rad=antenna_tilts(cfg))
    cand = tag_candidates(sc, cfg)
    oracle = OracleLikelihood.from_reader(cfg.reader, frequency_hz=cfg.frequency_hz)
    q = None
    if cfg.reader.inventory == "gen2":
        from pipeline.acquisition.singulation import miss_probability_at_poses

        q = miss_probability_at_poses(eval_reads, true_obs.slot_poses, cfg.reader, link_budget(cfg),
                                      extra_tags=0, n_antennas=len(cfg.robot.antennas))
    opts = trace_options(cfg)
    pattern_kw = {k: getattr(opts, k) for k in ("reader_pattern", "reader_polarization", "tag_pattern")}
    d_read = train_reads.loc[train_reads["read"].to_numpy(bool), "d_true_m"].to_numpy(float)
    dn = cfg.downstream
    search = OracleSearch(window_m=dn.oracle_window_m,
                          reach_m=max(dn.oracle_reach_m, 1.1 * float(d_read.max())))

    t0 = time.perf_counter()
    coarse = coarse_posteriors(obs, true_obs.slot_poses, cand, sc, oracle, search=search,
                               frequency_hz=cfg.frequency_hz, pattern_kw=pattern_kw,
                               miss_probability=q, cache_dir=cache)
    t_coarse = time.perf_counter() - t0
    t0 = time.perf_counter()
    res = global_oracle(obs, true_obs.slot_poses, cand, sc, oracle, search=search,
                        frequency_hz=cfg.frequency_hz, trace=opts, pattern_kw=pattern_kw,
                        cache_dir=cache, miss_probability=q)
    t_search = time.perf_counter() - t0
    t0 = time.perf_counter()
    again = global_oracle(obs, true_obs.slot_poses, cand, sc, oracle, search=search,
                          frequency_hz=cfg.frequency_hz, trace=opts, pattern_kw=pattern_kw,
                          cache_dir=cache, miss_probability=q)
    t_warm = time.perf_counter() - t0
    assert np.array_equal(again.posteriors.map_m, res.posteriors.map_m), "cached rerun differs"

    import pipeline.localisation.global_oracle as oracle_mod

    # the name the global oracle calls (imported there at module level)
    dense = oracle_mod.window_gains_db
    oracle_mod.window_gains_db = _per_link_window
    try:
        t0 = time.perf_counter()
        per_link = global_oracle(obs, true_obs.slot_poses, cand, sc, oracle, search=search,
                                 frequency_hz=cfg.frequency_hz, trace=opts, pattern_kw=pattern_kw,
                                 cache_dir=cache, miss_probability=q)
        t_per_link = time.perf_counter() - t0
    finally:
        oracle_mod.window_gains_db = dense
    finite = np.isfinite(again.posteriors.log_posterior)
    assert np.array_equal(finite, np.isfinite(per_link.posteriors.log_posterior)), \
        "dense and per-link windows differ in which candidates they score"
    d_lp = float(np.max(np.abs(per_link.posteriors.log_posterior[finite]
                               - again.posteriors.log_posterior[finite]), initial=0.0))

    err = np.linalg.norm(res.posteriors.map_m - tags.positions_m, axis=1)
    exhaustive = obs.n_slots * len(cand)
    fine_cold = max(t_search - t_warm, 1e-9)  # the fine pass's tracing (coarse cached by then)
    rate = res.n_traced_links / fine_cold
    print(f"study {args.run}: {obs.n_tags} tags, {obs.n_slots} slots, {len(cand)} candidates")
    print(f"oracle tag error: median {np.median(err):.2f} m, p90 {np.percentile(err, 90):.2f} m, "
          f"within 0.5 m {np.mean(err <= 0.5):.0%}")
    print(f"coarse pass (specular model, {coarse[4]} links): {t_coarse:.1f} s")
    print(f"search (coarse from cache + fine: {res.n_traced_links} traced links, "
          f"{sum(len(c) for c in res.centres_m)} centres): {t_search:.1f} s; "
          f"warm rerun {t_warm:.1f} s ({obs.n_tags / t_warm:.2f} tags/s)")
    print(f"warm search, windows per link (anchored_gains_db): {t_per_link:.1f} s; dense blocks / "
          f"per link = {t_warm / t_per_link:.2f}; largest log-posterior difference {d_lp:.1e}")
    print(f"traced links / exhaustive {exhaustive}: {res.n_traced_links / exhaustive:.4f}")
    if t_search - t_warm > max(5.0, 0.5 * t_warm):  # else the fine links came from the cache
        print(f"fine tracing rate this run: {rate:.0f} links/s -> exhaustive oracle "
              f"~{exhaustive / rate / 3600:.1f} h")
    else:
        print("the fine links were cached before this run: no tracing rate measured")


def _per_link_window(paths, pos_index, poses, anchor_m, targets_m, target_normal, frequency_hz,
                     **pattern_kw):
    """``window_gains_db`` computed link by link with ``anchored_gains_db`` (the reference)."""
    from propagation.anchored import anchored_gains_db

    s, m = np.meshgrid(np.arange(len(pos_index)), np.arange(len(targets_m)), indexing="ij")
    s, m = s.ravel(), m.ravel()
    gains = anchored_gains_db(paths, np.asarray(pos_index)[s], np.reshape(anchor_m, (1, 3)),
                              np.zeros(len(s), int), np.asarray(targets_m)[m],
                              np.tile(target_normal, (len(s), 1)), np.asarray(poses)[s],
                              frequency_hz, **pattern_kw)
    return gains.reshape(len(pos_index), len(targets_m))


if __name__ == "__main__":
    main()
