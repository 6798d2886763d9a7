"""Stage ``reads``: the ray-traced reader simulation along both tours; the training tour
reads the training tags, the evaluation path the held-out ones (``pipeline.acquisition``,
``propagation``); writes ``reads.parquet``, ``poses.parquet`` and their ``eval_`` twins."""

from __future__ import annotations

from pipeline.acquisition import simulate_reads
from pipeline.engine.study import Stage
from pipeline.engine.tracetasks import trace_tasks
from pipeline.runfiles import STAGE_OUTPUTS
from pipeline.stages.common import TRACING_KEYS, load_scene, read_track, split_tags
from pipeline.studyscene import (
    build_robot,
    resolve_cache_dir,
    select_backend,
    stage_rng,
    trace_options,
)

__all__ = ["STAGE", "stage_reads"]


def stage_reads(ctx) -> dict:
    """Simulate the reader along both tracks (ray-traced); write reads/poses Parquet files.

    The ``[reader]`` section is the acquisition package's own
    :class:`pipeline.acquisition.ReaderConfig`, traced at the study's ``frequency_hz``;
    each attempt's gain, phase and Doppler are those of its regional channel.
    """
    cfg = ctx.config
    variant = select_backend(cfg)
    sc = load_scene(ctx)
    robot = build_robot(cfg)
    cache = resolve_cache_dir(cfg)
    cache.mkdir(parents=True, exist_ok=True)
    rng = stage_rng(cfg, "reads")
    info = {"variant": variant, "cache_dir": str(cache)}
    with trace_tasks(cfg) as tasks:  # tracing.scheduler: chunks as Dask tasks
        for name, prefix in (("train", ""), ("eval", "eval_")):
            track = read_track(ctx, name)
            # held out: the training tour reads only the training tags, the evaluation tour
            # only the held-out ones
            tags = split_tags(ctx, name)
            readlog = simulate_reads(sc, robot, track, cfg.reader, rng, trace=trace_options(cfg), cache_dir=cache,
                                     progress=ctx.progress(f"tracing {name} links"),
                                     tags=tags, frequency_hz=cfg.frequency_hz)
            readlog.write(ctx.staging_dir, prefix=prefix)
            info[name] = {"n_attempts": readlog.n_attempts, "n_reads": readlog.n_reads,
                          "n_pairs_traced": readlog.metadata.get("n_pairs_traced"),
                          "n_sources_traced": readlog.n_sources_traced}
    if tasks is not None:
        info["trace_tasks"] = tasks.as_dict()
    return info


STAGE = Stage("reads", stage_reads, ("seed", "robot", "reader") + TRACING_KEYS, ("scene", "tour"),
              version=6,  # each version's change: CHANGELOG.md
              description="ray-traced reader simulation",
              outputs=STAGE_OUTPUTS["reads"])
