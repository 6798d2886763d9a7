"""What-if sweeps: a grid of study configs run locally or on a Dask cluster.

A sweep TOML names a base study config and the values of a few parameters::

    base = "tiny.toml"            # study TOML, relative to this file ("" = defaults)
    mode = "grid"                 # "grid": Cartesian product; "zip": values side by side
    [parameters]
    antenna_height_m = [0.4, 0.8]
    tx_power_dbm = [24.0, 27.15]
    [study]                       # optional overrides of the base config (study TOML keys)
    seed = 7

``upto = "evaluation"`` (optional) stops every point after that stage: the summary reads
the points' reads and ``metrics.json`` (written by ``evaluation``), not their figures or
reports, which are most of a small study's time after its traces. Not with replicated
points (a replicated study runs every stage).

Parameters (:data:`PARAMETERS`) are antenna mounting height, yaw, tilt and count,
reader power, tag sensitivity, scene, seed and replicates; any dotted study key (``training.epochs``)
is accepted too. Every point becomes a :class:`~pipeline.config.StudyConfig` run into
``OUT/runs/<index>_<slug>/``; all runs share the propagation cache, so points that
only change antenna orientation, power or sensitivity trace nothing new where the
propagation package caches per antenna position.

Runs go to local worker processes (``concurrent.futures``, spawn context; with one
worker, one after the other in this process) or, with
``scheduler``, to a Dask distributed cluster (``distributed.Client(address)``), by
:func:`pipeline.apps.studypool.run_studies`; each point is run by
:func:`pipeline.apps.studyrun.run_full_study` (a replicated point: its replicates). The
summary (one row per point: parameters, read rate, completeness per pass, coverage
along the route at the tags, model errors; a replicated point: the replicates' mean
and ``n_replicates``) is written as Parquet and CSV, with one plot per swept
parameter, each saying what it averages over. For a ranked answer with intervals
over replicates and tags, use ``rfidstudy placement`` (:mod:`pipeline.apps.placement`).
"""

from __future__ import annotations

import dataclasses
import itertools
import logging
import re
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

from pipeline import runfiles
from pipeline.apps.studypool import run_studies
from pipeline.apps.studyrun import run_full_study
from pipeline.config import (
    ConfigError,
    StudyConfig,
    base_config,
    config_from_mapping,
    config_to_dict,
    read_toml,
    replace_path,
)
from pipeline.configschema import from_dict
from pipeline.engine.runstore import atomic_write_bytes, atomic_write_json
from pipeline.outdirs import check_marker_file, own_marker
from pipeline.stages import study_stages
from pipeline.studyscene import resolve_cache_dir

__all__ = [
    "PARAMETERS",
    "SweepPlan",
    "SweepResult",
    "apply_parameter",
    "expand_sweep",
    "load_sweep",
    "run_sweep",
]

log = logging.getLogger(__name__)

#: Named sweep parameters and what each sets in the study config.
PARAMETERS = {
    "antenna_height_m": "robot.antennas[*].z_m: mounting height of every antenna [m]",
    "antenna_yaw_deg": "robot.antennas[*].yaw_deg: |yaw| of every antenna, each keeping its side's sign [deg]",
    "antenna_tilt_deg": "robot.antennas[*].tilt_deg: tilt of every antenna [deg]",
    "antenna_count": "robot.antennas: keep the first N antennas of the base config",
    "tx_power_dbm": "reader.tx_power_dbm: conducted reader power [dBm]",
    "tag_sensitivity_dbm": "reader.tag_sensitivity_dbm: tag chip sensitivity [dBm]",
    "scene": "scene: bundled scene name or scene path",
    "seed": "seed: the study's seed (a noise estimate: the same point on other seeds)",
    "replicates": "replicates.n: replicates of each point, pooled with intervals (rfidstudy run -r)",
}

_SWEEP_KEYS = ("base", "mode", "parameters", "study", "upto")


def apply_parameter(cfg: StudyConfig, name: str, value) -> StudyConfig:
    """Return ``cfg`` with sweep parameter ``name`` set to ``value``.

    Raises
    ------
    ConfigError
        If ``name`` is neither in :data:`PARAMETERS` nor a dotted study key (the message
        lists the known parameters), or the value is invalid for it.
    """
    if name == "antenna_height_m":
        return replace_path(cfg, "robot.antennas[*].z_m", float(value))
    if name == "antenna_tilt_deg":
        return replace_path(cfg, "robot.antennas[*].tilt_deg", float(value))
    if name == "antenna_yaw_deg":
        ants = tuple(
            dataclasses.replace(a, yaw_deg=abs(float(value)) * (-1.0 if a.yaw_deg < 0 else 1.0))
            for a in cfg.robot.antennas
        )
        return dataclasses.replace(cfg, robot=dataclasses.replace(cfg.robot, antennas=ants))
    if name == "antenna_count":
        n = int(value)
        have = len(cfg.robot.antennas)
        if not 1 <= n <= have:
            raise ConfigError(f"antenna_count = {value!r}: the base config defines {have} antennas; "
                              f"give 1..{have} or define more [[robot.antennas]] in the base config")
        return dataclasses.replace(cfg, robot=dataclasses.replace(cfg.robot, antennas=cfg.robot.antennas[:n]))
    if name == "tx_power_dbm":
        return replace_path(cfg, "reader.tx_power_dbm", float(value))
    if name == "tag_sensitivity_dbm":
        return replace_path(cfg, "reader.tag_sensitivity_dbm", float(value))
    if name == "scene":
        return dataclasses.replace(cfg, scene=str(value))
    if name in ("seed", "replicates"):
        if isinstance(value, bool) or not isinstance(value, int) or value < (0 if name == "seed" else 1):
            raise ConfigError(f"{name} = {value!r}: expected an integer >= {0 if name == 'seed' else 1}")
        return replace_path(cfg, "seed" if name == "seed" else "replicates.n", int(value))
    if "." in name and "[" not in name:
        data = config_to_dict(cfg)
        cur = data
        parts = name.split(".")
        known = True
        for part in parts[:-1]:
            if not isinstance(cur.get(part), dict):
                known = False
                break
            cur = cur[part]
        if known and parts[-1] in _fields_at(cfg, parts[:-1]):
            cur[parts[-1]] = value
            return config_from_mapping(data, source=f"sweep parameter {name} = {value!r}")
    raise ConfigError(f"unknown sweep parameter {name!r}; known parameters: "
                      f"{', '.join(PARAMETERS)} (or a dotted study key such as training.epochs)")


def _fields_at(cfg, parts: list[str]) -> set[str]:
    obj = cfg
    for p in parts:
        obj = getattr(obj, p)
    return {f.name for f in dataclasses.fields(obj)}


@dataclass
class SweepPlan:
    """An expanded sweep.

    Attributes
    ----------
    base : StudyConfig
        The base study config.
    parameters : dict[str, list]
        Swept parameter -> values, in file order.
    points : list of dict
        One mapping parameter -> value per run.
    configs : list of StudyConfig
        The study config of each point.
    names : list of str
        Run directory name of each point.
    source : str
        Sweep file (for messages).
    upto : str or None
        The last stage each point runs (:func:`pipeline.stages.stages_upto`); None: all.
    """

    base: StudyConfig
    parameters: dict[str, list]
    points: list[dict] = field(default_factory=list)
    configs: list[StudyConfig] = field(default_factory=list)
    names: list[str] = field(default_factory=list)
    source: str = "<sweep>"
    upto: str | None = None


def _slug(point: dict) -> str:
    s = "_".join(f"{k}={v}" for k, v in point.items())
    return re.sub(r"[^A-Za-z0-9_.=-]+", "-", s)[:80]


def expand_sweep(base: StudyConfig, parameters: dict, mode: str = "grid",
                 source: str = "<sweep>") -> SweepPlan:
    """Expand parameter values into one study config per point.

    Parameters
    ----------
    base : StudyConfig
        Base config.
    parameters : dict[str, list]
        Parameter name -> list of values (a scalar means one value).
    mode : {"grid", "zip"}
        Cartesian product, or values taken side by side (equal lengths).
    source : str
        Sweep file for messages.

    Raises
    ------
    ConfigError
        Unknown parameter (named, known ones listed), empty value list, unequal lengths
        in ``zip`` mode, or a value the study config rejects.
    """
    if mode not in ("grid", "zip"):
        raise ConfigError(f"{source}: mode must be 'grid' or 'zip', got {mode!r}")
    if not parameters:
        raise ConfigError(f"{source}: [parameters] is empty; known parameters: {', '.join(PARAMETERS)}")
    params = {k: (list(v) if isinstance(v, (list, tuple)) else [v]) for k, v in parameters.items()}
    for k, v in params.items():
        if not v:
            raise ConfigError(f"{source}: parameters.{k} has no values")
        try:
            apply_parameter(base, k, v[0])
        except ConfigError as exc:
            raise ConfigError(f"{source}: parameters.{k}: {exc}") from None
    keys = list(params)
    if mode == "grid":
        combos = list(itertools.product(*(params[k] for k in keys)))
    else:
        lens = {k: len(v) for k, v in params.items()}
        if len(set(lens.values())) != 1:
            raise ConfigError(f"{source}: mode 'zip' needs equal-length value lists, got {lens}")
        combos = list(zip(*(params[k] for k in keys), strict=True))
    plan = SweepPlan(base=base, parameters=params, source=source)
    for i, combo in enumerate(combos):
        point = dict(zip(keys, combo, strict=True))
        cfg = base
        for k, v in point.items():
            try:
                cfg = apply_parameter(cfg, k, v)
            except ConfigError as exc:
                raise ConfigError(f"{source}: point {i} ({point}): {exc}") from None
        try:  # every point checked as its run will read it, before any point runs
            from_dict(StudyConfig, config_to_dict(cfg), source=f"{source}: point {i}")
        except ConfigError as exc:
            raise ConfigError(f"{exc} ({point})") from None
        plan.points.append(point)
        plan.configs.append(cfg)
        plan.names.append(f"{i:03d}_{_slug(point)}")
    return plan


def load_sweep(path: str | Path) -> SweepPlan:
    """Read and expand a sweep TOML (see the module docstring for the format).

    Raises
    ------
    ConfigError
        Naming the file and the offending key or parameter.
    """
    path = Path(path)
    data = read_toml(path, "sweep")
    unknown = [k for k in data if k not in _SWEEP_KEYS]
    if unknown:
        raise ConfigError(f"{path}: unknown key(s) {unknown}; a sweep file has {', '.join(_SWEEP_KEYS)}")
    base = base_config(data, str(path), path.parent)
    params = data.get("parameters", {})
    if not isinstance(params, dict):
        raise ConfigError(f"{path}: parameters must be a table")
    plan = expand_sweep(base, params, mode=data.get("mode", "grid"), source=str(path))
    plan.upto = _check_upto(data.get("upto"), plan, str(path))
    return plan


def _check_upto(upto, plan: SweepPlan, source: str) -> str | None:
    """The sweep's ``upto``: None, or a stage of every point's study at or after the one
    that writes ``metrics.json`` (the summary reads it; an earlier stop would leave the
    table empty, or read a metrics file of an earlier, longer run); no replicated point
    (it runs every stage).

    Raises
    ------
    ConfigError
        Not a stage of a point's study (its stages listed), a stage before its metrics,
        or a point with ``replicates.n > 1``.
    """
    if upto is None:
        return None
    for i, cfg in enumerate(plan.configs):
        stages = study_stages(cfg)
        names = [s.name for s in stages]
        if not isinstance(upto, str) or upto not in names:
            raise ConfigError(f"{source}: upto = {upto!r} is not a stage of point {i}'s "
                              f"study; its stages are {', '.join(names)}")
        # the stage declaring metrics.json among its outputs
        metrics = next(s.name for s in stages if runfiles.METRICS in s.outputs)
        if names.index(upto) < names.index(metrics):
            raise ConfigError(f"{source}: upto = {upto!r} stops before {metrics!r}, which "
                              "writes the metrics the sweep's summary reads; use "
                              f"{metrics!r} or a later stage")
        if cfg.replicates.n > 1:
            raise ConfigError(f"{source}: upto = {upto!r} with point {i} "
                              f"({plan.points[i]}) a replicated study (replicates.n = "
                              f"{cfg.replicates.n}), which runs every stage: drop upto or "
                              "the replicates")
    return upto


@dataclass
class SweepResult:
    """Outcome of :func:`run_sweep`.

    Attributes
    ----------
    out_dir : pathlib.Path
        Sweep directory.
    summary : pandas.DataFrame
        One row per point: ``run``, the swept parameters, status and summary metrics.
    files : list of pathlib.Path
        summary.parquet, summary.csv, sweep.json and the plots.
    """

    out_dir: Path
    summary: object
    files: list[Path] = field(default_factory=list)


#: Files a sweep writes at the top of its directory.
SWEEP_FILES = ("summary.parquet", "summary.csv", "sweep.json")


def check_sweep_dir(out_dir: str | Path) -> Path:
    """The resolved sweep directory, or a ConfigError naming why it cannot be one: a
    file, or a non-empty directory that is not a sweep directory of this tool (a user's
    ``summary.csv`` there would be overwritten)."""
    out = Path(out_dir)
    try:
        if out.exists() and not out.is_dir():
            raise ConfigError(f"--out {out_dir}: a file, not a directory")
        out = out.resolve()
        entries = sorted(p.name for p in out.iterdir()) if out.is_dir() else []
    except (OSError, RuntimeError) as exc:  # a link loop, no permission
        raise ConfigError(f"--out {out_dir}: cannot be used as a sweep directory: {exc}") from None
    if entries:
        # sweep.json is written before the first point runs and says whose it is: a
        # sweep.json of the user's (the same name) does not make the folder ours
        check_marker_file(out_dir, "sweep.json")  # a link is refused by name, never followed
        ours = own_marker(out / "sweep.json", "sweep", ("source", "parameters", "runs"))
        if entries and not ours:
            shown = ", ".join(entries[:3]) + (", ..." if len(entries) > 3 else "")
            raise ConfigError(f"--out {out_dir} is not empty ({shown}) and is not a sweep "
                              "directory of rfidstudy: choose another directory")
    return out


def run_sweep(plan: SweepPlan, out_dir: str | Path, *, scheduler: str | None = None,
              workers: int | None = None, client=None,
              on_done: Callable[[int, dict], None] | None = None) -> SweepResult:
    """Run every point of ``plan`` and write the summary table and plots.

    Parameters
    ----------
    plan : SweepPlan
        From :func:`load_sweep` or :func:`expand_sweep`.
    out_dir : path
        Sweep directory; runs go to ``out_dir/runs/<name>``.
    scheduler : str, optional
        Dask scheduler address (``tcp://host:8786``); runs go to that cluster.
    workers : int, optional
        Local worker processes (default: min(points, 2)); ignored with a scheduler.
    client : distributed.Client, optional
        An existing Dask client (takes precedence over ``scheduler``).
    on_done : callable, optional
        ``on_done(index, row)`` after each point (progress display).
    """
    import pandas as pd

    # the stage package (its import is most of a second): loaded when points run

    out = check_sweep_dir(out_dir)
    (out / "runs").mkdir(parents=True, exist_ok=True)
    # the marker first: an interrupted sweep's directory is recognised as ours on rerun
    atomic_write_json(out / "sweep.json", _marker(plan))
    configs = [_shared_cache(c, out) for c in plan.configs]
    args = [(config_to_dict(c), str(out / "runs" / n)) for c, n in zip(configs, plan.names, strict=True)]
    # a point may be a replicated study: run_full_study runs its replicates
    rows = run_studies(args, scheduler=scheduler, workers=workers, client=client,
                       on_done=on_done, runner=run_full_study, upto=plan.upto)  # summarised
    table = []
    for name, point, row in zip(plan.names, plan.points, rows, strict=True):
        r = {"run": name}
        r.update({k: (v if not isinstance(v, (list, tuple)) else str(v)) for k, v in point.items()})
        r.update(row or {})
        table.append(r)
    df = pd.DataFrame(table)
    files = _write_summary(df, out, plan)
    return SweepResult(out_dir=out, summary=df, files=files)


def _marker(plan: SweepPlan) -> dict:
    """``sweep.json``: whose directory this is and what the sweep ran."""
    return {"tool": "rfidstudy", "kind": "sweep", "source": plan.source,
            "parameters": plan.parameters, "runs": plan.names, "upto": plan.upto}


def _shared_cache(cfg: StudyConfig, out: Path) -> StudyConfig:
    """Pin the propagation cache to one absolute directory for every point."""
    return replace_path(cfg, "tracing.cache_dir", str(resolve_cache_dir(cfg)))


def _write_summary(df, out: Path, plan: SweepPlan) -> list[Path]:
    import io

    files = []
    buf = io.BytesIO()
    df.to_parquet(buf, index=False)
    files.append(atomic_write_bytes(out / "summary.parquet", buf.getvalue()))
    files.append(atomic_write_bytes(out / "summary.csv", df.to_csv(index=False).encode()))
    files.append(atomic_write_json(out / "sweep.json", _marker(plan)))
    files.extend(_plots(df, out, list(plan.parameters)))
    return files


_PLOT_METRICS = (
    ("read_rate", "read rate (reads / attempts in range)"),
    ("completeness", "tags read >= 3 times per pass (share)"),
    ("surface_coverage", "route share with a closing link, at the tags"),
    ("ssm_rmse_db", "RSSI model RMSE [dB]"),
    ("tdm_rmse", "detection model RMSE"),
)


def _plots(df, out: Path, params: list[str]) -> list[Path]:
    import io

    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    import numpy as np

    files = []
    metrics = [(k, lab) for k, lab in _PLOT_METRICS if k in df.columns]
    if not metrics:
        return files
    for p in params:
        fig, axes = plt.subplots(1, len(metrics), figsize=(3.2 * len(metrics), 3.0), squeeze=False)
        x = df[p]
        numeric = np.issubdtype(np.asarray(x).dtype, np.number)
        for ax, (k, lab) in zip(axes[0], metrics, strict=True):
            if numeric:
                g = df.groupby(p)[k].mean().sort_index()
                ax.plot(g.index, g.values, "o-")
            else:
                g = df.groupby(p, sort=False)[k].mean()
                ax.bar(range(len(g)), g.values)
                ax.set_xticks(range(len(g)), [str(i) for i in g.index], rotation=30, fontsize=7)
            ax.set_xlabel(p)
            others = [o for o in params if o != p and df[o].nunique() > 1]
            # no silent averaging: the title names what each point averages over
            ax.set_title(lab + (f"\n(mean over {', '.join(others)})" if others else ""), fontsize=8)
            ax.grid(alpha=0.3)
        fig.tight_layout()
        buf = io.BytesIO()
        fig.savefig(buf, format="png", dpi=110)
        plt.close(fig)
        files.append(atomic_write_bytes(out / f"sweep_{p}.png", buf.getvalue()))
    return files
