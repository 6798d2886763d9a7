"""The study's scene: the building, its two tag layouts, the route, the robot and the link.

What a study makes of its config before anything is traced or driven, as pure functions
of the :class:`~pipeline.config.StudyConfig` (the stages, placement and the benchmarks
call them; nothing here reads a run directory):

=========================  ==============================================================
function                   what it gives
=========================  ==============================================================
:func:`study_building`     the scene with the study's ``[[materials]]`` laid over it
:func:`study_scene`        the scene with the training tags and ``evaluation.n_eval_tags``
                           held-out tags (racks' beams or walls, near the route), and
                           which tag is which
:func:`recorded_scene`     the building with a recording's tags and its held-out split
:func:`map_route`          a map scene's planned coverage route (tags it cannot serve
                           removed, each logged)
:func:`study_route`        the route cut to ``tour.max_length_m``
:func:`tag_candidates`     where the downstream stage looks for a held-out tag
:func:`build_robot`        the robot with the config's antenna mounts
:func:`link_budget`        the reader's link budget at the study's carrier
:func:`trace_options`      the tracer's options; :func:`preferred_backend`,
                           :func:`select_backend` its Dr.Jit variant
:func:`stage_rng`          the study's named random streams (one per stage or draw)
=========================  ==============================================================
"""

from __future__ import annotations

import dataclasses
import logging
import os
import zlib
from pathlib import Path

import numpy as np

import propagation
import scenes
from pipeline.config import StudyConfig, TracingConfig
from pipeline.recording import RecordingError
from pipeline.recording.load import load_recording, recorded_tagset
from pipeline.robot import AntennaMount, Robot, plan_coverage_route
from pipeline.robot.kinematics import antenna_poses
from pipeline.sceneconfig import material_overrides
from propagation.tracing import TraceOptions
from scenes.mapsites import shelf_sites
from scenes.scene import TagSet
from scenes.sources import traits_of
from scenes.tagsites import draw_tags, tag_sites

__all__ = ["EVAL_TAG_SPACING_M", "NARROW_ROUTE_MARGIN_M", "antenna_tilts", "build_robot",
           "link_budget", "load_study_recording", "map_route", "preferred_backend",
           "recorded_scene", "resolve_cache_dir", "select_backend", "stage_rng", "study_building",
           "study_route", "study_scene", "tag_candidates", "trace_options", "warn_skipped_faces"]


def stage_rng(cfg: StudyConfig, stage: str) -> np.random.Generator:
    """The random generator of one stage: seeded by (study seed, crc32 of the stage name).

    Every stage draws from its own stream, so re-running one stage reproduces it
    bit for bit whatever ran before it.
    """
    return np.random.default_rng([int(cfg.seed), zlib.crc32(stage.encode())])


def resolve_cache_dir(cfg: StudyConfig) -> Path:
    """The shared propagation cache: tracing.cache_dir, $RFIDSTUDY_CACHE or ~/.cache/rfidstudy."""
    if cfg.tracing.cache_dir:
        return Path(cfg.tracing.cache_dir).expanduser().resolve()
    env = os.environ.get("RFIDSTUDY_CACHE")
    if env:
        return Path(env).expanduser().resolve()
    return (Path.home() / ".cache" / "rfidstudy").resolve()


#: Grid of candidate sites the held-out tags are drawn from [m]: fine, so their positions
#: and heights are not those of any lattice the training tags or truth sites use.
EVAL_TAG_SPACING_M = 0.1


def tag_candidates(scene, cfg: StudyConfig):
    """Where the downstream stage looks for a held-out tag (every model, the phase
    estimator and the oracle alike): the sites of every vertical surface of ``scene``
    that faces free space, at every height it has (floor to top), every
    ``downstream.candidate_spacing_m`` (:func:`scenes.tagsites.tag_sites` with
    ``z_range_m=None``).

    Not the held-out tags' own height band (``evaluation.eval_tag_heights_m``): a user's
    unknown tags could be wherever a tag sticks, and candidates cut to the band the
    evaluation drew its tags from would hand every model a prior it could not have.

    The held-out tags are drawn on each face's :data:`EVAL_TAG_SPACING_M` grid; this
    grid is laid half a step off it along both face axes (``tag_sites(between_m=...)``),
    so when :data:`EVAL_TAG_SPACING_M` is a whole multiple of the candidate spacing (the
    default 0.1 m / 0.05 m) a held-out tag lies exactly half a cell diagonal (3.5 cm at
    5 cm) from its nearest candidates, never on one, whatever the faces' sizes (two grids
    each centred on its face coincided where ``floor(W / 0.05)`` was odd). Another
    spacing may put a candidate on a held-out tag.
    """
    return tag_sites(scene, spacing_m=cfg.downstream.candidate_spacing_m, z_range_m=None,
                     between_m=EVAL_TAG_SPACING_M)


def study_building(cfg: StudyConfig):
    """``scenes.load(cfg.scene)`` with the study's ``[[materials]]`` laid over the scene's own
    material overrides (:func:`pipeline.sceneconfig.material_overrides`)."""
    sc = scenes.load(cfg.scene)
    if not cfg.materials:
        return sc
    ov = {k: dict(v) for k, v in sc.metadata.get("material_overrides", {}).items()}
    for name, entry in material_overrides(cfg.materials).items():
        ov.setdefault(name, {}).update(entry)
    return dataclasses.replace(sc, metadata={**sc.metadata, "material_overrides": ov})


def study_scene(cfg: StudyConfig):
    """The scene with the study's two tag layouts, and which tag belongs to which.

    The scene's own tags are the training layout; ``evaluation.n_eval_tags`` held-out
    tags are drawn on its racks' front beams where it is a map with racks
    (:func:`scenes.mapsites.shelf_sites`), else on its walls, boxes and cabinets
    (:func:`scenes.tagsites.draw_tags`,
    stream ``stage_rng(cfg, "eval_tags")``), at least ``eval_tag_min_separation_m`` from
    every other tag and at heights in ``eval_tag_heights_m``, so the evaluation tour
    reads tags at positions and heights the training tour never read.

    Returns
    -------
    scene : scenes.Scene
        A copy whose ``tags`` are the training tags followed by the held-out ones.
    split : numpy.ndarray, shape (n_tags,), str
        ``"train"`` or ``"eval"`` per tag, in ``scene.tags`` order.
    """
    sc = map_route(study_building(cfg), build_robot(cfg))
    ev = cfg.evaluation
    train = sc.tags
    # a map with racks: the held-out tags are shelf tags too (on the front beams, at every
    # beam height in range), not tags on its walls and pillars
    route = study_route(sc, cfg)

    def near_route(sites):  # only where the evaluation tour passes within the models' domain
        if route is None:
            return sites
        return sites.subset(_route_distance_m(sites.positions_m[:, :2], route) <= cfg.training.d_max_m)

    sites = near_route(shelf_sites(sc, EVAL_TAG_SPACING_M, tuple(ev.eval_tag_heights_m)))
    if len(sites) < 4 * ev.n_eval_tags:  # too few shelf sites to draw from, spread out
        sites = near_route(tag_sites(sc, spacing_m=EVAL_TAG_SPACING_M,
                                     z_range_m=tuple(ev.eval_tag_heights_m)))
    held = draw_tags(sites, ev.n_eval_tags, stage_rng(cfg, "eval_tags"), avoid_m=train.positions_m,
                     min_separation_m=ev.eval_tag_min_separation_m, prefix="E",
                     where=f"{sc.name}: evaluation.n_eval_tags = {ev.n_eval_tags}")
    clash = sorted(set(train.ids.tolist()) & set(held.ids.tolist()))
    if clash:
        raise ValueError(f"{sc.name}: held-out tag ids {clash} are already used by the scene's tags")
    tags = TagSet(np.concatenate([train.ids, held.ids]),
                  np.vstack([train.positions_m, held.positions_m]),
                  np.vstack([train.normals, held.normals]))
    split = np.array(["train"] * len(train) + ["eval"] * len(held))
    return dataclasses.replace(sc, tags=tags), split


#: The planner's clearance margin beyond the robot's radius when the default (0.25 m)
#: leaves faces unserved [m]: the tour keeps 0.10 m beyond the footprint, the route's
#: simplification moves it by half a planning cell (0.05 m).
NARROW_ROUTE_MARGIN_M = 0.15


def map_route(scene, robot):
    """``scene`` with a planned coverage route when it is a map scene without a route.

    A scene of a source that plans routes (:attr:`scenes.sources.SceneTraits.plans_route`:
    one from an occupancy-grid map) without ``route_m`` gets
    :func:`pipeline.robot.plan_coverage_route` past its tags, within the map's
    ``route_standoff_m`` (``[map]``, default 1 m); every other scene is returned as is.
    Tags on faces the route cannot serve (:attr:`pipeline.robot.CoverageRoute.skipped`)
    are removed from the scene, each face logged at INFO with its reason (the run log) and
    listed in ``scene.metadata["route"]["skipped"]``: a tag the robot never passes would
    only be a tag never read. The console's one line about them is the scene stage's
    (:func:`warn_skipped_faces`): every process that loads the scene plans its route.
    """
    if scene.route_m is not None or not traits_of(scene).plans_route:
        return scene

    standoff = float(scene.metadata.get("map", {}).get("route_standoff_m", 1.0))
    try:
        plan, failure = plan_coverage_route(scene, robot, standoff), None
    except ValueError as exc:
        plan, failure = None, exc
    if plan is None or plan.skipped:
        # a real map's clutter pinches aisles under the robot's width plus 0.5 m: with the
        # margin narrowed to what the tour itself keeps (0.10 m beyond the footprint, plus half
        # a planning cell) the robot may still pass; the plan serving more tags is kept
        try:
            narrow = plan_coverage_route(scene, robot, standoff, margin_m=NARROW_ROUTE_MARGIN_M)
        except ValueError:
            narrow = None
        if narrow is not None and (plan is None or
                                   len(narrow.skipped_tag_index) < len(plan.skipped_tag_index)):
            logging.getLogger("pipeline.stages").info(
                "%s: route margin narrowed to %.2f m: %d tags skipped (%s with 0.25 m)", scene.name,
                NARROW_ROUTE_MARGIN_M, len(narrow.skipped_tag_index),
                "no route" if plan is None else len(plan.skipped_tag_index))
            plan = narrow
    if plan is None:
        raise failure
    meta = dict(scene.metadata)
    meta["route"] = {"length_m": round(plan.length_m, 3), "passes": int(len(plan.passes_m)),
                     "skipped": [{"tags": [str(t) for t in scene.tags.ids[s.face.tag_index]],
                                  "xy_m": np.round(scene.tags.positions_m[s.face.tag_index, :2], 4).tolist(),
                                  "reason": s.reason} for s in plan.skipped]}
    tags = scene.tags
    if plan.skipped:
        log = logging.getLogger("pipeline.stages")
        gone = plan.skipped_tag_index
        log.info("%s: the planned route skips %d of %d tag faces (%d of %d tags removed from the "
                 "scene)", scene.name, len(plan.skipped), len(plan.faces), len(gone), len(tags))
        for s in plan.skipped:
            log.info("  skipped %s", s.describe())
        tags = tags.subset(~np.isin(np.arange(len(tags)), gone))
    return dataclasses.replace(scene, route_m=plan.route_m, tags=tags, metadata=meta)


def warn_skipped_faces(scene) -> None:
    """One WARNING line when the planned route skips tag faces, with where each face and
    its reason are (the run's ``scene/scene.json``, ``route_skipped``, written by the
    scene stage; ``rfidstudy scenes show``; the run log at INFO, from :func:`map_route`).

    The scene stage calls it once per study: the Neobotix lab map's clutter skips 14
    faces, which printed a WARNING line each in every process that loaded the scene."""
    skipped = scene.metadata.get("route", {}).get("skipped", [])
    if skipped:
        logging.getLogger("pipeline.stages").warning(
            "%s: the planned route skips %d tag faces (%d tags removed from the scene); each "
            "face and why: scene/scene.json (route_skipped), or `rfidstudy scenes show`",
            scene.name, len(skipped), sum(len(s["tags"]) for s in skipped))


def _route_distance_m(xy: np.ndarray, route: np.ndarray) -> np.ndarray:
    """Horizontal distance of points (k, 2) to a polyline (n, 2) [m]."""
    a, b = route[:-1], route[1:]
    ab = b - a
    t = np.einsum("kij,ij->ki", xy[:, None, :] - a[None], ab) / np.maximum(
        np.einsum("ij,ij->i", ab, ab), 1e-12)
    proj = a[None] + np.clip(t, 0.0, 1.0)[..., None] * ab[None]
    return np.min(np.linalg.norm(xy[:, None, :] - proj, axis=2), axis=1)


def load_study_recording(cfg):
    """The study's ``[recording]`` read (:func:`pipeline.recording.load.load_recording`)."""
    return load_recording(cfg.recording, region=cfg.reader.region,
                          n_mounts=len(cfg.robot.antennas))


def recorded_scene(cfg, memo: dict | None = None):
    """The study's building with the recording's tags, and each tag's split.

    Parameters
    ----------
    cfg : StudyConfig
    memo : dict, optional
        Receives the loaded :class:`~pipeline.recording.Recording` under ``"recording"``
        (a run's memo: the recording stage then need not read the files again).

    Returns
    -------
    scene : scenes.Scene
        ``study_building(cfg)`` with ``tags`` the recording's (ids = EPCs).
    split : numpy.ndarray of str
        ``"train"`` or ``"eval"`` per tag: ``round(heldout_fraction * n)`` tags (at least
        one, at most n - 1) held out, drawn from ``stage_rng(cfg, "recording_split")``.

    Raises
    ------
    pipeline.recording.RecordingError
        A recording file cannot be read; fewer than two tags.
    """
    rec = load_study_recording(cfg)
    if memo is not None:  # the recording stage reads it from here, not the files again
        memo["recording"] = rec
    mounts = build_robot(cfg).antennas
    ant_xy = antenna_poses(np.zeros((1, 3)), list(mounts))[0, :, :2]
    tags = recorded_tagset(rec, ant_xy)
    n = len(tags)
    if n < 2:
        raise RecordingError(f"{cfg.recording.tags}: {n} tag(s); a held-out split needs two")
    k = int(min(max(round(cfg.recording.heldout_fraction * n), 1), n - 1))
    held = stage_rng(cfg, "recording_split").choice(n, size=k, replace=False)
    split = np.full(n, "train", dtype="<U5")
    split[held] = "eval"
    return dataclasses.replace(study_building(cfg), tags=tags), split


def study_route(scene, cfg: StudyConfig) -> np.ndarray | None:
    """The scene's route, cut to its first ``tour.max_length_m`` metres when set.

    Returns
    -------
    numpy.ndarray or None
        Polyline (k, 2) [m].
    """
    route = None if scene.route_m is None else np.asarray(scene.route_m, dtype=float)
    L = cfg.tour.max_length_m
    if route is None or L <= 0:
        return route
    seg = np.linalg.norm(np.diff(route, axis=0), axis=1)
    s = np.concatenate([[0.0], np.cumsum(seg)])
    if L >= s[-1]:
        return route
    k = int(np.searchsorted(s, L))
    t = (L - s[k - 1]) / seg[k - 1]
    end = route[k - 1] + t * (route[k] - route[k - 1])
    return np.vstack([route[:k], end[None]])


def build_robot(cfg: StudyConfig):
    """``pipeline.robot.Robot`` with the config's antenna mounts (degrees -> radians)."""
    mounts = [
        AntennaMount(a.name, x_m=a.x_m, y_m=a.y_m, z_m=a.z_m, yaw_rad=float(np.deg2rad(a.yaw_deg)),
                     tilt_rad=float(np.deg2rad(a.tilt_deg)), cable_loss_db=float(a.cable_loss_db))
        for a in cfg.robot.antennas
    ]
    return Robot(antennas=mounts)


def link_budget(cfg: StudyConfig):
    """``propagation.LinkBudget`` of the [reader] section at the study's carrier frequency."""
    return cfg.reader.link_budget(cfg.frequency_hz)


def trace_options(cfg: StudyConfig):
    """The ``propagation.TraceOptions`` of the [tracing] section (for ``trace_links``)."""
    t = cfg.tracing
    return TraceOptions(
        method=t.method,
        max_depth=t.max_depth,
        samples_per_src=t.samples_per_src,
        shared_samples_per_src=t.shared_samples_per_src,
        min_samples_per_position=t.min_samples_per_position,
        share_radius_m=t.share_radius_m,
        completion_order=t.completion_order,
        completion_min_area_m2=t.completion_min_area_m2,
        completion_max_planes=t.completion_max_planes,
        reader_pattern=t.reader_pattern,
        tag_pattern=t.tag_pattern,
        reader_polarization=t.reader_polarization,
        memory_budget_bytes=int(t.memory_budget_mb * 2**20),
    )


def preferred_backend(tracing: TracingConfig) -> str:
    """The ``prefer`` of ``propagation.select_variant`` for a ``[tracing]`` section.

    ``backend``, except that bit-reproducible traces (``deterministic``) need the CPU:
    then ``"llvm"`` (the CUDA path solver is not reproducible whatever the thread count;
    the config refuses ``deterministic`` with ``backend = "cuda"``).

    Parameters
    ----------
    tracing : pipeline.config.TracingConfig

    Returns
    -------
    str
        ``"auto"``, ``"cuda"`` or ``"llvm"``.
    """
    return "llvm" if tracing.deterministic else tracing.backend


def select_backend(cfg: StudyConfig) -> str:
    """Select the Dr.Jit variant (``propagation.select_variant``, as
    :func:`preferred_backend` says) before any tracing."""
    variant = propagation.select_variant(prefer=preferred_backend(cfg.tracing))
    propagation.set_deterministic(cfg.tracing.deterministic)
    return variant


def antenna_tilts(cfg: StudyConfig) -> dict:
    """Antenna index (as in reads.parquet) -> tilt [rad]."""
    return {i: float(np.deg2rad(a.tilt_deg)) for i, a in enumerate(cfg.robot.antennas)}
