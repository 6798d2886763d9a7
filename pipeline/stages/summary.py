"""What sweeps read from a finished run directory: one summary row per run."""

from __future__ import annotations

from pathlib import Path

import scenes
from pipeline import runfiles
from pipeline.config import config_from_mapping, read_toml
from pipeline.engine.runstore import inside, run_files
from pipeline.evaluation.inventory import inventory_statistic, tour_tag_table
from pipeline.stages.evaluation import field_coverage
from scenes.fileio import read_npz

__all__ = ["corridor_coverage", "inventory_summary", "run_summary", "tour_tags"]


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
    if (run / runfiles.REPLICATES_INDEX).is_file():  # a replicated study: their mean
        reps = sorted((p for p in (run / "replicates").iterdir()
                       if p.name.isdecimal() and (p / runfiles.METRICS).is_file()),
                      key=lambda p: int(p.name))
        rows = pd.DataFrame([run_summary(p) for p in reps])
        out = {k: float(rows[k].mean()) for k in rows.columns
               if pd.api.types.is_numeric_dtype(rows[k])}
        out["n_replicates"] = len(reps)
        return out
    row: dict = {}
    reads = pd.read_parquet(run / runfiles.TRAIN_READS, columns=["tag_id", "read", "in_range"])
    scene_info = json.loads((run / runfiles.SCENE_SUMMARY).read_text())
    n_tags = scene_info.get("n_tags_train", scene_info["n_tags"])  # the training tour's layout
    in_range = reads["in_range"].to_numpy(bool)
    read = reads["read"].to_numpy(bool)
    row["n_attempts_in_range"] = int(in_range.sum())
    row["n_reads"] = int(read.sum())
    row["read_rate"] = float(read.sum() / max(in_range.sum(), 1))
    row["tag_coverage"] = float(reads.loc[read, "tag_id"].nunique() / max(n_tags, 1))
    mpath = run / runfiles.METRICS
    if mpath.exists():
        metrics = json.loads(mpath.read_text())
        row.update(_metric_columns(metrics))
    # counted at the tags, on point-to-point links: the former plane coverage (one field
    # plane at one height) had an artefact with the antenna at the plane's height
    row.update(inventory_summary(run))
    return row


def tour_tags(run_dir: str | Path, budget=None):
    """The training tour's counts per (tag, pass) of a finished run directory
    (:func:`pipeline.evaluation.inventory.tour_tag_table` on its ``reads.parquet``,
    ``tour/train_track.npz`` and ``scene/tags.parquet``, every file read through
    :func:`pipeline.engine.runstore.inside`); ``budget`` defaults to the run's own
    ``config.toml``. None for a run whose track predates ``pass_index``."""
    import pandas as pd


    run = Path(run_dir)
    with read_npz(inside(run, runfiles.TRAIN_TRACK)) as z:
        if "pass_index" not in z.files:
            return None
        t_s, passes = z["t_s"], z["pass_index"]
    if budget is None:
        path = inside(run, "config.toml")
        cfg = config_from_mapping(read_toml(path), source=str(path))
        budget = cfg.reader.link_budget(cfg.frequency_hz)
    reads = pd.read_parquet(inside(run, runfiles.TRAIN_READS),
                            columns=["time_s", "cycle", "antenna", "tag_id", "read", "in_range",
                                     "gain_db"])
    tags = pd.read_parquet(inside(run, runfiles.SCENE_TAGS), columns=["tag_id", "z_m"])
    return tour_tag_table(reads, t_s, passes, tags, budget)


def inventory_summary(run_dir: str | Path, min_reads: int = 3) -> dict:
    """``completeness`` (share of (tag, pass) read >= ``min_reads`` times) and
    ``surface_coverage`` (route share along which each tag's link closes) of the run's
    training tour (:mod:`pipeline.evaluation.inventory`); empty for a run directory
    whose track predates ``pass_index``."""
    import numpy as np


    rows = tour_tags(run_dir)
    if rows is None:
        return {}
    units, codes = np.unique(rows["unit"].to_numpy(), return_inverse=True)
    w = np.ones(len(units))
    return {k: float(inventory_statistic(k, rows, codes, len(units), min_reads=min_reads)(w))
            for k in ("completeness", "surface_coverage")}


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
            "bound_rmse_db": ("heldout", "bound", "rssi_dbm", "rmse"),
            "rho_rmse": ("tag_sites", "anfis", "all", "rho", "rmse"),
            "fig7_median_pct": ("fig7", "anfis", "median_pct"),
            "mcl_error_median_m": ("localisation", "eval", "position_error_median_m"),
        }
        # the downstream score: an antenna-placement what-if judged by localisation
        for name in (m.get("tag_localisation") or {}):
            paths[f"tag_localisation.{name}.median_m"] = ("tag_localisation", name, "median_m")
        robot = m.get("robot_localisation")  # a sentence on a recording: not run
        for name in (robot if isinstance(robot, dict) else {}):
            paths[f"robot_localisation.{name}.median_m"] = ("robot_localisation", name, "median_m")
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


    run = Path(run_dir)
    mpath = run / runfiles.METRICS
    if mpath.exists():
        cov = json.loads(mpath.read_text()).get("coverage")
        if isinstance(cov, dict) and "corridor_fraction" in cov:
            return float(cov["corridor_fraction"])
    files = run_files(run, "fields", "field_*.npz")
    if not files:
        return None
    cfg = config_from_mapping(tomllib.loads((run / "config.toml").read_text()),
                              source=str(run / "config.toml"))
    eval_reads = None
    if (run / runfiles.EVAL_READS).is_file():  # the Gen2 truth needs the field poses' slots
        import pandas as pd

        eval_reads = pd.read_parquet(run / runfiles.EVAL_READS)
    cov = field_coverage(cfg, scenes.load(cfg.scene), files, eval_reads)
    return None if cov is None else cov["corridor_fraction"]
