"""The study's stage list, and what the CLI and sweeps need around it.

Stages, in order (inputs in brackets; each also depends on its upstream stages)::

    scene         load the scene, write scene/ (summary, tags, floor plan)   [scene]
    tour          guided tour + evaluation path, odometry, laser, MCL        [robot, tour, localisation]
    reads         ray-traced reader simulation -> reads/poses Parquet         [reader, tracing]
    training_sets SSM / TDM samples (MCL and true poses)                       [training bins]
    models        FCM + ANFIS (SSM, TDM; MCL and true poses), baselines        [training fit]
    truth         detection truth grid, Fig. 6 traced points, RSSI fields      [evaluation]
    evaluation    metrics.json                                                 [evaluation]
    figures       figures/*.png (pipeline.figures.draw_all)
    report        report.html

The scene stage always runs (it is cheap) so an edited scene file changes its
outputs' digest and everything downstream re-runs.
"""

from __future__ import annotations

import importlib.metadata as _md
import logging
import platform
from pathlib import Path

from pipeline.config import StudyConfig
from pipeline.stages_data import resolve_cache_dir, stage_reads, stage_scene, stage_tour
from pipeline.stages_model import stage_evaluation, stage_models, stage_training_sets, stage_truth
from pipeline.study import Stage

__all__ = [
    "STAGES",
    "corridor_coverage",
    "draw_figures",
    "draw_scene_top_view",
    "manifest_info",
    "resolve_cache_dir",
    "run_summary",
    "stage_names",
]

log = logging.getLogger(__name__)

_TRACING = ("frequency_hz", "tracing.max_depth", "tracing.samples_per_src", "tracing.reader_pattern",
            "tracing.tag_pattern", "tracing.reader_polarization", "tracing.backend")


def _stage_figures(ctx) -> dict:
    paths = draw_figures(ctx.store.root, ctx.staging_dir / "figures")
    return {"n_files": len(paths)}


def _stage_report(ctx) -> dict:
    from pipeline.report import write_report

    write_report(ctx.store.root, out=ctx.out("report.html"))
    return {}


STAGES: tuple[Stage, ...] = (
    Stage("scene", stage_scene, ("scene", "seed", "tour.max_length_m", "evaluation.n_eval_tags",
                                 "evaluation.eval_tag_min_separation_m",
                                 "evaluation.eval_tag_heights_m", "training.d_max_m"),
          (), version=2,  # 2: held-out tag layout (tags.parquet split)
          description="load the scene", always=True),
    Stage("tour", stage_tour, ("seed", "robot", "tour", "localisation"), ("scene",),
          version=2,  # 2: one biased robot map per building (tour/map_error.npz, localisation.json)
          description="robot tours and MCL"),
    Stage("reads", stage_reads, ("seed", "robot", "reader") + _TRACING, ("scene", "tour"),
          version=2,  # 2: each tour reads its own tag layout; range-margin check in metadata
          description="ray-traced reader simulation"),
    Stage("training_sets", stage_training_sets,
          ("training.d_max_m", "training.rssi_range_dbm", "training.d_bin_m",
           "training.alpha_bin_deg", "training.min_attempts", "training.n_clusters"),
          ("reads",), description="training sets"),
    Stage("models", stage_models, ("seed", "training"), ("training_sets", "reads"),
          version=2,  # 2: competitors and ablations (pipeline.sensormodels)
          description="FCM + ANFIS"),
    Stage("truth", stage_truth,
          ("seed", "reader", "evaluation", "training.d_max_m", "training.d_bin_m",
           "training.alpha_bin_deg", "tracing.field_cell_m", "tracing.field_samples_per_tx")
          + _TRACING,
          ("scene", "reads", "models"), version=2,  # 2: held-out grid, tag sites, eval poses
          description="propagation truth"),
    Stage("evaluation", stage_evaluation, ("reader", "evaluation", "training", "robot"),
          ("scene", "tour", "reads", "models", "truth"),
          version=5,  # 2: coverage, fig7 table; 3: RSSI floor; 4: held-out sections; 5: range margin
          description="metrics"),
    Stage("figures", _stage_figures, (), ("scene", "tour", "reads", "models", "truth", "evaluation"),
          description="figures"),
    Stage("report", _stage_report, (), ("figures", "evaluation"), description="report.html"),
)


def stage_names() -> list[str]:
    """Names of the study's stages, in order."""
    return [s.name for s in STAGES]


def draw_figures(run_dir: str | Path, out_dir: str | Path) -> list[Path]:
    """Every figure of a run, from the run directory's files alone (pipeline.figures.draw_all).

    Returns
    -------
    list of pathlib.Path
        Files written under ``out_dir``.
    """
    from pipeline.figures import draw_all

    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    res = draw_all(Path(run_dir), out_dir=out)
    if isinstance(res, dict):
        res = [p for v in res.values() for p in (v if isinstance(v, (list, tuple)) else [v])]
    return [Path(p) for p in (res or [])]


def draw_scene_top_view(scene, png: str | Path) -> Path:
    """Top view of a scene (walls at laser height, tags, route) as PNG, via pipeline.figures."""
    from pipeline.figures import scene_top_view

    png = Path(png)
    png.parent.mkdir(parents=True, exist_ok=True)
    return Path(scene_top_view(scene, png))


def _version(dist: str) -> str | None:
    try:
        return _md.version(dist)
    except _md.PackageNotFoundError:
        return None


def manifest_info(cfg: StudyConfig) -> dict:
    """Package versions, platform and the Dr.Jit backend for ``manifest.json``."""
    dists = ["rfidstudy", "sionna-rt", "mitsuba", "drjit", "numpy", "scipy", "scikit-fuzzy",
             "trimesh", "pandas", "pyarrow", "matplotlib", "dask", "distributed"]
    info = {
        "versions": {d: _version(d) for d in dists},
        "python": platform.python_version(),
        "platform": platform.platform(),
        "cache_dir": str(resolve_cache_dir(cfg)),
    }
    try:
        import propagation

        info["backend"] = propagation.backend_info()
    except Exception as exc:  # the manifest must not fail the study
        info["backend"] = {"error": f"{type(exc).__name__}: {exc}"}
    return info


def run_summary(run_dir: str | Path) -> dict:
    """One sweep-summary row from a finished run directory's files.

    Read rate, tag coverage and corridor coverage come from ``metrics.json`` where the
    evaluation wrote them, else they are counted from ``reads.parquet`` (reads over
    in-range attempts; tags read at least once over all tags). Model errors are taken
    from ``metrics.json``.
    """
    import json

    import pandas as pd

    run = Path(run_dir)
    row: dict = {}
    reads = pd.read_parquet(run / "reads.parquet", columns=["tag_id", "read", "in_range"])
    scene_info = json.loads((run / "scene" / "scene.json").read_text())
    n_tags = scene_info.get("n_tags_train", scene_info["n_tags"])  # the training tour's layout
    in_range = reads["in_range"].to_numpy(bool)
    read = reads["read"].to_numpy(bool)
    row["n_attempts_in_range"] = int(in_range.sum())
    row["n_reads"] = int(read.sum())
    row["read_rate"] = float(read.sum() / max(in_range.sum(), 1))
    row["tag_coverage"] = float(reads.loc[read, "tag_id"].nunique() / max(n_tags, 1))
    mpath = run / "metrics.json"
    if mpath.exists():
        metrics = json.loads(mpath.read_text())
        row.update(_metric_columns(metrics))
    cov = corridor_coverage(run)
    if cov is not None:
        row["corridor_coverage"] = cov
    return row


def _find(d, *path):
    for p in path:
        if not isinstance(d, dict) or p not in d:
            return None
        d = d[p]
    return d if isinstance(d, (int, float)) else None


def _metric_columns(metrics: dict) -> dict:
    """Sweep columns from metrics.json: the learned model's HELD-OUT scores (older run
    directories without a ``heldout`` section: their single ``models`` section)."""
    m = metrics.get("evaluation", metrics)
    out = {}
    if isinstance(m.get("heldout"), dict):
        paths = {
            "ssm_rmse_db": ("heldout", "models", "anfis", "rssi_dbm", "rmse"),
            "tdm_rmse": ("heldout", "models", "anfis", "detection", "rmse"),
            "brier": ("heldout", "models", "anfis", "detection", "brier"),
            "floor_rmse_db": ("heldout", "floor", "rssi_dbm", "rmse"),
            "rho_rmse": ("tag_sites", "anfis", "all", "rho", "rmse"),
            "fig7_median_pct": ("fig7", "anfis", "median_pct"),
            "mcl_error_median_m": ("localisation", "eval", "position_error_median_m"),
        }
    else:
        paths = {k: ("models", "anfis", *v) for k, v in {
            "ssm_rmse_db": ("rssi_dbm", "rmse"), "tdm_rmse": ("detection", "rmse"),
            "rho_rmse": ("rho", "rmse")}.items()}
    for key, path in paths.items():
        v = _find(m, *path)
        if v is not None:
            out[key] = float(v)
    return out


def corridor_coverage(run_dir: str | Path) -> float | None:
    """Fraction of the RSSI-field plane cells (inside the scene's free space) where a tag
    would be read with probability > 0.5, averaged over the run's field poses; None
    without fields.

    Read from ``metrics.json`` (``coverage.corridor_fraction``, written by the evaluation
    stage with :func:`pipeline.evaluation.detection_coverage`); computed from
    ``fields/*.npz`` the same way for runs whose metrics predate it.
    """
    import json
    import tomllib

    import scenes
    from pipeline.config import config_from_mapping
    from pipeline.stages_model import field_coverage

    run = Path(run_dir)
    mpath = run / "metrics.json"
    if mpath.exists():
        cov = json.loads(mpath.read_text()).get("coverage")
        if isinstance(cov, dict) and "corridor_fraction" in cov:
            return float(cov["corridor_fraction"])
    files = sorted((run / "fields").glob("field_*.npz"))
    if not files:
        return None
    cfg = config_from_mapping(tomllib.loads((run / "config.toml").read_text()),
                              source=str(run / "config.toml"))
    cov = field_coverage(cfg, scenes.load(cfg.scene), files)
    return None if cov is None else cov["corridor_fraction"]
