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

import logging
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from propagation.backend import ensure_variant
from propagation.pathcache import PathCache, SourcePaths, settings_key
from propagation.patterns import (
    PATTERNS,
    POLARIZATIONS,
    dipole_rotation,
    pattern_field_world,
    pose_rotation,
    unit_vec_from_theta_phi,
)
from propagation.pooled import pooling_plan, trace_pooled
from propagation.sionna_scene import check_antenna_positions, load_sionna_scene

__all__ = [
    "DEFAULT_MAX_DEPTH",
    "DEFAULT_SAMPLES_PER_SRC",
    "LinkChannels",
    "LinkSet",
    "PathSet",
    "bytes_per_source",
    "link_channels",
    "tag_dipole_axes",
    "trace_links",
    "trace_paths",
]

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
_SPEED_OF_LIGHT = 299_792_458.0
_MAX_SOURCES_PER_CALL = 128
_PATHS_PER_BATCH = 500_000  # pattern re-application batch (~200 MB of temporaries)
#: Pooling radius over lattice spacing: at 1.2 a position pools its ~3 nearest lattice
#: points on a tour (measured, docs/physics.md); wider adds candidates, not accuracy.
POOL_RADIUS_FACTOR = 1.2


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
    reader_polarization: str = "V"
    n_traced_sources: int = 0
    n_solver_calls: int = 0
    trace_s: float = 0.0
    settings: dict = field(default_factory=dict)
    h: np.ndarray | None = None
    dh_dpos: np.ndarray | None = None


def bytes_per_source(samples_per_src: int, max_depth: int) -> int:
    """Estimated peak memory of one source in a ``PathSolver`` call, bytes.

    Measured on the LLVM backend (sionna-rt 2.2) with ``max_num_paths_per_src = samples *
    (depth + 1)``: 40 sources x 1e5 rays took 2.0 GB at depth 3 and 4.1 GB at depth 5;
    17 sources x 3e5 rays at depth 6 took 8.7 GB. The estimate ``samples * (300 + 300 *
    depth)`` bounds these with a margin.
    """
    return int(samples_per_src * (300 + 300 * max(1, max_depth)))


def _default_budget() -> int:
    try:
        with open("/proc/meminfo") as fh:
            for line in fh:
                if line.startswith("MemAvailable:"):
                    return int(int(line.split()[1]) * 1024 * 0.25)
    except OSError:
        pass
    return 4 * 1024**3


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
    poses = np.asarray(antenna_poses, dtype=float)
    if poses.ndim != 2 or poses.shape[1] not in (4, 6):
        raise ValueError(
            "antenna_poses must have shape (n, 4) [x, y, z, yaw_rad] or (n, 6) "
            f"[x, y, z, yaw, pitch, roll], got {poses.shape}"
        )
    if poses.shape[1] == 4:
        poses = np.concatenate([poses, np.zeros((len(poses), 2))], axis=1)
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


def _trace_chunk(rt_scene, sources, receivers, max_depth, samples_per_src, seed, refraction=True):
    """One PathSolver call; returns a SourcePaths per source (all receivers)."""
    import sionna.rt as rt

    from propagation.sionna_scene import clear_devices

    clear_devices(rt_scene)
    rt_scene.tx_array = rt.PlanarArray(num_rows=1, num_cols=1, pattern="iso", polarization="VH")
    rt_scene.rx_array = rt.PlanarArray(num_rows=1, num_cols=1, pattern="iso", polarization="VH")
    for k, p in enumerate(sources):
        rt_scene.add(rt.Transmitter(f"tx{k}", position=[float(v) for v in p]))
    for k, p in enumerate(receivers):
        rt_scene.add(rt.Receiver(f"rx{k}", position=[float(v) for v in p]))
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
    a_re, a_im = (x.numpy() for x in paths.a)  # (n_rx, 2, n_tx, 2, P)
    n_rx, n_tx = len(receivers), len(sources)
    n_p = a_re.shape[-1]
    if n_p == 0:
        out = []
        for p in sources:
            sp = SourcePaths.empty(p)
            sp.tag_positions_m = np.asarray(receivers, float).copy()
            sp.offsets = np.zeros(n_rx + 1, np.int64)
            out.append(sp)
        clear_devices(rt_scene)
        return out
    a = (a_re.astype(np.float64) + 1j * a_im.astype(np.float64)).reshape(n_rx, 2, n_tx, 2, n_p)
    a = np.transpose(a, (2, 0, 4, 1, 3))  # (n_tx, n_rx, P, rx_pol, tx_pol)
    valid = paths.valid.numpy().reshape(n_rx, n_tx, n_p).transpose(1, 0, 2)
    tau = paths.tau.numpy().astype(np.float64).reshape(n_rx, n_tx, n_p).transpose(1, 0, 2)
    th_t = paths.theta_t.numpy().astype(np.float64).reshape(n_rx, n_tx, n_p).transpose(1, 0, 2)
    ph_t = paths.phi_t.numpy().astype(np.float64).reshape(n_rx, n_tx, n_p).transpose(1, 0, 2)
    th_r = paths.theta_r.numpy().astype(np.float64).reshape(n_rx, n_tx, n_p).transpose(1, 0, 2)
    ph_r = paths.phi_r.numpy().astype(np.float64).reshape(n_rx, n_tx, n_p).transpose(1, 0, 2)
    clear_devices(rt_scene)
    out = []
    for s, p in enumerate(sources):
        v = valid[s]  # (n_rx, P); row-major flattening keeps receivers in order
        counts = v.sum(axis=1)
        out.append(SourcePaths(
            source_m=np.asarray(p, float),
            tag_positions_m=np.asarray(receivers, float).copy(),
            offsets=np.concatenate([[0], np.cumsum(counts)]).astype(np.int64),
            transfer=a[s][v],
            tau_s=tau[s][v],
            k_tx=unit_vec_from_theta_phi(th_t[s][v], ph_t[s][v]),
            k_rx=unit_vec_from_theta_phi(th_r[s][v], ph_r[s][v]),
        ))
    return out


@dataclass(frozen=True)
class LinkChannels:
    """Coherent one-way channels of a list of links, from their paths.

    Attributes
    ----------
    h : numpy.ndarray
        Complex one-way channel coefficient incl. both antenna patterns, shape (L,),
        complex128 (``|h|^2`` is the gain; ``arg h`` the one-way phase, e^{j omega t}).
    dh_dpos : numpy.ndarray or None
        Derivative of ``h`` with respect to the antenna position, shape (L, 3),
        complex128, 1/m (each path's phase term only: ``j 2 pi f / c k_tx``; the
        amplitude and pattern terms are smaller by ``1 / (k l)``); None unless asked.
    n_paths : numpy.ndarray
        Paths per link, (L,), int64.
    los : numpy.ndarray
        A line-of-sight path exists, (L,), bool.
    """

    h: np.ndarray
    dh_dpos: np.ndarray | None
    n_paths: np.ndarray
    los: np.ndarray


def link_channels(src_paths, pos_index, tag_index, poses, tags, frequency_hz, reader_pattern: str,
                  reader_polarization: str, tag_pattern: str, tag_axes, gradient: bool = False
                  ) -> LinkChannels:
    """Coherent channels of links (pose, tag) from their path sets, patterns re-applied.

    Parameters
    ----------
    src_paths : list of SourcePaths
        Path sets per antenna position (:attr:`PathSet.paths`).
    pos_index, tag_index : numpy.ndarray
        Per link (L,), int: the path set (antenna position) and the tag row.
    poses : numpy.ndarray
        Per link antenna pose (L, 6) [x, y, z, yaw, pitch, roll]; only the orientation is
        used (the position is that of the path set).
    tags : numpy.ndarray
        Tag positions (m, 3), metres (matched exactly against the path sets).
    frequency_hz : float or numpy.ndarray
        Frequency of each link's coherent sum, scalar or (L,), Hz: the channel of a
        hopping reader. The paths' amplitudes keep the traced carrier's materials and
        free-space factor lambda / (4 pi l): the gain is off by 20 log10(f / f_carrier)
        (0.03 dB across the ETSI band traced at 865 MHz; trace an FCC study at 915 MHz),
        and ITU-R P.2040 permittivities change by well under 1 % across a UHF RFID band.
    reader_pattern, reader_polarization, tag_pattern : str
        As in :func:`trace_links`.
    tag_axes : numpy.ndarray
        Tag dipole axes (m, 3) (:func:`tag_dipole_axes`).
    gradient : bool
        Also return ``dh_dpos``.

    Returns
    -------
    LinkChannels

    Notes
    -----
    Vectorised over links in batches of about ``_PATHS_PER_BATCH`` paths (the per-source
    arrays are gathered into one array per batch), so the cost is per path, not per
    antenna position.
    """
    pos_index = np.asarray(pos_index, dtype=np.int64)
    tag_index = np.asarray(tag_index, dtype=np.int64)
    n_links = len(pos_index)
    freq = np.broadcast_to(np.asarray(frequency_hz, dtype=float), (n_links,))
    h_all = np.zeros(n_links, complex)
    dh_all = np.zeros((n_links, 3), complex) if gradient else None
    los = np.zeros(n_links, bool)
    starts = np.zeros(n_links, np.int64)
    counts = np.zeros(n_links, np.int64)
    order = np.argsort(pos_index, kind="stable")
    bounds = np.flatnonzero(np.diff(pos_index[order])) + 1
    groups = np.split(order, bounds)
    for sel in groups:
        sp = src_paths[pos_index[sel[0]]]
        rows = sp.index_of(tags[tag_index[sel]])
        if np.any(rows < 0):
            raise RuntimeError("internal error: a requested link is missing from the path set")
        starts[sel] = sp.offsets[rows]
        counts[sel] = sp.offsets[rows + 1] - sp.offsets[rows]
    r_reader = pose_rotation(poses)
    r_tag = dipole_rotation(tag_axes)
    g0 = 0
    while g0 < len(groups):
        # a batch of whole source groups holding about _PATHS_PER_BATCH paths
        g1, total = g0, 0
        while g1 < len(groups) and (g1 == g0 or total < _PATHS_PER_BATCH):
            total += int(counts[groups[g1]].sum())
            g1 += 1
        batch = groups[g0:g1]
        g0 = g1
        if total == 0:
            continue
        srcs = [src_paths[pos_index[sel[0]]] for sel in batch]
        base = np.concatenate([[0], np.cumsum([len(sp.tau_s) for sp in srcs])[:-1]]).astype(np.int64)
        transfer = np.concatenate([sp.transfer for sp in srcs])
        tau = np.concatenate([sp.tau_s for sp in srcs])
        k_tx = np.concatenate([sp.k_tx for sp in srcs])
        k_rx = np.concatenate([sp.k_rx for sp in srcs])
        links = np.concatenate(batch)
        gstart = np.concatenate([base[i] + starts[sel] for i, sel in enumerate(batch)])
        cnt = counts[links]
        link = np.repeat(np.arange(len(links)), cnt)
        pidx = np.repeat(gstart - np.concatenate([[0], np.cumsum(cnt)[:-1]]), cnt) + np.arange(int(cnt.sum()))
        lk = links[link]
        c_tx = pattern_field_world(reader_pattern, reader_polarization, r_reader[lk], k_tx[pidx])
        g_rx = pattern_field_world(tag_pattern, "V", r_tag[tag_index[lk]], k_rx[pidx])
        f_path = freq[lk]
        amp = np.einsum("pr,prt,pt->p", np.conj(g_rx), transfer[pidx], c_tx)
        amp = amp * np.exp(-2j * np.pi * f_path * tau[pidx])
        h_re = np.bincount(link, weights=amp.real, minlength=len(links))
        h_im = np.bincount(link, weights=amp.imag, minlength=len(links))
        h_all[links] = h_re + 1j * h_im
        if gradient:
            # d/dp exp(-j 2 pi f l / c) with dl/dp = -k_tx
            damp = (2j * np.pi * f_path / _SPEED_OF_LIGHT * amp)[:, None] * k_tx[pidx]
            for ax in range(3):
                dh_all[links, ax] = (np.bincount(link, weights=damp[:, ax].real, minlength=len(links))
                                     + 1j * np.bincount(link, weights=damp[:, ax].imag,
                                                        minlength=len(links)))
        src_of_link = np.concatenate([np.full(len(sel), i) for i, sel in enumerate(batch)])
        src_pos = np.stack([sp.source_m for sp in srcs])[src_of_link]
        d = np.linalg.norm(tags[tag_index[links]] - src_pos, axis=1)[link]
        is_los = np.abs(tau[pidx] * _SPEED_OF_LIGHT - d) < 1e-3 + 1e-6 * d
        los[links] = np.bincount(link, weights=is_los, minlength=len(links)) > 0
    return LinkChannels(h=h_all, dh_dpos=dh_all, n_paths=counts, los=los)


def trace_links(scene, antenna_poses, tag_positions, frequency_hz: float = 865e6,
                max_depth: int = DEFAULT_MAX_DEPTH, samples_per_src: int = DEFAULT_SAMPLES_PER_SRC,
                reader_pattern: str = "tr38901", tag_pattern: str = "hw_dipole",
                tag_normals=None, pairs=None, cache_dir=None, memory_budget_bytes=None,
                progress=None, reader_polarization: str = "V", seed: int = 42,
                refraction: bool = True, lattice_spacing_m: float | None = None,
                channel_hz=None, channel_gradient: bool = False) -> LinkSet:
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
    frequency_hz : float
        Carrier frequency [Hz]; materials are evaluated there.
    max_depth, samples_per_src : int
        Sionna ``PathSolver`` depth and rays per antenna position. Too few rays miss paths
        silently; the defaults come from the convergence check in ``bench/trace.py``.
    reader_pattern, tag_pattern : str
        Pattern names (``"tr38901"``, ``"hw_dipole"``, ``"dipole"``, ``"iso"``).
    tag_normals : array_like, optional
        (m, 3) tag surface normals; the tag dipole lies in the tag plane along the
        projection of world z (:func:`tag_dipole_axes`). None: vertical dipoles.
    pairs : array_like of bool, optional
        (n, m) mask of links to compute; others get gain 0, gain_db -inf, traced False.
        Each antenna position is traced against the union of tags any of its poses
        needs, and sources are batched, so a few unrequested links are traced and cached.
    cache_dir : str or Path, optional
        Folder of the on-disk path cache (:mod:`propagation.pathcache`); a second call
        with the same scene, positions, frequency and solver settings traces nothing, even
        with other orientations, patterns or polarisation.
    memory_budget_bytes : int, optional
        Peak memory allowed per ``PathSolver`` call; sources are chunked so that
        ``n_sources * bytes_per_source(samples_per_src, max_depth)`` stays below it.
        Default: a quarter of the available RAM.
    progress : callable, optional
        ``progress(done, total)`` in antenna positions traced, called after each chunk.
    reader_polarization : {"V", "H", "RHCP", "LHCP"}
        Reader antenna polarisation. With a circular reader the 3 dB circular-to-linear
        mismatch is inside the gain, so set ``LinkBudget.polarization_loss_db = 0``.
    seed : int
        Sionna sampling seed.
    refraction : bool
        Trace transmission through surfaces (Sionna ``refraction``). True (default) is the
        physics; False drops every path that crosses a wall, cabinet or box (faster, see
        ``bench/trace.py``; links inside one corridor change little).
    lattice_spacing_m : float, optional
        Shoot rays from a cubic lattice of this spacing instead of from every antenna
        position, and solve the exact paths at every position from the candidate chains
        found at the lattice points within ``1.2 * lattice_spacing_m`` of it (pooled,
        :mod:`propagation.pooled`): fewer positions to shoot from on a tour that passes
        the same places twice, and a chain one point's sampling missed is recovered from
        a neighbour's. Measured on ``corridor_lab`` (docs/physics.md): at 0.25 m the
        seed-to-seed p95 over readable links drops from 1.5 dB to 0.9 dB. None (default):
        every position shoots its own rays.
    channel_hz : float or array_like, optional
        Frequency of each pose's coherent sum (n,), Hz (a hopping reader's channel): one
        trace at ``frequency_hz`` (materials evaluated there) serves every channel; the
        gain and ``h`` are those at the channel. Default: ``frequency_hz``.
    channel_gradient : bool
        Also compute ``LinkSet.dh_dpos`` (the Doppler of a moving antenna).

    Returns
    -------
    LinkSet

    Raises
    ------
    ValueError
        Wrong shapes, NaN poses, unknown pattern/polarisation, an antenna outside the
        scene bounds or inside solid geometry (naming the pose index and coordinates).
    scenes.UnknownMaterialError
        If the scene uses a material the library does not know.
    """
    poses, tags, pairs = _validate(antenna_poses, tag_positions, pairs)
    for name in (reader_pattern, tag_pattern):
        if name not in PATTERNS:
            raise ValueError(f"unknown antenna pattern {name!r}; known: {', '.join(PATTERNS)}")
    if reader_polarization not in POLARIZATIONS:
        raise ValueError(f"unknown reader_polarization {reader_polarization!r}; "
                         f"known: {', '.join(POLARIZATIONS)}")
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
    ps = trace_paths(scene, uniq, tags, need, frequency_hz=frequency_hz, max_depth=max_depth,
                     samples_per_src=samples_per_src, cache_dir=cache_dir,
                     memory_budget_bytes=memory_budget_bytes, progress=progress, seed=seed,
                     refraction=refraction, lattice_spacing_m=lattice_spacing_m)

    ii, jj = np.nonzero(pairs)
    gain = np.zeros((n, m))
    h = np.zeros((n, m), complex)
    dh = np.zeros((n, m, 3), complex) if channel_gradient else None
    n_paths = np.zeros((n, m), np.int64)
    los = np.zeros((n, m), bool)
    if len(ii):
        ch = link_channels(ps.paths, inv[ii], jj, poses[ii], tags, channel[ii], reader_pattern,
                           reader_polarization, tag_pattern, tag_axes, gradient=channel_gradient)
        h[ii, jj] = ch.h
        gain[ii, jj] = ch.h.real**2 + ch.h.imag**2
        n_paths[ii, jj], los[ii, jj] = ch.n_paths, ch.los
        if channel_gradient:
            dh[ii, jj] = ch.dh_dpos
    with np.errstate(divide="ignore"):
        gain_db = np.where(pairs, 10.0 * np.log10(gain), -np.inf)
    return LinkSet(
        gain=gain, gain_db=gain_db, n_paths=n_paths, los=los, traced=pairs.copy(),
        frequency_hz=float(frequency_hz), max_depth=int(max_depth),
        samples_per_src=int(samples_per_src), reader_pattern=reader_pattern,
        tag_pattern=tag_pattern, reader_polarization=reader_polarization,
        n_traced_sources=ps.n_traced_sources, n_solver_calls=ps.n_solver_calls,
        trace_s=ps.trace_s, settings=ps.settings, h=h, dh_dpos=dh,
    )


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
        Solver settings, memory budget, sources per call, lattice spacing and the number
        of points rays were shot from (``n_shooting_points``).
    """

    positions_m: np.ndarray
    paths: list
    n_traced_sources: int
    n_solver_calls: int
    trace_s: float
    settings: dict


def trace_paths(scene, positions_m, tag_positions_m, need=None, *, frequency_hz: float = 865e6,
                max_depth: int = DEFAULT_MAX_DEPTH, samples_per_src: int = DEFAULT_SAMPLES_PER_SRC,
                cache_dir=None, memory_budget_bytes=None, progress=None, seed: int = 42,
                refraction: bool = True, lattice_spacing_m: float | None = None) -> PathSet:
    """Paths from antenna positions to tags: from the cache, traced, or carried from a lattice.

    The tracing half of :func:`trace_links` (same parameters); the positions must be
    distinct and already checked (:func:`propagation.sionna_scene.check_antenna_positions`).

    Parameters
    ----------
    positions_m : array_like
        Distinct antenna positions (k, 3), metres.
    tag_positions_m : array_like
        Tag positions (m, 3), metres.
    need : array_like of bool, optional
        (k, m): the tags each position needs; default all.

    Returns
    -------
    PathSet
    """
    uniq = np.asarray(positions_m, dtype=float).reshape(-1, 3)
    tags = np.asarray(tag_positions_m, dtype=float).reshape(-1, 3)
    m = len(tags)
    need = np.ones((len(uniq), m), bool) if need is None else np.asarray(need, bool)
    if need.shape != (len(uniq), m):
        raise ValueError(f"need must have shape ({len(uniq)}, {m}), got {need.shape}")
    if not (np.isfinite(frequency_hz) and frequency_hz > 0):
        raise ValueError(f"frequency_hz must be positive, got {frequency_hz!r}")
    if int(max_depth) < 0 or int(samples_per_src) < 1:
        raise ValueError(f"need max_depth >= 0 and samples_per_src >= 1, got {max_depth}, {samples_per_src}")
    settings = {"frequency_hz": float(frequency_hz), "max_depth": int(max_depth),
                "samples_per_src": int(samples_per_src), "seed": int(seed),
                "los": True, "specular_reflection": True, "refraction": bool(refraction),
                "diffuse_reflection": False, "diffraction": False}
    if lattice_spacing_m is not None:
        if not (np.isfinite(lattice_spacing_m) and lattice_spacing_m > 0):
            raise ValueError(f"lattice_spacing_m must be positive, got {lattice_spacing_m!r}")
        settings["lattice_spacing_m"] = float(lattice_spacing_m)
        settings["pool_radius_m"] = POOL_RADIUS_FACTOR * float(lattice_spacing_m)
    at = uniq
    need_at = need

    cache = PathCache(Path(cache_dir) / settings_key(scene.content_hash(), settings)) if cache_dir else None
    cached = cache.load(at) if cache is not None else [None] * len(at)
    src_paths: list[SourcePaths] = []
    missing: list[np.ndarray] = []
    for u in range(len(at)):
        sp = cached[u] if cached[u] is not None else SourcePaths.empty(at[u])
        src_paths.append(sp)
        want = np.flatnonzero(need_at[u])
        missing.append(want[sp.index_of(tags[want]) < 0] if len(want) else want)
    todo = [u for u in range(len(at)) if len(missing[u])]

    budget = int(memory_budget_bytes) if memory_budget_bytes else _default_budget()
    per_chunk = max(1, min(_MAX_SOURCES_PER_CALL, budget // bytes_per_source(samples_per_src, max_depth)))
    n_calls, t_trace, n_shot = 0, 0.0, 0
    if todo:
        ensure_variant()
        rt_scene = load_sionna_scene(scene, frequency_hz)
        if lattice_spacing_m is not None:
            plan = pooling_plan(scene, at[todo], float(lattice_spacing_m), per_chunk)
            chunks = [[todo[i] for i in c.positions] for c in plan]
        else:
            plan = None
            chunks = [todo[c0:c0 + per_chunk] for c0 in range(0, len(todo), per_chunk)]
        n_shot = 0
        for c, chunk in enumerate(chunks):
            rec = np.unique(np.concatenate([missing[u] for u in chunk]))
            t0 = time.perf_counter()
            if plan is None:
                fresh = _trace_chunk(rt_scene, at[chunk], tags[rec], max_depth, samples_per_src, seed,
                                     refraction)
                n_shot += len(chunk)
            else:
                want = np.zeros((len(chunk), len(rec)), bool)
                for r, u in enumerate(chunk):
                    want[r, np.searchsorted(rec, missing[u])] = True
                fresh = trace_pooled(rt_scene, plan[c].shoot_m, at[chunk], plan[c].neighbours,
                                     tags[rec], want, max_depth, samples_per_src, seed, refraction)
                n_shot += len(plan[c].shoot_m)
            t_trace += time.perf_counter() - t0
            n_calls += 1
            for u, sp in zip(chunk, fresh, strict=True):
                src_paths[u] = src_paths[u].merged(sp)
            if cache is not None:
                cache.save([src_paths[u] for u in chunk])
            done = sum(len(x) for x in chunks[:c + 1])
            if progress is not None:
                progress(done, len(todo))
            logger.info("traced %d/%d antenna positions (%d tags, %d shooting points) in %.1f s",
                        done, len(todo), len(rec), n_shot, t_trace)
    elif progress is not None:
        progress(0, 0)
    return PathSet(
        positions_m=uniq, paths=src_paths, n_traced_sources=len(todo), n_solver_calls=n_calls,
        trace_s=t_trace,
        settings={**settings, "memory_budget_bytes": budget, "sources_per_call": per_chunk,
                  "lattice_spacing_m": None if lattice_spacing_m is None else float(lattice_spacing_m),
                  "n_shooting_points": int(n_shot),
                  "cache_dir": str(cache_dir) if cache_dir else None},
    )
