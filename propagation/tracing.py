"""Ray-traced one-way channel gain between reader-antenna poses and tags (Sionna RT).

``docs/physics.md`` ("Making the truth affordable"): every antenna *position* is
traced once with unrotated isotropic dual-polarised (``VH``) antennas at both ends;
per path the 2x2 polarimetric transfer matrix T, the delay tau and the departure /
arrival directions are kept (and cached on disk, see :mod:`propagation.pathcache`).
Patterns, orientations and polarisations are then applied in NumPy::

    h = sum_paths  conj(g_tag(k_r))^T  T  c_reader(k_t)  exp(-j 2 pi f tau)
    gain = |h|^2

with ``c``/``g`` the antenna patterns rotated into the world spherical basis
(:func:`propagation.patterns.pattern_field_world`), which is the algebra of Sionna's
field calculator (``FieldCalculator.compute_channel_coefficients``: ``a = f_rx^H E``).
The gain is the coherent narrowband one-way channel power gain including both
patterns; e.g. in free space it equals Friis ``G_t G_r (lambda / 4 pi d)^2``.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from propagation.channels import link_channels
from propagation.pathsolve import (
    DEFAULT_MAX_DEPTH,
    DEFAULT_SAMPLES_PER_SRC,
    METHODS,
    TraceMethod,
    TraceOptions,
    trace_paths,
)
from propagation.patterns import as_pose6
from propagation.sionna_scene import check_antenna_positions

__all__ = [
    "DEFAULT_MAX_DEPTH",
    "DEFAULT_SAMPLES_PER_SRC",
    "METHODS",
    "LinkSet",
    "TraceMethod",
    "TraceOptions",
    "tag_dipole_axes",
    "trace_links",
]


@dataclass(frozen=True)
class LinkSet:
    """Ray-traced links between antenna poses (rows) and tags (columns).

    Attributes
    ----------
    gain : numpy.ndarray
        One-way coherent channel power gain incl. both antenna patterns, linear,
        shape (n, m), float64; 0 where not traced.
    gain_db : numpy.ndarray
        10 log10(gain), shape (n, m), dB; -inf where not traced or no path.
    n_paths : numpy.ndarray
        Number of paths found, shape (n, m), int64.
    los : numpy.ndarray
        A line-of-sight path exists, shape (n, m), bool.
    traced : numpy.ndarray
        The link was computed (requested through ``pairs``), shape (n, m), bool.
    frequency_hz : float
        Carrier frequency, Hz.
    max_depth : int
        Maximum interactions per path.
    samples_per_src : int
        Rays shot per antenna position.
    reader_pattern, tag_pattern : str
        Pattern names (:data:`propagation.patterns.PATTERNS`).
    reader_polarization : str
        Reader polarisation (``"V"``, ``"H"``, ``"RHCP"``, ``"LHCP"``).
    n_traced_sources : int
        Antenna positions ray-traced by this call (0 when everything came from the cache).
    n_solver_calls : int
        Sionna ``PathSolver`` calls made by this call.
    trace_s : float
        Wall time spent in Sionna, s.
    settings : dict
        Solver settings and how the call was split (see :class:`PathSet`).
    h : numpy.ndarray
        Complex one-way channel coefficient, shape (n, m), complex128, at each pose's
        channel (``channel_hz``); 0 where not traced. ``|h|^2 = gain``; the backscatter
        (two-way) channel of a monostatic reader is ``h^2``.
    dh_dpos : numpy.ndarray or None
        d h / d (antenna position), shape (n, m, 3), complex128, 1/m, when
        ``channel_gradient`` was asked (:class:`LinkChannels`).
    """

    gain: np.ndarray
    gain_db: np.ndarray
    n_paths: np.ndarray
    los: np.ndarray
    traced: np.ndarray
    frequency_hz: float
    max_depth: int
    samples_per_src: int
    reader_pattern: str
    tag_pattern: str
    reader_polarization: str = "RHCP"
    n_traced_sources: int = 0
    n_solver_calls: int = 0
    trace_s: float = 0.0
    settings: dict = field(default_factory=dict)
    h: np.ndarray | None = None
    dh_dpos: np.ndarray | None = None


def tag_dipole_axes(tag_normals, m: int) -> np.ndarray:
    """Dipole axis per tag: world z projected onto the tag plane (vertical on walls).

    Parameters
    ----------
    tag_normals : array_like or None
        Surface normals (m, 3); None means every dipole is vertical.
    m : int
        Number of tags.

    Returns
    -------
    numpy.ndarray
        Unit axes (m, 3). For a horizontal tag (normal along z) the axis is world x
        projected onto the plane.
    """
    if tag_normals is None:
        return np.tile([0.0, 0.0, 1.0], (m, 1))
    n = np.asarray(tag_normals, dtype=float)
    if n.shape != (m, 3) or not np.all(np.isfinite(n)):
        raise ValueError(f"tag_normals must be finite with shape ({m}, 3), got {n.shape}")
    norm = np.linalg.norm(n, axis=1, keepdims=True)
    if np.any(norm < 1e-12):
        raise ValueError(f"tag_normals has zero rows: {np.flatnonzero(norm[:, 0] < 1e-12).tolist()}")
    n = n / norm
    z = np.array([0.0, 0.0, 1.0])
    axis = z - (n @ z)[:, None] * n
    flat = np.linalg.norm(axis, axis=1) < 1e-6
    x = np.array([1.0, 0.0, 0.0])
    axis[flat] = x - (n[flat] @ x)[:, None] * n[flat]
    return axis / np.linalg.norm(axis, axis=1, keepdims=True)


def _validate(antenna_poses, tag_positions, pairs):
    if np.ndim(antenna_poses) != 2:
        raise ValueError(f"antenna_poses must have shape (n, 4) or (n, 6), got {np.shape(antenna_poses)}")
    poses = as_pose6(antenna_poses)
    bad = ~np.all(np.isfinite(poses), axis=1)
    if np.any(bad):
        i = int(np.flatnonzero(bad)[0])
        raise ValueError(f"antenna pose {i} is not finite: {poses[i].tolist()}")
    tags = np.asarray(tag_positions, dtype=float)
    if tags.ndim != 2 or tags.shape[1] != 3:
        raise ValueError(f"tag_positions must have shape (m, 3), got {tags.shape}")
    bad = ~np.all(np.isfinite(tags), axis=1)
    if np.any(bad):
        i = int(np.flatnonzero(bad)[0])
        raise ValueError(f"tag position {i} is not finite: {tags[i].tolist()}")
    if pairs is None:
        pairs = np.ones((len(poses), len(tags)), dtype=bool)
    else:
        pairs = np.asarray(pairs)
        if pairs.shape != (len(poses), len(tags)) or pairs.dtype != bool:
            raise ValueError(
                f"pairs must be a bool mask of shape ({len(poses)}, {len(tags)}), "
                f"got {pairs.dtype} {pairs.shape}"
            )
    return poses, tags, pairs


def trace_links(scene, antenna_poses, tag_positions, options: TraceOptions | None = None, *,
                frequency_hz: float = 865e6, tag_normals=None, pairs=None, channel_hz=None,
                channel_gradient: bool = False, cache_dir=None, progress=None) -> LinkSet:
    """Ray-trace the one-way channel gain between antenna poses and tags.

    Parameters
    ----------
    scene : scenes.Scene
        The scene: its radio surfaces are traced (each physical layer once, see
        :mod:`scenes.radio`; its solid meshes as they are when it has none), its solids
        bound and check the antenna positions.
    antenna_poses : array_like
        (n, 4) [x, y, z, yaw] or (n, 6) [x, y, z, yaw, pitch, roll] [m, rad]; boresight is
        the local +x axis, positive pitch tilts it up (see :mod:`propagation.patterns`).
    tag_positions : array_like
        (m, 3) tag positions [m].
    options : TraceOptions, optional
        The tracer (``method``), its ray budget, the antenna patterns and polarisation,
        the seed. Default ``TraceOptions()``: the study's tracer and settings, so a
        library call gives the study's truth.
    frequency_hz : float
        Carrier frequency [Hz]; materials are evaluated there.
    tag_normals : array_like, optional
        (m, 3) tag surface normals; the tag dipole lies in the tag plane along the
        projection of world z (:func:`tag_dipole_axes`). None: vertical dipoles.
    pairs : array_like of bool, optional
        (n, m) mask of links to compute; others get gain 0, gain_db -inf, traced False.
        Each antenna position is traced against the union of tags any of its poses
        needs, and sources are batched, so a few unrequested links are traced and cached.
    channel_hz : float or array_like, optional
        Frequency of each pose's coherent sum (n,), Hz (a hopping reader's channel): one
        trace at ``frequency_hz`` (materials evaluated there) serves every channel; the
        gain and ``h`` are those at the channel. Default: ``frequency_hz``.
    channel_gradient : bool
        Also compute ``LinkSet.dh_dpos`` (the Doppler of a moving antenna).
    cache_dir : str or Path, optional
        Folder of the on-disk path cache (:mod:`propagation.pathcache`); a second call
        with the same scene, positions, frequency and solver settings traces nothing, even
        with other orientations, patterns or polarisation.
    progress : callable, optional
        ``progress(done, total)`` in antenna positions traced, called after each chunk.

    Returns
    -------
    LinkSet

    Raises
    ------
    ValueError
        Wrong shapes, NaN poses, an antenna outside the scene bounds or inside solid
        geometry (naming the pose index and coordinates).
    scenes.UnknownMaterialError
        If the scene uses a material the library does not know.
    propagation.sionna_internals.SionnaVersionError
        ``method="shared"`` on an untested Sionna / Mitsuba / Dr.Jit version.
    """
    opt = TraceOptions() if options is None else options
    if not isinstance(opt, TraceOptions):
        raise TypeError(f"options must be a TraceOptions, got {type(opt).__name__}")
    poses, tags, pairs = _validate(antenna_poses, tag_positions, pairs)
    n, m = pairs.shape
    if channel_hz is None:
        channel = np.full(n, float(frequency_hz))
    else:
        channel = np.broadcast_to(np.asarray(channel_hz, dtype=float), (n,)).copy()
        if not np.all(np.isfinite(channel) & (channel > 0)):
            raise ValueError("channel_hz must be positive and finite")
    tag_axes = tag_dipole_axes(tag_normals, len(tags))
    active = np.flatnonzero(pairs.any(axis=1))
    if len(active):
        check_antenna_positions(scene, poses[active, :3])
    uniq, inv = np.unique(poses[:, :3], axis=0, return_inverse=True)
    inv = inv.reshape(-1)
    need = np.zeros((len(uniq), m), dtype=bool)
    np.logical_or.at(need, inv, pairs)
    ps = trace_paths(scene, uniq, tags, need, opt, frequency_hz=frequency_hz, cache_dir=cache_dir,
                     progress=progress)

    ii, jj = np.nonzero(pairs)
    gain = np.zeros((n, m))
    h = np.zeros((n, m), complex)
    dh = np.zeros((n, m, 3), complex) if channel_gradient else None
    n_paths = np.zeros((n, m), np.int64)
    los = np.zeros((n, m), bool)
    if len(ii):
        ch = link_channels(ps.paths, inv[ii], jj, poses[ii], tags, channel[ii], opt.reader_pattern,
                           opt.reader_polarization, opt.tag_pattern, tag_axes, gradient=channel_gradient)
        h[ii, jj] = ch.h
        gain[ii, jj] = ch.h.real**2 + ch.h.imag**2
        n_paths[ii, jj], los[ii, jj] = ch.n_paths, ch.los
        if channel_gradient:
            dh[ii, jj] = ch.dh_dpos
    with np.errstate(divide="ignore"):
        gain_db = np.where(pairs, 10.0 * np.log10(gain), -np.inf)
    return LinkSet(
        gain=gain, gain_db=gain_db, n_paths=n_paths, los=los, traced=pairs.copy(),
        frequency_hz=float(frequency_hz), max_depth=int(opt.max_depth),
        samples_per_src=int(opt.samples_per_src), reader_pattern=opt.reader_pattern,
        tag_pattern=opt.tag_pattern, reader_polarization=opt.reader_polarization,
        n_traced_sources=ps.n_traced_sources, n_solver_calls=ps.n_solver_calls,
        trace_s=ps.trace_s, settings=ps.settings, h=h, dh_dpos=dh,
    )
