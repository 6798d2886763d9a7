"""The oracle of RFID-only robot localisation: a ray-traced local-mean gain field.

The RFID particle filter (:mod:`.robot`) needs a likelihood at every particle of every
slot (2000 particles x 321 slots x 16 tags in the default study); tracing each is out
of reach. The oracle here is the reader's own likelihood (:class:`~.likelihood.
OracleLikelihood`) evaluated on the *local mean* of the true gain, tabulated once on a
grid of robot poses:

1. the antenna positions of every free grid pose (``spacing_m`` in x and y,
   ``n_heading`` headings) and mount are grouped into cells of ``lattice_m``; each
   cell's representative position is traced to every tag with the study's tracer
   (cached);
2. every grid antenna pose gets the local mean (paths summed in power) of its cell's
   paths carried to its own position and orientation
   (:func:`propagation.anchored.moved_antenna_local_mean_db`);
3. a particle takes its nearest grid pose's gains, and the reads are scored by the
   reader's likelihood *given the local mean* (:class:`~.fading.FadedLikelihood`): the
   coherent gain the reads were simulated from fades about the local mean (Rayleigh by
   default, :mod:`.fading`), which enters the RSSI twice (the monostatic link fades both
   ways at once): an RSSI offset of mean -5.0 dB and standard deviation 11.1 dB about
   ``reader_rssi_dbm(local mean)``, skewed, and a read probability ``(1 - q) P(E >=
   g_T / g_bar)`` instead of a step. The particles' resolution cannot follow the
   small-scale fading, which changes within a quarter wavelength.

So the robot oracle is the physics at the filter's resolution, not the exact gains: the
fading it averages out is the one thing a robot filter could not use anyway.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from pipeline.localisation.fading import RAYLEIGH, FadedLikelihood, FadedTerms, FadingModel
from pipeline.localisation.global_oracle import widened
from pipeline.localisation.likelihood import GaussianTerms
from pipeline.localisation.oracle_likelihood import OracleLikelihood
from pipeline.robot.kinematics import antenna_poses, mounts_to_array
from propagation.anchored import anchor_groups, moved_antenna_local_mean_db, trace_anchor_paths
from scenes import solid_material_at

__all__ = ["FieldLikelihood", "GainField", "gain_field"]


@dataclass(frozen=True)
class GainField:
    """Local-mean one-way gains on a grid of robot poses, per antenna and tag.

    Attributes
    ----------
    origin_m : numpy.ndarray (2,)
        Centre of grid cell (0, 0) [m].
    spacing_m : float
        Grid step in x and y [m].
    n_heading : int
        Headings per cell, ``2 pi k / n_heading``.
    gain_db : numpy.ndarray (A, nx, ny, n_heading, M), float32
        Gains [dB] per antenna, cell, heading and tag; -inf outside the free space.
    n_traced_links : int
        (lattice position, tag) links traced to build it.
    """

    origin_m: np.ndarray
    spacing_m: float
    n_heading: int
    gain_db: np.ndarray
    n_traced_links: int

    def lookup(self, antenna: int, particles) -> np.ndarray:
        """Gains (N, M) [dB] of antenna ``antenna`` at robot poses (N, 3) [x, y, theta]:
        the nearest grid pose's (clipped to the grid)."""
        p = np.asarray(particles, float).reshape(-1, 3)
        _, nx, ny, nh, _ = self.gain_db.shape
        ix = np.clip(np.rint((p[:, 0] - self.origin_m[0]) / self.spacing_m), 0, nx - 1).astype(int)
        iy = np.clip(np.rint((p[:, 1] - self.origin_m[1]) / self.spacing_m), 0, ny - 1).astype(int)
        ih = np.rint(np.mod(p[:, 2], 2 * np.pi) / (2 * np.pi / nh)).astype(int) % nh
        return self.gain_db[int(antenna), ix, iy, ih].astype(np.float64)


class FieldLikelihood:
    """The oracle's likelihood on a :class:`GainField`, for :class:`~.robot.RfidParticleFilter`.

    Parameters
    ----------
    oracle : OracleLikelihood
        The reader's likelihood (budget, noise, misses).
    field : GainField
        Its gains (local means); tag columns in the order of the filter's tag map.
    fading : FadingModel or None
        The law of the reads' coherent gain about the field's local mean (default
        Rayleigh, :mod:`.fading`); None: the field's gains are the reads' own (no
        small-scale fading, e.g. a free-space field), scored by the reader's Gaussian.
    extra_sigma_db : float
        Gaussian spread of the field's gain about the truth at the particle (the grid's
        resolution) [dB]: widens the RSSI density (and, with ``fading=None``, the soft
        link closure) in quadrature (>= 0).
    """

    def __init__(self, oracle: OracleLikelihood, field: GainField,
                 fading: FadingModel | None = RAYLEIGH, extra_sigma_db: float = 0.0) -> None:
        if not float(extra_sigma_db) >= 0:
            raise ValueError(f"extra_sigma_db must be >= 0, got {extra_sigma_db!r}")
        self.oracle = (widened(oracle, extra_sigma_db) if fading is None
                       else FadedLikelihood(oracle, fading, extra_sigma_db=extra_sigma_db))
        self.field = field

    @property
    def n_tags(self) -> int:
        return int(self.field.gain_db.shape[-1])

    def terms_for_particles(self, particles, antenna: int,
                            tag_mask=None) -> GaussianTerms | FadedTerms:
        """Per (particle, tag) terms (N, M') of the tags selected by ``tag_mask`` (M,)."""
        g = self.field.lookup(antenna, particles)
        if tag_mask is not None:
            g = g[:, np.asarray(tag_mask, bool)]
        return self.oracle.terms(g)


def gain_field(scene, mounts, tag_positions_m, tag_normals, free_space, *, frequency_hz: float,
               trace, pattern_kw: dict, cache_dir=None, spacing_m: float = 0.25,
               n_heading: int = 16, lattice_m: float = 0.5) -> GainField:
    """Tabulate the local-mean gain of every mount to every tag over the free space.

    Parameters
    ----------
    scene : scenes.Scene
    mounts : sequence of AntennaMount or array (A, 4|5)
    tag_positions_m, tag_normals : array_like (M, 3)
        The tag map (positions [m] and surface normals), in the filter's order.
    free_space : object with ``contains(xy)``
        The robot's free space (poses elsewhere get -inf).
    frequency_hz : float
    trace : propagation.TraceOptions
        The study tracer's options (its patterns are not used here: ``pattern_kw``).
    pattern_kw : dict
        Pattern names, as for
        :func:`propagation.anchored.trace_anchor_paths` and
        :func:`~propagation.anchored.moved_antenna_local_mean_db`.
    cache_dir : path, optional
    spacing_m, n_heading, lattice_m : grid step [m], headings, traced cell size [m].

    Returns
    -------
    GainField
    """
    if not (spacing_m > 0 and lattice_m > 0 and int(n_heading) >= 1):
        raise ValueError("gain_field: need spacing_m > 0, lattice_m > 0 and n_heading >= 1")
    tags = np.asarray(tag_positions_m, float).reshape(-1, 3)
    normals = np.asarray(tag_normals, float).reshape(-1, 3)
    if len(tags) == 0:
        raise ValueError("gain_field: the tag map is empty")
    m_arr = mounts_to_array(mounts)
    lo, hi = np.asarray(scene.bounds_m, float)[:, :2]
    xs = np.arange(lo[0], hi[0] + 1e-9, spacing_m)
    ys = np.arange(lo[1], hi[1] + 1e-9, spacing_m)
    gx, gy = np.meshgrid(xs, ys, indexing="ij")
    free = np.asarray(free_space.contains(np.column_stack([gx.ravel(), gy.ravel()])), bool)
    cells = np.flatnonzero(free)
    heading = 2 * np.pi * np.arange(int(n_heading)) / int(n_heading)
    robot = np.column_stack([np.repeat(gx.ravel()[cells], len(heading)),
                             np.repeat(gy.ravel()[cells], len(heading)),
                             np.tile(heading, len(cells))])  # (K, 3)
    ant = antenna_poses(robot, m_arr).reshape(-1, 6)  # (K * A, 6), antenna fastest
    # an antenna outside the scene or inside a solid (a pose at the free space's edge with
    # the mount over a wall) cannot read: -inf
    b_lo, b_hi = np.asarray(scene.bounds_m, float)
    ok = np.all((ant[:, :2] > b_lo[:2]) & (ant[:, :2] < b_hi[:2]), axis=1) & (ant[:, 2] > b_lo[2])
    ok[ok] = solid_material_at(scene, ant[ok, :3]) == ""
    good = np.flatnonzero(ok)
    rep, cell_of = anchor_groups(ant[good, :3], np.zeros((len(good), 3)), lattice_m)
    lattice = ant[good[rep], :3]
    paths = trace_anchor_paths(scene, lattice, tags, np.ones((len(lattice), len(tags)), bool),
                               frequency_hz=frequency_hz, cache_dir=cache_dir, options=trace)
    k, t = np.divmod(np.arange(len(good) * len(tags)), len(tags))
    gains = np.full((len(ant), len(tags)), -np.inf)
    gains[good] = moved_antenna_local_mean_db(paths, cell_of[k], tags, t, normals, ant[good[k]],
                                              **pattern_kw).reshape(len(good), len(tags))
    n_ant = len(m_arr)
    table = np.full((n_ant, len(xs) * len(ys), len(heading), len(tags)), -np.inf, np.float32)
    g = gains.reshape(len(cells), len(heading), n_ant, len(tags))
    table[:, cells] = np.transpose(g, (2, 0, 1, 3))
    return GainField(np.array([xs[0], ys[0]]), float(spacing_m), int(n_heading),
                     table.reshape(n_ant, len(xs), len(ys), len(heading), len(tags)),
                     int(len(lattice) * len(tags)))
