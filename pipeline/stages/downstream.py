"""Stage ``downstream``: localise the held-out tags, then the robot, with each sensor model,
the ray-traced oracle and, where the read table has phases, the phase estimator
(:mod:`pipeline.localisation.phase`; ``tag_localisation.phase`` says why when it did not
run); writes ``downstream/scores.json``, ``downstream/tag_errors.parquet`` and
``downstream/robot_error.parquet``, which the evaluation stage copies into ``metrics.json``
(``tag_localisation.<model>``, ``robot_localisation.<model>``).

On a recorded study (``[recording]``, :data:`pipeline.stages.RECORDED_STAGES`) the stage
localises the held-out tags only (:func:`_recorded_downstream`), with every fitted model
and the same candidates, from the recording's reads of them on the recorded poses (the
``est_`` columns; a recording's ``true_`` columns are the same poses, and the models see
``d_est_m``), scored against the positions in the recording's tags CSV: the ground truth a
real user has. What it leaves out, and why, is written in ``scores.json``:

- the robot filter (not run): it is scored against the true robot track, and a
  recording's poses are the only track there is, the best estimate of where the robot
  was (the filter's error would be its distance to another estimate, not to the truth;
  the recorded ``eval_poses.parquet`` has no odometry to drive it either).
  ``robot_localisation`` is a sentence saying so (:data:`RECORDED_ROBOT`);
- the oracle (not run, whatever ``downstream.oracle`` says): it could run, the scene is
  known and the recorded poses can be traced, but on a recording it is no oracle (its
  likelihood is the simulated reader's given traced gains, not what wrote the log) and
  it costs minutes of tracing; ``sim_vs_real`` scores the tracer against the log. With
  ``downstream.oracle = true`` ``tag_localisation.oracle`` says it was not run;
- the phase estimator runs where the recording's reads have phases (Impinj reports and
  ROS 2 bags may; a ``sllurp log`` CSV has none): else ``phase`` / ``phase_anfis`` say
  why, as in a simulated study whose reads carry none."""

from __future__ import annotations

import numpy as np

from pipeline import runfiles
from pipeline.acquisition.singulation import miss_probability_at_poses
from pipeline.engine.runstore import atomic_write_json
from pipeline.engine.study import Stage
from pipeline.evaluation.tables import write_parquet_atomic
from pipeline.localisation import (
    OracleLikelihood,
    RfidMCLConfig,
    as_free_space,
    localise_tags,
    observations_from_reads,
)
from pipeline.localisation.benchmark import (
    DetectionOnly,
    RobotRuns,
    model_sources,
    phase_posteriors,
    tag_localisation_scores,
)
from pipeline.localisation.global_oracle import OracleSearch, global_oracle
from pipeline.localisation.robot_oracle import FieldLikelihood, gain_field
from pipeline.parallel import map_forked
from pipeline.robot import collision_map
from pipeline.runfiles import STAGE_OUTPUTS
from pipeline.sensormodels.registry import load_models, model_info, stage_version
from pipeline.stages.common import TRACING_KEYS, load_scene, read_reads, split_tags
from pipeline.studyscene import (
    antenna_tilts,
    build_robot,
    link_budget,
    resolve_cache_dir,
    select_backend,
    stage_rng,
    tag_candidates,
    trace_options,
)

__all__ = ["RECORDED_ROBOT", "STAGE", "stage_downstream"]

#: Why a recorded study does not localise the robot (``scores.json``, ``metrics.json``).
RECORDED_ROBOT = ("not run: a recording's poses are the only track, so there is no truth to "
                  "score an RFID-only robot filter against")


def _models(ctx) -> dict:
    """The sensor models localised with: every model of the registry scored ``downstream``
    (the learned one, both baselines, the chapter's competitors and the ablations), in its
    study order; a ``"detection"`` model that predicts RSSI too localises with its
    detection alone (the grid count: Hähnel's counts, not the log-distance RSSI)."""
    models = load_models(ctx.input, "downstream")
    return {k: DetectionOnly(m) if model_info(k).kind == "detection"
            and getattr(m, "predicts_rssi", True) else m for k, m in models.items()}


def _solver_and_patterns(cfg) -> tuple:
    """The study tracer's options (``propagation.TraceOptions``) and its pattern names."""
    opts = trace_options(cfg)
    return opts, {k: getattr(opts, k) for k in ("reader_pattern", "reader_polarization", "tag_pattern")}


def _oracle_posteriors(ctx, obs, reads, eval_reads, eval_tags, cand) -> tuple[dict, dict]:
    """The oracle's posteriors (coarse-to-fine global search) and what it cost."""
    cfg = ctx.config
    dn = cfg.downstream
    sc = load_scene(ctx)
    index = {t: i for i, t in enumerate(eval_tags.ids.tolist())}
    rows = [index[t] for t in obs.tag_ids]
    true_obs = observations_from_reads(eval_reads, "true", tag_ids=list(obs.tag_ids),
                                       pitch_rad=antenna_tilts(cfg))
    oracle = OracleLikelihood.from_reader(cfg.reader, frequency_hz=cfg.frequency_hz)
    # the Gen2 reader's miss probability per slot: the candidate is the localised tag,
    # one of the log's (counted where its true link closes)
    q = None
    if cfg.reader.inventory == "gen2":
        q = miss_probability_at_poses(eval_reads, true_obs.slot_poses, cfg.reader,
                                      link_budget(cfg), extra_tags=0,
                                      n_antennas=len(cfg.robot.antennas))
    opts, pattern_kw = _solver_and_patterns(cfg)
    # the coarse pass must reach every read: at least the longest training read (+10 %)
    d_read = reads.loc[reads["read"].to_numpy(bool), "d_true_m"].to_numpy(float)
    reach = max(dn.oracle_reach_m, 1.1 * float(d_read.max()) if len(d_read) else 0.0)
    res = global_oracle(obs, true_obs.slot_poses, cand, sc, oracle,
                        search=OracleSearch(window_m=dn.oracle_window_m, reach_m=reach),
                        frequency_hz=cfg.frequency_hz, trace=opts, pattern_kw=pattern_kw,
                        cache_dir=resolve_cache_dir(cfg), miss_probability=q,
                        truth_m=eval_tags.positions_m[rows], truth_normals=eval_tags.normals[rows])
    err = np.linalg.norm(res.posteriors.map_m - eval_tags.positions_m[rows], axis=1)
    info = {"model_links": res.n_model_links, "traced_links": res.n_traced_links,
            "traced_centres": int(sum(len(c) for c in res.centres_m)), "reach_m": reach,
            # the exactly traced truth scores higher than an estimate more than a window
            # away: the search missed the truth's basin (not the reads' ambiguity)
            "search_missed": int(np.sum(res.truth_preferred & (err > dn.oracle_window_m)))}
    return {"oracle": res.posteriors}, info


def _robot_oracle(ctx, eval_tags, free):
    """The robot filter's oracle: the traced local-mean gain field over the free space."""
    cfg = ctx.config
    opts, pattern_kw = _solver_and_patterns(cfg)
    field = gain_field(load_scene(ctx), list(build_robot(cfg).antennas), eval_tags.positions_m,
                       eval_tags.normals, free, frequency_hz=cfg.frequency_hz, trace=opts,
                       pattern_kw=pattern_kw, cache_dir=resolve_cache_dir(cfg))
    oracle = OracleLikelihood.from_reader(cfg.reader, frequency_hz=cfg.frequency_hz)
    return FieldLikelihood(oracle, field), field.n_traced_links


def _tag_work(ctx, obs, reads, eval_reads, eval_tags, sources, *,
              no_phase: str | None = None) -> tuple:
    """The held-out tags' candidates and posteriors of every model and of the phase
    estimator (NumPy only: safe in a forked process); ``no_phase``: why the phase
    estimator does not run (it then does not)."""
    cand = tag_candidates(load_scene(ctx), ctx.config)
    posts = localise_tags(obs, cand, sources)
    if no_phase is not None:
        return cand, posts, {"run": False, "reason": no_phase}
    # the phase estimator's candidates: within the farthest training read of a pose that
    # read the tag; sub-apertures of 1 m of antenna travel (MCL drifts: on the tiny study
    # they halve the horizontal error against whole-track groups, on exact poses they
    # cost nothing)
    d_read = reads.loc[reads["read"].to_numpy(bool), "d_est_m"].to_numpy(float)
    reach = float(np.max(d_read)) if len(d_read) else None
    post_p, phase_info = phase_posteriors(eval_reads, list(eval_tags.ids), cand,
                                          reach_m=reach, combine_with=posts["anfis"],
                                          segment_m=1.0)
    posts.update(post_p)
    return cand, posts, phase_info


def _tag_scores(ctx, posts, eval_tags, phase_info) -> dict:
    """Each source's tag localisation scores (``phase`` / ``phase_anfis`` saying why they
    did not run); writes every tag's error to ``downstream/tag_errors.parquet``."""
    import pandas as pd


    tag_scores = tag_localisation_scores(posts, eval_tags)
    if not phase_info["run"]:  # recorded, never silently left out
        for name in ("phase", "phase_anfis"):
            tag_scores[name] = {"not_run": phase_info["reason"]}
    rows = [{"model": n, "tag_id": t, "error_m": e} for n, s in tag_scores.items()
            for t, e in s.pop("per_tag_m", {}).items()]
    write_parquet_atomic(pd.DataFrame(rows), ctx.out(runfiles.TAG_ERRORS))
    return tag_scores


def _tag_inputs(ctx) -> tuple:
    """The held-out tags, both read logs (the held-out one's metadata), every model's
    likelihood source and the held-out tags' observations on the estimated poses."""
    cfg = ctx.config
    eval_tags = split_tags(ctx, "eval")
    reads, _ = read_reads(ctx)
    eval_reads, meta = read_reads(ctx, "eval_")
    sources = model_sources(_models(ctx), reads, cfg.training.d_max_m)
    obs = observations_from_reads(eval_reads, "est", tag_ids=list(eval_tags.ids),
                                  pitch_rad=antenna_tilts(cfg))
    return eval_tags, reads, eval_reads, meta, sources, obs


def _recorded_downstream(ctx) -> dict:
    """A recorded study's held-out tags localised with every model (module doc): writes
    ``downstream/scores.json`` and ``downstream/tag_errors.parquet``."""

    cfg = ctx.config
    eval_tags, reads, eval_reads, meta, sources, obs = _tag_inputs(ctx)
    phase = eval_reads["phase_rad"].to_numpy(np.float64)[eval_reads["read"].to_numpy(bool)]
    no_phase = None if np.isfinite(phase).any() else (
        "the recording's reads of the held-out tags carry no backscatter phase "
        f"(a {(meta or {}).get('format', 'recording')} log without phases), so the phase "
        "estimator cannot run")
    cand, posts, phase_info = _tag_work(ctx, obs, reads, eval_reads, eval_tags, sources,
                                        no_phase=no_phase)
    info = {"n_tags": int(len(eval_tags)), "n_candidates": int(len(cand)), "phase": phase_info,
            "truth": "the held-out tags' positions in the recording's tags file"}
    tag_scores = _tag_scores(ctx, posts, eval_tags, phase_info)
    if cfg.downstream.oracle:
        tag_scores["oracle"] = {"not_run": "not run on a recording: the traced likelihood is "
                                "no oracle of a real log (sim_vs_real scores the tracer against "
                                "it; pipeline.stages.downstream)"}
    atomic_write_json(ctx.out(runfiles.DOWNSTREAM_SCORES),
                      {"tag_localisation": tag_scores, "robot_localisation": RECORDED_ROBOT,
                       "info": info})
    return info


def stage_downstream(ctx) -> dict:
    """Tag localisation (every model + oracle) and RFID-only robot localisation; on a
    recording the held-out tags alone, without the oracle (module doc)."""
    import pandas as pd


    cfg = ctx.config
    dn = cfg.downstream
    if not dn.enabled:
        return {"enabled": False}
    if cfg.recording.enabled:
        return _recorded_downstream(ctx)
    select_backend(cfg)
    sc = load_scene(ctx)
    robot = build_robot(cfg)
    eval_tags, reads, eval_reads, _, sources, obs = _tag_inputs(ctx)
    update = ctx.progress("tags and robot", total=3)
    eval_poses = pd.read_parquet(ctx.input(runfiles.EVAL_POSES))
    free = as_free_space(collision_map(sc, robot))
    robot_sources = dict(sources)
    if dn.oracle:  # traced here, before any fork
        robot_sources["oracle"], robot_field_links = _robot_oracle(ctx, eval_tags, free)
    runs = RobotRuns(robot_sources, obs, eval_tags, eval_poses, list(robot.antennas), free,
                     stage_rng(cfg, "downstream"),
                     config=RfidMCLConfig(n_particles=dn.robot_particles), n_runs=dn.robot_runs)

    # the tags' posteriors and the robot filter's runs are independent: one pool of forked
    # processes computes both, the tag work first (the longest task), so that the filter
    # runs fill the other processes meanwhile
    def task(i: int):
        if i == 0:
            return _tag_work(ctx, obs, reads, eval_reads, eval_tags, sources)
        return runs.run(i - 1)

    results = map_forked(task, 1 + len(runs), None)
    cand, posts, phase_info = results[0]
    info = {"n_tags": int(len(eval_tags)), "n_candidates": int(len(cand)), "phase": phase_info}
    robot_scores = runs.scores(results[1:])
    update(advance=1)
    if dn.oracle:
        post_o, info["oracle"] = _oracle_posteriors(ctx, obs, reads, eval_reads, eval_tags, cand)
        info["oracle"]["robot_field_links"] = robot_field_links
        posts.update(post_o)
    update(advance=1)
    tag_scores = _tag_scores(ctx, posts, eval_tags, info["phase"])
    update(advance=1)
    rrows, steps = [], []
    for n, s in robot_scores.items():
        t, e = s.pop("t_s"), s.pop("error_m")
        rrows += [{"model": n, "t_s": a, "error_m": b} for a, b in zip(t, e, strict=True)]
        for j, run in enumerate(s.pop("runs_steps")):
            steps.append(pd.DataFrame({
                "model": n, "unit": f"run{j}", "t_s": run["t_s"], "error_m": run["error_m"],
                "after_kidnap": run["after_kidnap"], "converge_s": run["converge_s"],
                "recover_s": np.nan if run["recover_s"] is None else run["recover_s"]}))
    write_parquet_atomic(pd.DataFrame(rrows), ctx.out(runfiles.ROBOT_ERROR))
    # every step of every filter run: what the robot's intervals resample (by run)
    write_parquet_atomic(pd.concat(steps, ignore_index=True),
                         ctx.out(runfiles.ROBOT_STEPS))
    atomic_write_json(ctx.out(runfiles.DOWNSTREAM_SCORES),
                      {"tag_localisation": tag_scores, "robot_localisation": robot_scores,
                       "info": info})
    return info


STAGE = Stage("downstream", stage_downstream,
              ("seed", "downstream", "training.d_max_m", "reader",
               "robot") + TRACING_KEYS,
              ("scene", "tour", "reads", "models"), version=stage_version(12),
              # each version's change: CHANGELOG.md
              description="downstream localisation (tags, robot)",
              outputs=STAGE_OUTPUTS["downstream"])
