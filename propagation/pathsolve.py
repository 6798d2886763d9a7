"""Paths from antenna positions to tags: from the cache, or traced by the method named.

The tracing half of :func:`propagation.trace_links`: every antenna *position* is traced
once with unrotated isotropic dual-polarised (``VH``) antennas at both ends, and per
path the 2x2 polarimetric transfer matrix, the delay and the departure / arrival
directions are kept (:class:`propagation.pathcache.SourcePaths`, cached on disk).
Patterns are applied afterwards (:mod:`propagation.channels`).

Two tracers, chosen by :attr:`TraceOptions.method`:

- ``"shared"`` (the default, the study's truth): positions of a call within
  ``share_radius_m`` share the chains their rays found (:mod:`propagation.shared`), and
  every specular chain over the large planes up to ``completion_order`` is enumerated
  (:mod:`propagation.completion`). It reaches into Sionna's path-solver stages through
  :mod:`propagation.sionna_internals`, whose version guard refuses untested versions.
- ``"direct"``: Sionna's documented ``PathSolver`` on the scene as loaded, nothing
  else: the public-API reference the fast tracer is tested against, and the way to run
  on a Sionna version the fast tracer was not tested with.
"""

from __future__ import annotations

import logging
import time
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Literal, get_args

import numpy as np

from propagation.backend import backend_info, ensure_variant
from propagation.chunkjobs import ChunkJob, current_chunk_runner
from propagation.completion import (
    complete_specular,
    large_planes,
    merge_paths,
    plane_lookup,
    triangle_planes,
)
from propagation.pathcache import PathCache, SourcePaths, settings_key
from propagation.patterns import PATTERNS, POLARIZATIONS, unit_vec_from_theta_phi
from propagation.raybudget import _default_budget, bytes_per_source, memory_shortfall
from propagation.shared import own_ray_levels, sharing_neighbours, trace_shared
from propagation.sionna_internals import check_versions
from propagation.sionna_paths import to_source_paths
from propagation.sionna_scene import clear_devices, load_sionna_scene, place_devices

__all__ = ["DEFAULT_MAX_DEPTH", "DEFAULT_SAMPLES_PER_SRC", "METHODS", "PathSet", "TraceMethod", "TraceOptions",
           "MAX_SOURCES_PER_CALL", "padded_target_count", "padding_point", "trace_paths"]

logger = logging.getLogger(__name__)

#: Default maximum number of interactions per path. Convergence check (bench/trace.py,
#: corridor_lab, 20 positions x 24 tags, reference depth 6 / 3e5 rays): on links within
#: 13 dB of the tag threshold, depth 5 / 3e4 rays gives median |error| 0.93 dB, p95 8 dB,
#: 5 of 480 detection decisions flipped -- the same as the reference traced again with
#: another seed (0.50 dB, 3.7 dB, 5 flips): coherent sums in a corridor are sensitive to
#: which high-order paths the ray sampling finds. Depth 4 flips 10, depth 3 flips 13.
DEFAULT_MAX_DEPTH = 5
#: Default rays per antenna position (1e5 rays costs 3.8x for 0.2 dB median gain); about
#: 260 links/s on 2 shared cores at these defaults.
DEFAULT_SAMPLES_PER_SRC = 30_000
MAX_SOURCES_PER_CALL = 128
#: Planes of at least this area are completed by the image method (completion_order,
#: TraceOptions.completion_min_area_m2's default): walls, floor, ceiling and furniture
#: faces; 22 planes on corridor_lab, the metal cabinets' sides and tops among them (16 at
#: 1 m^2, which leaves those to the rays, and chains over them are the largest part of the
#: truth's seed-to-seed noise on sparse poses, bench/seed_noise_chains.py; 0.4 m^2, 25
#: planes, removes little more of it and costs more; a plane counts where one connected
#: patch reaches the area: :func:`propagation.completion.large_planes`).
COMPLETION_MIN_AREA_M2 = 0.5
#: Versions of the tracing algorithms, part of the cache key: a change that changes
#: their paths must bump them so no cache serves the old results (what each version
#: changed: CHANGELOG.md, 2026-11-29, "Tracing algorithm versions").
COMPLETION_ALGORITHM = 4
DIRECT_ALGORITHM = 2
SHARING_ALGORITHM = 9


#: The tracers :func:`trace_paths` can run (:attr:`TraceOptions.method`).
TraceMethod = Literal["shared", "direct"]
METHODS: tuple[str, ...] = get_args(TraceMethod)


@dataclass(frozen=True)
class TraceOptions:
    """How :func:`propagation.trace_links` traces: the tracer, its ray budget and the
    antennas. The defaults are the study's (``[tracing]`` of ``pipeline.config``), so a
    library call gives the study's truth.

    Attributes
    ----------
    method : {"shared", "direct"}
        ``"shared"``: the fast tracer (chains shared between neighbouring positions,
        :mod:`propagation.shared`, plus the image-method completion); it uses Sionna
        internals (:mod:`propagation.sionna_internals`) and refuses untested Sionna
        versions. ``"direct"``: Sionna's public ``PathSolver`` alone, every position
        shooting ``samples_per_src`` rays (the reference; ``share_radius_m``,
        ``shared_samples_per_src`` and ``completion_order`` do not apply).
    max_depth : int
        Maximum interactions per path (Sionna ``max_depth``). Convergence check in
        ``bench/trace.py``.
    samples_per_src : int
        Rays per antenna position traced alone: every position of ``"direct"``, a
        position of ``"shared"`` with no neighbour within ``share_radius_m`` (or
        ``min_samples_per_position`` rays where that is more). Too few rays miss paths
        silently.
    shared_samples_per_src : int
        Rays per position that shares chains with a neighbour (``"shared"``).
    min_samples_per_position : int or None
        ``"shared"``: the least rays a position's chains come from, whatever its
        neighbours. A position gets the chains of its own ``shared_samples_per_src`` rays
        and of each neighbour's; one short of this many (few neighbours within
        ``share_radius_m``: sparse poses, the ends of a path, a chunk's edge) also shoots
        the rest alone (:func:`propagation.shared.own_ray_levels`: rounded up to a few
        levels) and keeps the paths of both traces, copies removed. None (default):
        ``samples_per_src``, the rays of a position without a neighbour, so no position
        of the shared tracer draws from fewer rays than a lone one; 0: off (a position
        with one neighbour then draws from 6,000 rays; on 48 such positions of
        ``corridor_lab`` the seed-to-seed p95 over readable links is 1.80 dB off,
        1.30 dB with the default, against 0.93 dB on the dense evaluation path, whose
        positions have 12-50 neighbours; ``bench/seed_noise.py``, docs/physics.md).
    share_radius_m : float
        Positions of one solver call within this distance share chains (``"shared"``),
        metres, > 0. A position is given every chain that was a valid path at a
        neighbour, solved again by Sionna's image method at its exact position (no path
        is moved); docs/physics.md, "Sharing chains between positions".
    completion_order : int
        0-3: also every specular reflection path of up to this order over the scene's
        large planes (>= 1 m^2), solved by Sionna's image method
        (:mod:`propagation.completion`) and merged without double counting
        (``"shared"``). The shoot-and-bounce samples reflection or refraction at each
        hit by their Fresnel weights, so chains of weak reflections are rarely shot.
    completion_min_area_m2 : float
        The completion's planes: those whose coplanar triangles cover at least this area,
        m^2, >= 0 (default :data:`COMPLETION_MIN_AREA_M2`). A chain over a smaller face
        (a cabinet's side) is found only by the rays, and by chance: on ``corridor_lab``'s
        sparse poses such chains were most of the seed-to-seed noise at 1 m^2.
    completion_max_planes : int
        At most this many completion planes, the largest (``large_planes``'s
        ``max_planes``); 0 (default): every plane of ``completion_min_area_m2`` and up.
    reader_pattern, tag_pattern : str
        Pattern names (:data:`propagation.patterns.PATTERNS`), applied after tracing.
    reader_polarization : {"RHCP", "LHCP", "V", "H"}
        Reader polarisation, applied after tracing with the patterns
        (:func:`propagation.patterns.pattern_field_world`, the per-path 2x2 transfer
        matrices of the ``VH`` trace): default ``"RHCP"``, the circular panel of a UHF
        RFID reader. The mismatch with the linear tag dipole is then in the gain, path by
        path (1/2 = 3.01 dB on a line-of-sight path, other values after reflections, which
        change the wave's polarisation), so ``LinkBudget.polarization_loss_db`` is 0 by
        default; ``"V"`` / ``"H"``: a linear panel.
    seed : int
        Sionna's sampling seed.
    refraction : bool
        Trace transmission through surfaces (Sionna ``refraction``). False drops every
        path that crosses a wall, cabinet or box (faster; not the physics).
    memory_budget_bytes : int or None
        Peak memory per solver call, bytes; sources are chunked to fit
        (:func:`bytes_per_source`), and the chunks decide which positions share chains
        and which rays a lone position draws, so the study's 2 GiB is the default. None:
        a quarter of the available RAM.
    """

    method: TraceMethod = "shared"
    max_depth: int = DEFAULT_MAX_DEPTH
    samples_per_src: int = DEFAULT_SAMPLES_PER_SRC
    shared_samples_per_src: int = 3000
    min_samples_per_position: int | None = None
    share_radius_m: float = 1.0
    completion_order: int = 3
    completion_min_area_m2: float = COMPLETION_MIN_AREA_M2
    completion_max_planes: int = 0
    reader_pattern: str = "tr38901"
    tag_pattern: str = "hw_dipole"
    reader_polarization: str = "RHCP"
    seed: int = 42
    refraction: bool = True
    memory_budget_bytes: int | None = 2 * 1024**3

    def __post_init__(self):
        if self.method not in METHODS:
            raise ValueError(f"method must be one of {', '.join(map(repr, METHODS))}, got {self.method!r}")
        if int(self.max_depth) < 0 or int(self.samples_per_src) < 1 or int(self.shared_samples_per_src) < 1:
            raise ValueError("need max_depth >= 0, samples_per_src >= 1 and shared_samples_per_src >= 1, "
                             f"got {self.max_depth}, {self.samples_per_src}, {self.shared_samples_per_src}")
        if self.min_samples_per_position is not None and (
                isinstance(self.min_samples_per_position, bool) or int(self.min_samples_per_position) < 0):
            raise ValueError(f"min_samples_per_position must be >= 0 or None, got {self.min_samples_per_position!r}")
        if not (np.isfinite(self.share_radius_m) and self.share_radius_m > 0):
            raise ValueError(f"share_radius_m must be positive, got {self.share_radius_m!r}")
        if not (np.isfinite(self.completion_min_area_m2) and self.completion_min_area_m2 >= 0):
            raise ValueError(f"completion_min_area_m2 must be >= 0, got {self.completion_min_area_m2!r}")
        if isinstance(self.completion_max_planes, bool) or int(self.completion_max_planes) < 0:
            raise ValueError(f"completion_max_planes must be >= 0, got {self.completion_max_planes!r}")
        if int(self.completion_order) not in (0, 1, 2, 3):
            raise ValueError(f"completion_order must be 0 (off) to 3, got {self.completion_order!r}")
        for name in (self.reader_pattern, self.tag_pattern):
            if name not in PATTERNS:
                raise ValueError(f"unknown antenna pattern {name!r}; known: {', '.join(PATTERNS)}")
        if self.reader_polarization not in POLARIZATIONS:
            raise ValueError(f"unknown reader_polarization {self.reader_polarization!r}; "
                             f"known: {', '.join(POLARIZATIONS)}")
        if self.memory_budget_bytes is not None and int(self.memory_budget_bytes) < 1:
            raise ValueError(f"memory_budget_bytes must be positive, got {self.memory_budget_bytes!r}")
        if self.memory_budget_bytes is not None:
            short = memory_shortfall(self.method, int(self.max_depth), int(self.samples_per_src),
                                     int(self.shared_samples_per_src), int(self.memory_budget_bytes))
            if short:
                raise ValueError(short)

    @property
    def min_samples(self) -> int:
        """:attr:`min_samples_per_position` resolved (None: ``samples_per_src``)."""
        m = self.min_samples_per_position
        return int(self.samples_per_src) if m is None else int(m)

    def replace(self, **changes) -> TraceOptions:
        """A copy with ``changes`` (validated again)."""
        return TraceOptions(**{**asdict(self), **changes})


def padded_target_count(n_targets: int) -> int:
    """Receivers a ``PathSolver`` call (direct tracing, :func:`_trace_chunk`) is given for
    ``n_targets`` tags.

    Sionna's shooting kernel loops over the targets with their count as a literal, so
    every new count compiles it anew (~1 s on 2 cores). Counts up to 32 are kept; larger
    ones are rounded up to a quarter octave (at most 25 % more receivers, whose paths are
    dropped): four kernels per doubling. The shared tracer and its lone positions use
    :func:`propagation.sionna_internals.candidate_generator` instead, one kernel for every
    count, and pad nothing.
    """
    n = int(n_targets)
    if n <= 32:
        return n
    step = 1 << (n.bit_length() - 3)
    return -(-n // step) * step


def padding_point(rt_scene) -> np.ndarray:
    """Where padding receivers go: 1 m below the scene's lowest point.

    Only paths through the floor reach it: on corridor_lab at 3e4 rays, depth 5, a
    padding receiver got 4-5 valid paths against ~42 per tag, and the candidates of a
    call stayed far below Sionna's cap of rays x (depth + 1) per source, so the padding
    takes no slot a tag's path needed."""
    bb = rt_scene.mi_scene.bbox()
    return np.array([(bb.min.x + bb.max.x) / 2, (bb.min.y + bb.max.y) / 2, bb.min.z - 1.0])


def _trace_chunk(rt_scene, sources, receivers, max_depth, samples_per_src, seed, refraction=True):
    """One ``PathSolver`` call (Sionna's documented API only); returns a SourcePaths per
    source (all receivers)."""
    import sionna.rt as rt


    n_pad = padded_target_count(len(receivers)) - len(receivers)
    place_devices(rt_scene, sources, np.vstack([np.asarray(receivers, float).reshape(-1, 3),
                                                np.tile(padding_point(rt_scene), (n_pad, 1))]))
    solver = rt.PathSolver()
    paths = solver(
        rt_scene,
        max_depth=int(max_depth),
        samples_per_src=int(samples_per_src),
        max_num_paths_per_src=int(samples_per_src) * (int(max_depth) + 1),
        synthetic_array=True,
        los=True,
        specular_reflection=True,
        diffuse_reflection=False,
        refraction=bool(refraction),
        diffraction=False,
        seed=int(seed),
    )
    a_re, a_im = (x.numpy() for x in paths.a)  # (n_rx + n_pad, 2, n_tx, 2, P)
    pos = np.asarray(sources, float).reshape(-1, 3)
    tgt = np.asarray(receivers, float).reshape(-1, 3)
    n_rx, n_tx = len(tgt), len(pos)
    n_p = a_re.shape[-1]
    out = {"src": [], "tgt": [], "a": [], "tau": [], "k_tx": [], "k_rx": []}
    if n_p:
        a_re, a_im = a_re[:n_rx], a_im[:n_rx]  # the padding receivers' paths are dropped
        a = (a_re.astype(np.float64) + 1j * a_im.astype(np.float64)).reshape(n_rx, 2, n_tx, 2, n_p)
        a = np.transpose(a, (2, 0, 4, 1, 3))  # (n_tx, n_rx, P, rx_pol, tx_pol)
        n_all = n_rx + n_pad

        def per_link(x, dtype=np.float64):  # (n_all, n_tx, P) -> (n_tx, n_rx, P), padding dropped
            return x.numpy().astype(dtype).reshape(n_all, n_tx, n_p)[:n_rx].transpose(1, 0, 2)

        valid = per_link(paths.valid, bool)
        tau, th_t, ph_t, th_r, ph_r = (per_link(x) for x in (paths.tau, paths.theta_t,
                                                             paths.phi_t, paths.theta_r,
                                                             paths.phi_r))
        # the valid paths in (source, receiver, path) order; to_source_paths sorts them by
        # source, tag and length and counts a path PathSolver returned twice (a reflection
        # found through two triangles of one plane, sionna_paths.path_copies) once
        src, tg, _ = np.nonzero(valid)
        out["src"].append(src.astype(np.int64))
        out["tgt"].append(tg.astype(np.int64))
        out["a"].append(a[valid])
        out["tau"].append(tau[valid])
        out["k_tx"].append(unit_vec_from_theta_phi(th_t[valid], ph_t[valid]))
        out["k_rx"].append(unit_vec_from_theta_phi(th_r[valid], ph_r[valid]))
    clear_devices(rt_scene)
    return to_source_paths(out, pos, tgt)


def _trace_sharing(rt_scene, positions, receivers, radius_m, shared_samples, lone_samples, lone_per_call,
                   max_depth, seed, refraction, completion=None, plane_ids=None, min_samples=0,
                   budget_bytes=None) -> list[SourcePaths]:
    """One chunk traced with chain sharing (:mod:`propagation.shared`): positions with a
    neighbour within ``radius_m`` shoot ``shared_samples`` rays and take their neighbours'
    valid chains (leaving the chains ``completion`` enumerates to it; chains named by
    ``plane_ids``); a position with none shoots ``lone_samples`` as in direct tracing. A
    sharing position whose own and neighbours' rays fall short of ``min_samples`` also
    shoots rays alone (:func:`propagation.shared.own_ray_levels`), in calls of at most
    ``budget_bytes`` (default: ``lone_per_call`` positions), and keeps both traces' paths."""
    nbs = sharing_neighbours(positions, radius_m)
    lone = np.array([len(nb) == 0 for nb in nbs], bool)
    out: list = [None] * len(positions)
    together = np.flatnonzero(~lone)
    if len(together):
        row = np.full(len(positions), -1, np.int64)
        row[together] = np.arange(len(together))
        fresh = trace_shared(rt_scene, positions[together], receivers, [row[nbs[i]] for i in together],
                             max_depth, shared_samples, seed, refraction, completion, plane_ids)
        for i, sp in zip(together, fresh, strict=True):
            out[i] = sp
    # a position with no neighbour: what PathSolver does, without its Paths object (whose
    # per-call kernels cost ~0.3 s), its copies removed; no padding receivers: the shooting
    # kernel takes any target count (propagation.sionna_internals.candidate_generator)
    alone = np.flatnonzero(lone)
    for c0 in range(0, len(alone), lone_per_call):
        grp = alone[c0:c0 + lone_per_call]
        fresh = trace_shared(rt_scene, positions[grp], receivers, [np.zeros(0, np.int64)] * len(grp),
                             max_depth, lone_samples, seed, refraction, None, plane_ids)
        for i, sp in zip(grp, fresh, strict=True):
            out[i] = sp
    # a sharing position short of min_samples: the rest of its rays shot alone (leaving
    # the completion's chains to it, as its shared rays do); a path both traces found is
    # kept once (copies as to_source_paths tells them: length, directions and transfer
    # matrix)
    extra = own_ray_levels(nbs, shared_samples, min_samples)
    if extra.any():
        logger.info("%d of %d sharing positions short of %d rays: %s more rays each, shot alone",
                    int((extra > 0).sum()), int((~lone).sum()), int(min_samples),
                    "/".join(str(int(v)) for v in np.unique(extra[extra > 0])))
    for level in np.unique(extra[extra > 0]):
        grp_all = np.flatnonzero(extra == level)
        per_call = lone_per_call if budget_bytes is None else max(
            1, min(MAX_SOURCES_PER_CALL, int(budget_bytes) // bytes_per_source(int(level), max_depth,
                                                                                 len(receivers))))
        for c0 in range(0, len(grp_all), per_call):
            grp = grp_all[c0:c0 + per_call]
            fresh = trace_shared(rt_scene, positions[grp], receivers, [np.zeros(0, np.int64)] * len(grp),
                                 max_depth, int(level), seed, refraction, completion, plane_ids)
            for i, sp in zip(grp, fresh, strict=True):
                out[i] = merge_paths(out[i], sp, transfer_rtol=1e-3)
    return out


def tracer_state(scene, frequency_hz: float, shared: bool, completion_order: int,
                 min_area_m2: float = COMPLETION_MIN_AREA_M2, max_planes: int = 0) -> tuple:
    """What every chunk of one scene traces with: the Sionna scene (cached by content), its
    planes of ``min_area_m2`` and up (at most ``max_planes``, the largest; 0: all) and
    plane lookups (``None`` where not used)."""
    rt_scene = load_sionna_scene(scene, frequency_hz, public_api=not shared)
    planes = large_planes(rt_scene, min_area_m2, max_planes=int(max_planes)) if completion_order else None
    # shared positions leave the chains the completion enumerates to it
    to_completion = (plane_lookup(rt_scene, planes), completion_order) if completion_order else None
    plane_ids = triangle_planes(rt_scene) if shared else None
    return rt_scene, planes, to_completion, plane_ids


def trace_one_chunk(state: tuple, positions_m: np.ndarray, receivers_m: np.ndarray, opt: TraceOptions,
                    lone_samples: int, lone_per_chunk: int, budget: int,
                    completion_order: int, need: np.ndarray | None = None) -> list[SourcePaths]:
    """One chunk of :func:`trace_paths`: fresh paths, one per position, to the receivers
    it needs (``need``, (k, r) bool; default all). ``state`` is :func:`tracer_state`'s;
    the chunk is what :func:`trace_paths` cut, so a chunk traced here or in another
    process (:mod:`propagation.chunkjobs`) gives the same paths.
    """
    rt_scene, planes, to_completion, plane_ids = state
    max_depth, seed = int(opt.max_depth), int(opt.seed)
    if opt.method == "shared":
        fresh = _trace_sharing(rt_scene, positions_m, receivers_m, float(opt.share_radius_m),
                               int(opt.shared_samples_per_src), lone_samples, lone_per_chunk,
                               max_depth, seed, bool(opt.refraction), to_completion, plane_ids,
                               opt.min_samples, budget)
    else:
        fresh = _trace_chunk(rt_scene, positions_m, receivers_m, max_depth, int(opt.samples_per_src), seed,
                             bool(opt.refraction))
    if need is not None:
        # each position keeps (and caches) its own links: completing the chunk's union
        # for every position multiplies the completion's candidates and memory
        need = np.asarray(need, bool).reshape(len(positions_m), len(receivers_m))
        fresh = [f.subset(np.flatnonzero(w)) for f, w in zip(fresh, need, strict=True)]
    if completion_order:
        # complete every link the chunk keeps (and caches): the cache must never hold an
        # uncompleted link; in buffers of the tracer's depth (its image-method kernels)
        extra = complete_specular(rt_scene, positions_m, receivers_m, completion_order,
                                  planes, need=need, buffer_depth=max_depth)
        fresh = [merge_paths(f, e) for f, e in zip(fresh, extra, strict=True)]
    return fresh


@dataclass(frozen=True)
class PathSet:
    """Traced paths from antenna positions to tags (what :func:`trace_paths` returns).

    Attributes
    ----------
    positions_m : numpy.ndarray
        The antenna positions asked for, (k, 3), float64, metres.
    paths : list of SourcePaths
        Per position its paths to the tags it needs, solved at the exact position.
    n_traced_sources : int
        Antenna positions solved by this call (0 when all came from the cache).
    n_solver_calls : int
        Sionna ``PathSolver`` calls made.
    trace_s : float
        Wall time spent in Sionna, s.
    settings : dict
        Solver settings (the cache key's), the ``method``, memory budget, sources per call
        and the number of positions rays were shot from (``n_shooting_points``).
    """

    positions_m: np.ndarray
    paths: list
    n_traced_sources: int
    n_solver_calls: int
    trace_s: float
    settings: dict


def trace_paths(scene, positions_m, tag_positions_m, need=None, options: TraceOptions | None = None, *,
                frequency_hz: float = 865e6, cache_dir=None, progress=None) -> PathSet:
    """Paths from antenna positions to tags: from the cache, or traced by ``options.method``.

    The tracing half of :func:`propagation.trace_links`; the positions must be distinct
    and already checked (:func:`propagation.sionna_scene.check_antenna_positions`).

    Parameters
    ----------
    positions_m : array_like
        Distinct antenna positions (k, 3), metres.
    tag_positions_m : array_like
        Tag positions (m, 3), metres.
    need : array_like of bool, optional
        (k, m): the tags each position needs; default all.
    options : TraceOptions, optional
        Tracer and ray budget; default ``TraceOptions()`` (the study's).
    frequency_hz : float
        Carrier frequency [Hz]; materials are evaluated there.
    cache_dir : str or Path, optional
        Folder of the on-disk path cache (:mod:`propagation.pathcache`).
    progress : callable, optional
        ``progress(done, total)`` in antenna positions traced, called after each chunk.

    Returns
    -------
    PathSet

    Raises
    ------
    propagation.sionna_internals.SionnaVersionError
        ``method="shared"`` with anything to trace on an untested Sionna / Mitsuba /
        Dr.Jit version (cached paths are served whatever the version).
    """
    opt = TraceOptions() if options is None else options
    if not isinstance(opt, TraceOptions):
        raise TypeError(f"options must be a TraceOptions, got {type(opt).__name__}")
    shared = opt.method == "shared"
    max_depth, samples_per_src, seed = int(opt.max_depth), int(opt.samples_per_src), int(opt.seed)
    uniq = np.asarray(positions_m, dtype=float).reshape(-1, 3)
    tags = np.asarray(tag_positions_m, dtype=float).reshape(-1, 3)
    m = len(tags)
    need = np.ones((len(uniq), m), bool) if need is None else np.asarray(need, bool)
    if need.shape != (len(uniq), m):
        raise ValueError(f"need must have shape ({len(uniq)}, {m}), got {need.shape}")
    if not (np.isfinite(frequency_hz) and frequency_hz > 0):
        raise ValueError(f"frequency_hz must be positive, got {frequency_hz!r}")
    # the settings key the cache files are named by: unchanged from the tracers' earlier
    # keyword interface, so caches made before stay valid
    settings = {"frequency_hz": float(frequency_hz), "max_depth": max_depth,
                "samples_per_src": samples_per_src, "seed": seed,
                "los": True, "specular_reflection": True, "refraction": bool(opt.refraction),
                "diffuse_reflection": False, "diffraction": False}
    completion_order = min(int(opt.completion_order), max_depth) if shared else 0  # no path beyond max_depth
    if shared:
        settings["share_radius_m"] = float(opt.share_radius_m)
        settings["shared_samples_per_src"] = int(opt.shared_samples_per_src)
        settings["min_samples_per_position"] = opt.min_samples
        settings["sharing_algorithm"] = SHARING_ALGORITHM
    if completion_order > 0:  # absent at 0: the cache keys of earlier traces stay valid
        settings["completion_order"] = completion_order
        settings["completion_min_area_m2"] = float(opt.completion_min_area_m2)
        if opt.completion_max_planes:  # absent at 0: earlier traces' keys stay valid
            settings["completion_max_planes"] = int(opt.completion_max_planes)
        settings["completion_algorithm"] = COMPLETION_ALGORITHM
    if not shared:
        settings["direct_algorithm"] = DIRECT_ALGORITHM

    cache = PathCache(Path(cache_dir) / settings_key(scene.content_hash(), settings)) if cache_dir else None
    cached = cache.load(uniq) if cache is not None else [None] * len(uniq)
    src_paths: list[SourcePaths] = []
    missing: list[np.ndarray] = []
    for u in range(len(uniq)):
        sp = cached[u] if cached[u] is not None else SourcePaths.empty(uniq[u])
        src_paths.append(sp)
        want = np.flatnonzero(need[u])
        missing.append(want[sp.index_of(tags[want]) < 0] if len(want) else want)
    todo = [u for u in range(len(uniq)) if len(missing[u])]

    budget = int(opt.memory_budget_bytes) if opt.memory_budget_bytes else _default_budget()
    # a call's candidate buffer grows with its tags (at most every tag of this trace)
    n_tgt = len(np.unique(np.concatenate(missing))) if todo else 1
    per_chunk = max(1, min(MAX_SOURCES_PER_CALL, budget // bytes_per_source(samples_per_src, max_depth, n_tgt)))
    lone_samples = max(samples_per_src, opt.min_samples) if shared else samples_per_src
    lone_per_chunk = max(1, min(MAX_SOURCES_PER_CALL, budget // bytes_per_source(lone_samples, max_depth, n_tgt)))
    if shared:  # chunks of positions that share: fewer rays each, but the candidate
        # buffer is held twice (candidates and their solved copy)
        per_chunk = max(1, min(MAX_SOURCES_PER_CALL, budget // (
            2 * bytes_per_source(int(opt.shared_samples_per_src), max_depth, n_tgt))))
    n_calls, t_trace = 0, 0.0
    if todo:
        short = memory_shortfall(opt.method, max_depth, samples_per_src, int(opt.shared_samples_per_src), budget,
                                 n_targets=n_tgt)
        if short:  # before anything is traced: one source is the smallest chunk
            raise ValueError(short)
        ensure_variant()
        if shared:
            check_versions()  # before any work: one line naming the versions and the way out
        chunks = [todo[c0:c0 + per_chunk] for c0 in range(0, len(todo), per_chunk)]
        recs = [np.unique(np.concatenate([missing[u] for u in chunk])) for chunk in chunks]
        needs = [np.stack([np.isin(recs[c], missing[u]) for u in chunk]) for c, chunk in enumerate(chunks)]
        t0 = time.perf_counter()
        n_done = 0
        if progress is not None:  # the total is known before the first chunk: "0/N", not "0/?"
            progress(0, len(todo))
        logger.info("tracing %d antenna positions x %d tags in %d calls of up to %d positions",
                    len(todo), n_tgt, len(chunks), per_chunk)

        def finish(c: int, fresh: list) -> None:
            """A chunk's fresh paths: merged, cached, reported (here, in the calling process)."""
            nonlocal n_done
            for u, sp in zip(chunks[c], fresh, strict=True):
                src_paths[u] = src_paths[u].merged(sp)
            if cache is not None:
                cache.save([src_paths[u] for u in chunks[c]])
            n_done += len(chunks[c])
            if progress is not None:
                progress(n_done, len(todo))
            took = time.perf_counter() - t0
            left = took / n_done * (len(todo) - n_done)
            logger.info("traced %d/%d antenna positions (%d tags) in %.1f s%s",
                        n_done, len(todo), len(recs[c]), took,
                        f"; about {left / 60:.1f} min left at this pace" if n_done < len(todo) else "")

        runner = current_chunk_runner()
        if runner is None:
            state = tracer_state(scene, frequency_hz, shared, completion_order,
                                 float(opt.completion_min_area_m2), int(opt.completion_max_planes))
            t_trace = 0.0
            for c, chunk in enumerate(chunks):
                t1 = time.perf_counter()
                fresh = trace_one_chunk(state, uniq[chunk], tags[recs[c]], opt, lone_samples,
                                        lone_per_chunk, budget, completion_order, needs[c])
                t_trace += time.perf_counter() - t1  # the solver's part, as before the Dask runner
                finish(c, fresh)
        else:  # each chunk a job of the runner (a Dask task): the same chunks, the same paths

            info = backend_info()
            runner([ChunkJob(scene, uniq[chunk], tags[recs[c]], opt, float(frequency_hz), lone_samples,
                             lone_per_chunk, budget, completion_order, str(info["variant"]),
                             bool(info["deterministic"]), needs[c]) for c, chunk in enumerate(chunks)], finish)
        n_calls = len(chunks)
        if runner is not None:  # the cluster's wall time
            t_trace = time.perf_counter() - t0
    elif progress is not None:
        progress(0, 0)
    return PathSet(
        positions_m=uniq, paths=src_paths, n_traced_sources=len(todo), n_solver_calls=n_calls,
        trace_s=t_trace,
        settings={**settings, "method": opt.method, "memory_budget_bytes": budget,
                  "sources_per_call": per_chunk, "n_shooting_points": len(todo),
                  "completion_order": completion_order,
                  "cache_dir": str(cache_dir) if cache_dir else None},
    )
