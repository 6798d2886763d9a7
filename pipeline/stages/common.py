"""What the stages share that reads or describes a run: the study scene memoised per run,
the run's read logs, pose tracks and read attempts, the config keys every trace depends on,
and the manifest's provenance.

The study's scene itself (tag layouts, route, robot, link budget, tracer options, random
streams) is :mod:`pipeline.studyscene`: pure functions of the config, which placement and
the benchmarks use too.
"""

from __future__ import annotations

import importlib.metadata as _md
import logging
import platform
from pathlib import Path

import numpy as np

import propagation
from pipeline import runfiles
from pipeline.acquisition import PoseTrack, read_attempts, read_table
from pipeline.acquisition.config import POSE_SOURCES
from pipeline.config import StudyConfig
from pipeline.studyscene import (
    antenna_tilts,
    build_robot,
    recorded_scene,
    resolve_cache_dir,
    study_scene,
)
from scenes.fileio import read_npz

__all__ = ["POSE_SOURCES", "TRACING_KEYS", "attempt_poses", "load_scene", "manifest_info",
           "pose_sources", "read_reads", "read_track", "source_revision", "split_tags",
           "spread_evenly"]

log = logging.getLogger(__name__)

#: Config keys every traced result depends on (the reads and truth_traces stages).
TRACING_KEYS = ("frequency_hz", "tracing.max_depth", "tracing.samples_per_src",
                "tracing.reader_pattern", "tracing.tag_pattern", "tracing.reader_polarization",
                "tracing.backend", "tracing.method", "tracing.completion_order",
                "tracing.share_radius_m", "tracing.shared_samples_per_src",
                "tracing.min_samples_per_position", "tracing.completion_min_area_m2",
                "tracing.completion_max_planes")


def load_scene(ctx):
    """The study's scene with both tag layouts (:func:`study_scene`), memoised per run."""
    sc = ctx.memo.get("scene")
    if sc is None:
        if ctx.config.recording.enabled:  # the building with the recording's tags
            sc, split = recorded_scene(ctx.config, ctx.memo)
        else:
            sc, split = study_scene(ctx.config)
        ctx.memo["scene"] = sc
        ctx.memo["tag_split"] = split
    return sc


def pose_sources(cfg: StudyConfig) -> tuple[str, ...]:
    """The poses the training sets and models use: :data:`POSE_SOURCES` (MCL and true),
    or the estimate alone for a recording (it knows one pose, the robot's own)."""
    return ("est",) if cfg.recording.enabled else POSE_SOURCES


def split_tags(ctx, which: str):
    """The tags of one layout (``"train"`` or ``"eval"``) of the study scene (a TagSet)."""
    sc = load_scene(ctx)
    return sc.tags.subset(ctx.memo["tag_split"] == which)


def read_reads(ctx, prefix: str = ""):
    """``(frame, metadata)`` of the run's ``<prefix>reads.parquet`` (an error names the file)."""
    path = ctx.input(runfiles.READS.format(prefix=prefix))
    try:
        df, meta = read_table(path)
    except Exception as exc:
        raise ValueError(f"{path}: cannot read the read log ({type(exc).__name__}: {exc}); "
                         "delete it to re-run the reads stage") from None
    return df, meta


def read_track(ctx, name: str):
    """The tour's pose track ``tour/<name>_track.npz``.

    Parameters
    ----------
    ctx : pipeline.engine.study.StageContext
    name : {"train", "eval"}

    Returns
    -------
    pipeline.acquisition.PoseTrack

    Raises
    ------
    ValueError
        The file cannot be read (the message names it).
    """
    path = ctx.input(runfiles.TRACK.format(tour=name))
    try:
        with read_npz(path) as z:
            return PoseTrack(t_s=z["t_s"], true_poses=z["true"], est_poses=z["est"],
                             odom_poses=z["odom"])
    except (OSError, KeyError, ValueError) as exc:
        raise ValueError(f"{path}: cannot read pose track ({exc}); delete it to re-run the tour") from None


def attempt_poses(ctx, name: str, track=None) -> np.ndarray:
    """True antenna poses of the tour's read attempts, in time order, as the read log holds
    them (float32 positions and yaw; :func:`pipeline.acquisition.read_attempts` on the
    tour's track: they need no reads), with the antenna's tilt as pitch.

    Parameters
    ----------
    ctx : pipeline.engine.study.StageContext
    name : {"train", "eval"}
        The tour (its track ``tour/<name>_track.npz``).
    track : pipeline.acquisition.PoseTrack, optional
        The tour's track itself, instead of its file (only its true poses and times are
        used: e.g. :func:`pipeline.stages.tour.eval_track` before the tour's MCL ran).

    Returns
    -------
    numpy.ndarray, shape (n_attempts, 6), float64
        [x_m, y_m, z_m, yaw_rad, pitch_rad, roll_rad].
    """
    cfg = ctx.config
    track = read_track(ctx, name) if track is None else track
    att = read_attempts(track, list(build_robot(cfg).antennas), cfg.reader,
                        frequency_hz=cfg.frequency_hz)
    tilt = antenna_tilts(cfg)
    poses = np.asarray(att.true_antenna, np.float64)[:, :4].astype(np.float32).astype(np.float64)
    pitch = np.array([tilt[int(a)] for a in att.antenna], float)
    return np.column_stack([poses, pitch, np.zeros(len(poses))])


def spread_evenly(poses: np.ndarray, n: int) -> np.ndarray:
    """``n`` of ``poses`` (rows) spread evenly over them, the first and last left out."""
    idx = np.linspace(0, len(poses) - 1, n + 2)[1:-1].round().astype(int)
    return poses[idx]


def _version(dist: str) -> str | None:
    try:
        return _md.version(dist)
    except _md.PackageNotFoundError:
        return None


#: Source folders whose untracked files count as a change to the code that runs.
SOURCE_DIRS = ("pipeline", "scenes", "propagation", "fuzzymodel")


def source_revision(root=None) -> dict:
    """The git commit of the code that runs (this package's checkout) and whether it
    differs from it: ``{"commit": sha or None, "dirty": bool or None}``, with ``"why"``
    where git could not say (no git, not a checkout, e.g. an installed wheel).

    ``root`` (default: the folder holding this ``pipeline`` package) must be the top
    level of its git checkout (``git rev-parse --show-toplevel``) and hold ``pipeline/``:
    a package installed inside some other repository's tree names no commit rather than
    that repository's. ``dirty``: a tracked file differs from the commit, or an untracked
    (and not ignored) file lies under one of :data:`SOURCE_DIRS`. What a number quoted
    from a run directory names as its source."""
    import subprocess

    root = Path(__file__).resolve().parents[2] if root is None else Path(root).resolve()

    def git(*args) -> str:
        return subprocess.run(["git", "-C", str(root), *args], capture_output=True, text=True,
                              timeout=10, check=True).stdout

    if not (root / "pipeline").is_dir():
        return {"commit": None, "dirty": None, "why": f"{root} holds no pipeline/"}
    try:
        top = git("rev-parse", "--show-toplevel").strip()
        if Path(top).resolve() != root:
            return {"commit": None, "dirty": None,
                    "why": f"{root} is not the top of its git checkout ({top})"[:200]}
        sha = git("rev-parse", "HEAD").strip()
        dirty = (git("status", "--porcelain", "--untracked-files=no").strip() != ""
                 or git("status", "--porcelain", "--untracked-files=all", "--",
                        *SOURCE_DIRS).strip() != "")
    except (OSError, subprocess.SubprocessError) as exc:
        return {"commit": None, "dirty": None, "why": f"{type(exc).__name__}: {exc}"[:200]}
    return {"commit": sha, "dirty": dirty}


def manifest_info(cfg: StudyConfig) -> dict:
    """Package versions, platform, the source's git commit and the Dr.Jit backend for
    ``manifest.json``."""
    dists = ["rfidstudy", "sionna-rt", "mitsuba", "drjit", "numpy", "scipy", "scikit-fuzzy",
             "trimesh", "pandas", "pyarrow", "matplotlib", "dask", "distributed"]
    info = {
        "source": source_revision(),
        "versions": {d: _version(d) for d in dists},
        "python": platform.python_version(),
        "platform": platform.platform(),
        "cache_dir": str(resolve_cache_dir(cfg)),
    }
    try:
        info["backend"] = propagation.backend_info()
    except Exception as exc:  # the manifest must not fail the study
        info["backend"] = {"error": f"{type(exc).__name__}: {exc}"}
    return info
