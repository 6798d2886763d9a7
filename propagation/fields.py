"""Ray-traced gain fields of one reader-antenna pose: a horizontal plane and the wall surfaces.

Sionna's ``RadioMapSolver`` shoots rays from the transmitter and accumulates, per cell,
the Monte-Carlo mean of the path power crossing it: the *local mean* gain, without
small-scale fading (``shared/SIONNA_NOTES.md``). The receiver is isotropic there: the tag
pattern is not in these fields (unlike :func:`propagation.trace_links`).
"""

from __future__ import annotations

import tempfile
from dataclasses import asdict, dataclass, fields
from pathlib import Path

import numpy as np
import trimesh

from propagation.analytic import linear_to_db
from propagation.backend import ensure_variant
from propagation.patterns import PATTERNS, POLARIZATIONS, sionna_orientation
from propagation.sionna_scene import check_antenna_positions, clear_devices, load_sionna_scene
from scenes.fileio import atomic_save_npz

__all__ = ["RssiField", "rssi_field", "wall_surface_mesh"]


@dataclass(frozen=True)
class RssiField:
    """Gain fields from one antenna pose.

    Attributes
    ----------
    antenna_pose : numpy.ndarray
        (6,) [x, y, z, yaw, pitch, roll] [m, rad].
    frequency_hz : float
        Carrier [Hz].
    plane_gain : numpy.ndarray
        One-way local-mean gain (reader pattern included, isotropic receiver), linear,
        shape (ny, nx), float64; 0 where no ray arrived.
    plane_centers_m : numpy.ndarray
        Cell centres (ny, nx, 3), metres.
    wall_gain : numpy.ndarray
        Same quantity per wall-surface triangle, (k,), float64 (empty if not computed).
    wall_centers_m : numpy.ndarray
        Triangle centres (k, 3), metres.
    wall_normals : numpy.ndarray
        Triangle normals pointing into free space (k, 3).
    cell_size_m : float
        Plane cell size [m].
    plane_height_m : float
        Height of the plane [m].
    samples_per_tx, max_depth : int
        Solver settings.
    reader_pattern, reader_polarization : str
        Reader antenna used.
    """

    antenna_pose: np.ndarray
    frequency_hz: float
    plane_gain: np.ndarray
    plane_centers_m: np.ndarray
    wall_gain: np.ndarray
    wall_centers_m: np.ndarray
    wall_normals: np.ndarray
    cell_size_m: float
    plane_height_m: float
    samples_per_tx: int
    max_depth: int
    reader_pattern: str = "tr38901"
    reader_polarization: str = "V"

    @property
    def plane_gain_db(self) -> np.ndarray:
        """10 log10(plane_gain) [dB], -inf where no ray arrived."""
        return linear_to_db(self.plane_gain)

    @property
    def wall_gain_db(self) -> np.ndarray:
        """10 log10(wall_gain) [dB]."""
        return linear_to_db(self.wall_gain)

    def save(self, path) -> Path:
        """Write as NPZ (temporary file, then rename); returns the path."""
        data = {k: np.asarray(v) for k, v in asdict(self).items()}
        return atomic_save_npz(path, compressed=True, **data)

    @classmethod
    def load(cls, path) -> RssiField:
        """Read a field written by :meth:`save`; a missing key raises naming the file."""
        path = Path(path)
        with np.load(path, allow_pickle=False) as z:
            missing = [f.name for f in fields(cls) if f.name not in z.files]
            if missing:
                raise ValueError(f"{path}: not an RssiField file (missing {missing})")
            kw = {}
            for f in fields(cls):
                v = z[f.name]
                kw[f.name] = v.item() if v.ndim == 0 else v
        for k in ("samples_per_tx", "max_depth"):
            kw[k] = int(kw[k])
        for k in ("frequency_hz", "cell_size_m", "plane_height_m"):
            kw[k] = float(kw[k])
        for k in ("reader_pattern", "reader_polarization"):
            kw[k] = str(kw[k])
        return cls(**kw)


def wall_surface_mesh(scene, max_edge_m: float = 0.1, offset_m: float = 0.01) -> trimesh.Trimesh:
    """Measurement surface over the walls where tags sit.

    Vertical faces (|n_z| < 0.1) of every mesh whose face centre, moved ``offset_m`` along
    the face normal, stays inside the scene bounds (inner faces of the corridor walls,
    cabinet and box sides; not the outside of the outer walls), subdivided to edges of at
    most ``max_edge_m`` and moved ``offset_m`` into free space.
    """
    mesh = scene.combined_mesh()
    n = mesh.face_normals
    c = mesh.triangles_center + offset_m * n
    lo, hi = scene.bounds_m
    keep = (np.abs(n[:, 2]) < 0.1) & np.all((c > lo) & (c < hi), axis=1)
    if not np.any(keep):
        raise ValueError(f"scene {scene.name!r} has no inner vertical wall faces")
    sub = mesh.submesh([np.flatnonzero(keep)], append=True)
    v, f = trimesh.remesh.subdivide_to_size(sub.vertices, sub.faces, max_edge=max_edge_m)
    out = trimesh.Trimesh(v, f, process=False)
    # move each face along its own normal (vertices duplicated per face)
    tri = out.triangles + offset_m * out.face_normals[:, None, :]
    return trimesh.Trimesh(tri.reshape(-1, 3), np.arange(len(tri) * 3).reshape(-1, 3), process=False)


def rssi_field(scene, antenna_pose, frequency_hz: float = 865e6, cell_size_m: float = 0.1,
               plane_height_m: float = 1.0, samples_per_tx: int = 1_000_000, max_depth: int = 5,
               include_walls: bool = True, wall_samples_per_tx: int | None = None,
               wall_max_edge_m: float = 0.1, plane_bounds_m=None,
               reader_pattern: str = "tr38901", reader_polarization: str = "V",
               seed: int = 42) -> RssiField:
    """Radio maps of one reader-antenna pose: a horizontal plane and the wall surfaces.

    Parameters
    ----------
    scene : scenes.Scene
        The scene.
    antenna_pose : array_like
        (4,) [x, y, z, yaw] or (6,) [x, y, z, yaw, pitch, roll] [m, rad].
    frequency_hz : float
        Carrier [Hz].
    cell_size_m : float
        Square cell size of the plane [m].
    plane_height_m : float
        Height of the horizontal plane [m].
    samples_per_tx, max_depth : int
        ``RadioMapSolver`` rays and depth (1e6 rays, depth 5: 0.27 s per map on 2 cores).
    include_walls : bool
        Also compute the wall-surface map (:func:`wall_surface_mesh`).
    wall_samples_per_tx : int, optional
        Rays for the wall map (default ``10 * samples_per_tx``: triangles are small).
    wall_max_edge_m : float
        Triangle edge length of the wall surface [m].
    plane_bounds_m : array_like, optional
        (xmin, ymin, xmax, ymax) of the plane; default the scene bounds.
    reader_pattern, reader_polarization : str
        Reader antenna (Sionna patterns; circular is not available in radio maps).
    seed : int
        Sionna sampling seed.

    Returns
    -------
    RssiField
    """
    pose = np.asarray(antenna_pose, dtype=float).reshape(-1)
    if pose.shape not in ((4,), (6,)):
        raise ValueError(f"antenna_pose must have 4 or 6 values, got shape {pose.shape}")
    if not np.all(np.isfinite(pose)):
        raise ValueError(f"antenna_pose is not finite: {pose.tolist()}")
    if pose.shape == (4,):
        pose = np.concatenate([pose, [0.0, 0.0]])
    if reader_pattern not in PATTERNS:
        raise ValueError(f"unknown antenna pattern {reader_pattern!r}; known: {', '.join(PATTERNS)}")
    if reader_polarization not in POLARIZATIONS[:2]:
        raise ValueError(f"radio maps support reader_polarization 'V' or 'H', got {reader_polarization!r}")
    if not cell_size_m > 0:
        raise ValueError(f"cell_size_m must be > 0, got {cell_size_m!r}")
    check_antenna_positions(scene, pose[None, :3])
    ensure_variant()
    import mitsuba as mi
    import sionna.rt as rt

    rt_scene = load_sionna_scene(scene, frequency_hz)
    rt_scene.tx_array = rt.PlanarArray(num_rows=1, num_cols=1, pattern=reader_pattern,
                                       polarization=reader_polarization)
    rt_scene.rx_array = rt.PlanarArray(num_rows=1, num_cols=1, pattern="iso", polarization="V")
    ori = sionna_orientation(pose[3], pose[4], pose[5])
    rt_scene.add(rt.Transmitter("reader", position=[float(v) for v in pose[:3]],
                                orientation=[float(v) for v in ori]))
    if plane_bounds_m is None:
        lo, hi = scene.bounds_m
        x0, y0, x1, y1 = (float(v) for v in (lo[0], lo[1], hi[0], hi[1]))
    else:
        x0, y0, x1, y1 = (float(v) for v in plane_bounds_m)
    solver = rt.RadioMapSolver()
    common = dict(max_depth=int(max_depth), los=True, specular_reflection=True,
                  diffuse_reflection=False, refraction=True, diffraction=False, seed=int(seed))
    rm = solver(rt_scene, center=mi.Point3f((x0 + x1) / 2, (y0 + y1) / 2, float(plane_height_m)),
                orientation=mi.Point3f(0.0, 0.0, 0.0), size=mi.Point2f(x1 - x0, y1 - y0),
                cell_size=mi.Point2f(float(cell_size_m), float(cell_size_m)),
                samples_per_tx=int(samples_per_tx), **common)
    plane_gain = rm.path_gain.numpy()[0].astype(np.float64)
    plane_centers = rm.cell_centers.numpy().astype(np.float64)
    wall_gain = np.zeros(0)
    wall_centers = np.zeros((0, 3))
    wall_normals = np.zeros((0, 3))
    if include_walls:
        surf = wall_surface_mesh(scene, max_edge_m=wall_max_edge_m)
        with tempfile.TemporaryDirectory(prefix="rfidstudy-wall-") as tmp:
            ply = Path(tmp) / "walls.ply"
            ply.write_bytes(surf.export(file_type="ply", encoding="binary"))
            mi_mesh = rt.load_mesh(str(ply))
            wm = solver(rt_scene, measurement_surface=mi_mesh,
                        samples_per_tx=int(wall_samples_per_tx or 10 * samples_per_tx), **common)
            wall_gain = wm.path_gain.numpy()[0].astype(np.float64)
        wall_centers = surf.triangles_center
        wall_normals = surf.face_normals
    clear_devices(rt_scene)
    return RssiField(
        antenna_pose=pose, frequency_hz=float(frequency_hz), plane_gain=plane_gain,
        plane_centers_m=plane_centers, wall_gain=wall_gain, wall_centers_m=wall_centers,
        wall_normals=wall_normals, cell_size_m=float(cell_size_m),
        plane_height_m=float(plane_height_m), samples_per_tx=int(samples_per_tx),
        max_depth=int(max_depth), reader_pattern=reader_pattern,
        reader_polarization=reader_polarization,
    )
