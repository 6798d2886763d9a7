"""The robot's map: the true floor plan with its walls off the way real maps are off.

A real robot localises in a map that was surveyed, drawn or built by SLAM, and that map
is wrong *systematically*: a whole wall is drawn a few centimetres off, a tape-measure
or SLAM scale error stretches the building by a fraction of a percent. A laser MCL
robot then tracks the map, not the building, and every pose near that wall is shifted
by a similar amount (the bias a real robot shows; Thrun, Burgard & Fox, *Probabilistic
Robotics*, 2005, sec. 6.4 on map errors in the likelihood-field model).

The model here:

1. the floor plan at the laser height (:func:`scenes.floor_plan_segments`, the cut
   of every mesh) is merged into *wall lines*: maximal runs of collinear, touching
   segments (:func:`wall_lines`); one wall face of several triangles or materials is
   one line, a wall interrupted by a door is two;
2. every wall line is displaced along its normal by a signed offset drawn once,
   ``N(0, map_error_m^2)`` (:func:`displace_wall_lines`); lines that met at a corner
   or a T-junction still meet (the moved end point is the intersection of the two
   displaced lines);
3. optionally the whole plan is scaled about the centre of the scene's bounds by
   ``1 + s``, ``s ~ N(0, map_scale_error^2)``;
4. the displaced plan is rasterised into the occupancy grid and likelihood field MCL
   uses (:meth:`OccupancyMap.from_segments`, same grid as the true laser map), and
   optionally a small smooth random displacement of the likelihood field is added on
   top (:meth:`OccupancyMap.with_surface_error`, ``map_noise_m``).

Only the map is wrong: the robot drives in the true scene and the laser is simulated
in the true scene. :func:`draw_robot_map` draws all of it from one generator, so one
call per building gives the one map every tour of a study localises in.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy import ndimage

from pipeline.robot.occupancy import OccupancyMap, slice_heights
from scenes import floor_plan_segments
from scenes.rosmap import FREE, OBSTACLE, boundary_segments, resolve_unknown
from scenes.sources import traits_of

__all__ = [
    "MapError",
    "RobotMap",
    "displace_wall_lines",
    "draw_map_error",
    "draw_robot_map",
    "plan_segments",
    "robot_map",
    "wall_lines",
]

#: Lines closer than this in direction are parallel (no corner is joined between them),
#: sine of the angle: about 11 degrees.
_MIN_CORNER_SINE = 0.2


def _canonical_normal(n: np.ndarray) -> np.ndarray:
    """Unit normal(s) (..., 2) flipped to point to +x, or to +y for walls along x."""
    n = np.asarray(n, dtype=float)
    n = n / np.linalg.norm(n, axis=-1, keepdims=True)
    flip = (n[..., 0] < -1e-9) | ((np.abs(n[..., 0]) <= 1e-9) & (n[..., 1] < 0))
    return np.where(flip[..., None], -n, n)


def wall_lines(
    segments: np.ndarray, tol_m: float = 1e-3, angle_tol_rad: float = 1e-3
) -> tuple[np.ndarray, np.ndarray]:
    """Merge a floor plan's segments into maximal runs of collinear, touching segments.

    Segments whose directions differ by less than ``angle_tol_rad`` and whose lines lie
    within ``tol_m`` of each other are collinear; along their common line, intervals
    that overlap or leave a gap of at most ``tol_m`` are joined. A wall face cut from
    many triangles (or built from several materials) becomes one line; a wall with a
    door in it becomes two.

    Parameters
    ----------
    segments : numpy.ndarray
        Floor-plan segments (m, 2, 2) [m] (:func:`scenes.floor_plan_segments`).
    tol_m : float
        Distance tolerance [m] for "same line" and for "touching".
    angle_tol_rad : float
        Direction tolerance [rad].

    Returns
    -------
    lines : numpy.ndarray
        Wall lines (k, 2, 2) [m], each from its smaller to its larger coordinate along
        the line direction ``(-n_y, n_x)``; in a deterministic order (that of the
        segments' first appearance, then by offset and position along the line).
    normals : numpy.ndarray
        Unit normals (k, 2), pointing to +x (to +y for lines along x): the direction a
        positive offset moves the line (:func:`displace_wall_lines`).
    """
    seg = np.asarray(segments, dtype=float).reshape(-1, 2, 2)
    e = seg[:, 1] - seg[:, 0]
    length = np.linalg.norm(e, axis=1)
    seg, e, length = seg[length > 1e-12], e[length > 1e-12], length[length > 1e-12]
    if len(seg) == 0:
        return np.zeros((0, 2, 2)), np.zeros((0, 2))
    # orientation modulo pi as a doubled-angle unit vector: antiparallel segments agree
    psi = np.arctan2(e[:, 1], e[:, 0])
    u = np.stack([np.cos(2 * psi), np.sin(2 * psi)], 1)
    chord = 2 * np.sin(angle_tol_rad)  # |u_i - u_j| for a direction difference of tol
    group = np.full(len(seg), -1)
    centres = []
    for i in range(len(seg)):  # greedy: O(m * n_directions)
        if group[i] >= 0:
            continue
        near = (group < 0) & (np.linalg.norm(u - u[i], axis=1) <= chord)
        group[near] = len(centres)
        centres.append(i)
    lines, normals = [], []
    for g in range(len(centres)):
        members = np.nonzero(group == g)[0]
        # mean direction of the group (doubled angles averaged, length-weighted)
        uu = (u[members] * length[members, None]).sum(0)
        ang = 0.5 * np.arctan2(uu[1], uu[0])
        d = np.array([np.cos(ang), np.sin(ang)])
        n = _canonical_normal(np.array([-d[1], d[0]]))
        d = np.array([-n[1], n[0]])  # line direction, right-handed with the normal
        mid = seg[members].mean(axis=1)
        c = mid @ n  # signed distance of each segment's line from the origin
        order = np.argsort(c, kind="stable")
        split = np.nonzero(np.diff(c[order]) > tol_m)[0] + 1
        for coll in np.split(members[order], split):
            cc = float(np.average(seg[coll].mean(axis=1) @ n, weights=length[coll]))
            t = seg[coll] @ d  # (j, 2)
            t0, t1 = t.min(1), t.max(1)
            o = np.argsort(t0, kind="stable")
            a, b = t0[o[0]], t1[o[0]]
            for s0, s1 in zip(t0[o[1:]], t1[o[1:]], strict=True):
                if s0 <= b + tol_m:
                    b = max(b, s1)
                else:
                    lines.append([cc * n + a * d, cc * n + b * d])
                    normals.append(n)
                    a, b = s0, s1
            lines.append([cc * n + a * d, cc * n + b * d])
            normals.append(n)
    return np.asarray(lines, dtype=float).reshape(-1, 2, 2), np.asarray(normals).reshape(-1, 2)


def _point_segment_distance(p: np.ndarray, seg: np.ndarray) -> np.ndarray:
    """Distance (n, k) from points (n, 2) to segments (k, 2, 2) [m]."""
    a, e = seg[:, 0], seg[:, 1] - seg[:, 0]
    ee = np.maximum(np.sum(e * e, axis=1), 1e-300)
    ap = p[:, None, :] - a[None]
    t = np.clip(np.sum(ap * e[None], axis=2) / ee[None], 0.0, 1.0)
    return np.linalg.norm(ap - t[..., None] * e[None], axis=2)


def displace_wall_lines(
    lines: np.ndarray,
    normals: np.ndarray,
    offsets_m: np.ndarray,
    scale: float = 0.0,
    centre_m: np.ndarray | None = None,
    tol_m: float = 1e-3,
) -> np.ndarray:
    """Move every wall line along its normal, keep corners closed, scale the plan.

    Each line ``i`` moves by ``offsets_m[i] * normals[i]``. An end point that touched
    another, non-parallel line (a corner, a T-junction: within ``tol_m`` of it before
    the move) goes to the intersection of the two displaced lines, so that walls still
    meet and no gap opens in the plan (of the lines it touched, the most nearly
    perpendicular one). Then every point ``p`` becomes ``centre + (1 + scale) (p - centre)``.

    Parameters
    ----------
    lines : numpy.ndarray
        Wall lines (k, 2, 2) [m] (:func:`wall_lines`).
    normals : numpy.ndarray
        Their unit normals (k, 2).
    offsets_m : numpy.ndarray
        Signed offsets (k,) [m] along the normals.
    scale : float
        Fractional scale error s (the map is ``1 + s`` times the building).
    centre_m : numpy.ndarray, optional
        Centre (2,) [m] of the scaling; default the centre of the lines' bounding box.
    tol_m : float
        Distance [m] within which an end point touches another line.

    Returns
    -------
    numpy.ndarray
        Displaced lines (k, 2, 2) [m].
    """
    ln = np.asarray(lines, dtype=float).reshape(-1, 2, 2)
    nrm = np.asarray(normals, dtype=float).reshape(-1, 2)
    off = np.asarray(offsets_m, dtype=float).reshape(-1)
    if not len(ln) == len(nrm) == len(off):
        raise ValueError(
            f"displace_wall_lines: {len(ln)} lines, {len(nrm)} normals, {len(off)} offsets"
        )
    out = ln + off[:, None, None] * nrm[:, None, :]
    if len(ln) > 1 and np.any(off != 0):
        d = np.stack([-nrm[:, 1], nrm[:, 0]], 1)
        ends = ln.reshape(-1, 2)  # (2k, 2): start, end of line 0, ...
        owner = np.repeat(np.arange(len(ln)), 2)
        j = np.zeros(len(ends), dtype=int)
        best = np.full(len(ends), -1.0)
        step = max(1, 2_000_000 // len(ln))
        for r0 in range(0, len(ends), step):  # (rows, k) blocks bound the memory
            r = slice(r0, r0 + step)
            dist = _point_segment_distance(ends[r], ln)
            do = d[owner[r]]
            sine = np.abs(do[:, 0:1] * d[None, :, 1] - do[:, 1:2] * d[None, :, 0])
            ok = (dist <= tol_m) & (sine >= _MIN_CORNER_SINE)
            ok[np.arange(len(do)), owner[r]] = False
            score = np.where(ok, sine, -1.0)
            j[r] = np.argmax(score, axis=1)
            best[r] = score[np.arange(len(do)), j[r]]
        for q in np.nonzero(best > 0)[0]:
            i, jj = owner[q], j[q]
            # displaced line i: p = out[i, 0] + s d_i; line jj: n_jj . p = n_jj . out[jj, 0]
            den = float(nrm[jj] @ d[i])
            s = float(nrm[jj] @ (out[jj, 0] - out[i, 0])) / den
            out[i, q % 2] = out[i, 0] + s * d[i]  # start stays on line i when moved
    if scale != 0.0 and len(out):
        c = (
            0.5 * (out.reshape(-1, 2).min(0) + out.reshape(-1, 2).max(0))
            if centre_m is None
            else np.asarray(centre_m, dtype=float)
        )
        out = c + (1.0 + float(scale)) * (out - c)
    return out


@dataclass(frozen=True)
class MapError:
    """How the robot's map differs from the building: per-wall offsets and a scale.

    Attributes
    ----------
    lines_m : numpy.ndarray
        True wall lines (k, 2, 2) [m] at the laser height (:func:`wall_lines`).
    normals : numpy.ndarray
        Their unit normals (k, 2) (to +x, or to +y for lines along x).
    offsets_m : numpy.ndarray
        Signed offset (k,) [m] of each line along its normal in the map.
    scale : float
        Fractional scale error s: the map is ``centre + (1 + s) (world - centre)``.
    centre_m : numpy.ndarray
        Centre (2,) [m] of the scaling (the centre of the scene's horizontal bounds).
    height_m : float
        Height of the cut [m] (the laser's scan plane).
    """

    lines_m: np.ndarray
    normals: np.ndarray
    offsets_m: np.ndarray
    scale: float
    centre_m: np.ndarray
    height_m: float

    @property
    def is_zero(self) -> bool:
        """True when the map is the floor plan itself (no offset, no scale error)."""
        return not np.any(self.offsets_m != 0) and self.scale == 0.0

    @property
    def displaced_lines_m(self) -> np.ndarray:
        """The wall lines as the map has them (k, 2, 2) [m] (:func:`displace_wall_lines`)."""
        return displace_wall_lines(self.lines_m, self.normals, self.offsets_m, self.scale,
                                   self.centre_m)

    def to_arrays(self) -> dict[str, np.ndarray]:
        """Arrays for an NPZ file (``tour/map_error.npz``).

        ``segments`` (k, 2, 2) [m], ``normals`` (k, 2), ``offsets_m`` (k,) [m],
        ``scale`` () [1], ``centre_m`` (2,) [m], ``height_m`` () [m] and
        ``displaced_segments`` (k, 2, 2) [m]; :meth:`from_arrays` reads them back.
        """
        return {
            "segments": np.asarray(self.lines_m, dtype=float),
            "normals": np.asarray(self.normals, dtype=float),
            "offsets_m": np.asarray(self.offsets_m, dtype=float),
            "scale": np.asarray(float(self.scale)),
            "centre_m": np.asarray(self.centre_m, dtype=float),
            "height_m": np.asarray(float(self.height_m)),
            "displaced_segments": self.displaced_lines_m,
        }

    @classmethod
    def from_arrays(cls, arrays) -> MapError:
        """Inverse of :meth:`to_arrays` (a mapping or an opened NPZ file)."""
        return cls(
            lines_m=np.asarray(arrays["segments"], dtype=float).reshape(-1, 2, 2),
            normals=np.asarray(arrays["normals"], dtype=float).reshape(-1, 2),
            offsets_m=np.asarray(arrays["offsets_m"], dtype=float).reshape(-1),
            scale=float(arrays["scale"]),
            centre_m=np.asarray(arrays["centre_m"], dtype=float),
            height_m=float(arrays["height_m"]),
        )


@dataclass(frozen=True)
class RobotMap:
    """The map a robot localises in, and how it was drawn.

    Attributes
    ----------
    occupancy_map : OccupancyMap
        Occupancy grid and likelihood field MCL uses (:func:`robot_map`).
    error : MapError
        The drawn wall offsets and scale error.
    """

    occupancy_map: OccupancyMap
    error: MapError


def _scene_centre(scene) -> np.ndarray:
    b = np.asarray(scene.bounds_m, dtype=float)
    return 0.5 * (b[0, :2] + b[1, :2])


def plan_segments(scene, height_m: float) -> np.ndarray:
    """The floor plan the robot's map is drawn from, segments (k, 2, 2) [m].

    The cut of every mesh at the laser height (as the laser map's cut); for a scene
    made from an occupancy grid (its source's :attr:`scenes.sources.SceneTraits.grid`: a
    ROS map, :mod:`scenes.rosmap`) the outline of the grid's obstacle cells instead: the
    robot's map is the map as given, with its imperfections, not the geometry extracted
    from it.
    """
    rm = traits_of(scene).grid(scene)
    if rm is None:
        return floor_plan_segments(scene, slice_heights((height_m, height_m), 1)[0])

    return boundary_segments(resolve_unknown(rm.cell_class) == OBSTACLE, rm.origin_m, rm.resolution_m)


def _grid_map(scene, rm, error: MapError) -> OccupancyMap:
    """The robot's map of a scene from occupancy grid ``rm``, on that grid.

    Free: the map's free cells (enclosed unknown ones resolved as in
    :func:`scenes.rosmap.resolve_unknown`) 4-connected to the route; with a map error,
    the displaced outlines rasterised on the same grid (:meth:`OccupancyMap.from_segments`).
    """
    h = float(error.height_m)
    if not error.is_zero:
        return OccupancyMap.from_segments(error.displaced_lines_m, rm.origin_m, rm.shape,
                                          rm.resolution_m, route_m=scene.route_m, z_range=(h, h),
                                          name=f"{scene.name} (robot map)")
    free = resolve_unknown(rm.cell_class) == FREE
    lab, n = ndimage.label(free)
    if scene.route_m is not None and len(scene.route_m):
        occ = OccupancyMap.from_grid(free, rm.origin_m, rm.resolution_m, np.zeros((0, 2, 2)))
        row, col, inside = occ.cell_index(np.asarray(scene.route_m, dtype=float))
        seeds = np.unique(lab[row[inside], col[inside]])
        seeds = seeds[seeds > 0]
        if not len(seeds):
            raise ValueError(f"{rm.path}: no point of the route of {scene.name!r} lies in the "
                             "map's free space")
    else:
        sizes = ndimage.sum_labels(free, lab, np.arange(1, n + 1))
        seeds = np.array([int(np.argmax(sizes)) + 1])
    return OccupancyMap.from_grid(np.isin(lab, seeds), rm.origin_m, rm.resolution_m,
                                  plan_segments(scene, h), (h, h))


def draw_map_error(
    scene,
    height_m: float,
    map_error_m: float,
    scale_error: float,
    rng: np.random.Generator,
) -> MapError:
    """Draw per-wall offsets ``N(0, map_error_m^2)`` and a scale error ``N(0, scale_error^2)``.

    Parameters
    ----------
    scene : scenes.Scene
    height_m : float
        Height of the laser's scan plane [m]; the floor plan is cut there.
    map_error_m : float
        Standard deviation of the offset of each wall line along its normal [m].
    scale_error : float
        Standard deviation of the fractional scale error [1] (0.001 = 1 mm per metre).
    rng : numpy.random.Generator
        Two independent streams are spawned from it (offsets, scale), so switching the
        scale error on does not change the offsets.

    Returns
    -------
    MapError
        Zero offsets and scale exactly when the standard deviations are 0.
    """
    if not (map_error_m >= 0 and scale_error >= 0):
        raise ValueError(
            f"draw_map_error: map_error_m={map_error_m} and scale_error={scale_error} "
            "must be >= 0"
        )
    rng_off, rng_scale = rng.spawn(2)
    h = float(height_m)
    cut = plan_segments(scene, h)
    lines, normals = wall_lines(cut)
    offsets = (map_error_m * rng_off.standard_normal(len(lines)) if map_error_m > 0
               else np.zeros(len(lines)))
    scale = float(scale_error * rng_scale.standard_normal()) if scale_error > 0 else 0.0
    return MapError(lines, normals, offsets, scale, _scene_centre(scene), h)


def robot_map(
    scene,
    error: MapError,
    resolution_m: float = 0.05,
    noise_m: float = 0.0,
    noise_correlation_m: float = 1.0,
    rng: np.random.Generator | None = None,
) -> OccupancyMap:
    """Rasterise the displaced floor plan into the grid and likelihood field MCL uses.

    Same grid as the true laser map (:meth:`OccupancyMap.scene_grid`); free space is
    what the scene's route reaches. A scene made from an occupancy grid (its source's
    :attr:`scenes.sources.SceneTraits.grid`: a ROS map) gets that grid as given, on its own grid and resolution (``resolution_m`` unused). A zero ``error`` gives the true laser map exactly
    (``OccupancyMap.from_scene`` at the laser height), before the noise.

    Parameters
    ----------
    scene : scenes.Scene
    error : MapError
    resolution_m : float
        Cell size [m].
    noise_m : float
        Standard deviation of a smooth random displacement of the likelihood field added
        on top [m] (:meth:`OccupancyMap.with_surface_error`); 0 = none.
    noise_correlation_m : float
        Correlation length of that displacement [m].
    rng : numpy.random.Generator, optional
        Needed when ``noise_m > 0``.

    Returns
    -------
    OccupancyMap
    """
    h = float(error.height_m)
    grid = traits_of(scene).grid(scene)
    if grid is not None:  # the map as given, on its own grid
        occ = _grid_map(scene, grid, error)
    elif error.is_zero:
        occ = OccupancyMap.from_scene(scene, resolution_m, (h, h), n_slices=1)
    else:
        origin, shape = OccupancyMap.scene_grid(scene, resolution_m)
        occ = OccupancyMap.from_segments(
            error.displaced_lines_m, origin, shape, resolution_m, route_m=scene.route_m,
            z_range=(h, h), name=f"{scene.name} (robot map)",
        )
    if noise_m > 0:
        if rng is None:
            raise ValueError("robot_map: noise_m > 0 needs a random generator (rng)")
        occ = occ.with_surface_error(rng, noise_m, noise_correlation_m)
    return occ


def draw_robot_map(scene, config, rng: np.random.Generator) -> RobotMap:
    """Draw the robot's map of a building once: wall offsets, scale error, smooth noise.

    Call it once per building and pass ``.occupancy_map`` to every
    :func:`pipeline.robot.simulate_localisation` of the study, so that all tours
    localise in the same (wrong) map, as one real robot would.

    Parameters
    ----------
    scene : scenes.Scene
    config : pipeline.robot.LocalisationConfig
        Uses ``scanner.height_m``, ``map_resolution_m``, ``map_error_m``,
        ``map_scale_error``, ``map_noise_m`` and ``map_noise_correlation_m``.
    rng : numpy.random.Generator
        Two streams are spawned from it: the map error (:func:`draw_map_error`) and the
        smooth noise.

    Returns
    -------
    RobotMap
    """
    rng_error, rng_noise = rng.spawn(2)
    error = draw_map_error(scene, config.scanner.height_m, config.map_error_m,
                           config.map_scale_error, rng_error)
    occ = robot_map(scene, error, config.map_resolution_m, config.map_noise_m,
                    config.map_noise_correlation_m, rng_noise)
    return RobotMap(occ, error)
