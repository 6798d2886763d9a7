"""Ray-traced gain fields of one reader-antenna pose: a horizontal plane and the wall surfaces.

Sionna's ``RadioMapSolver`` shoots rays from the transmitter and accumulates, per cell,
the Monte-Carlo mean of the path power crossing it: the *local mean* gain, without
small-scale fading (``docs/physics.md``, "Radio maps"). The receiver is isotropic there: the tag
pattern is not in these fields (unlike :func:`propagation.trace_links`).
"""

from __future__ import annotations

import hashlib
import json
import tempfile
import warnings
from dataclasses import asdict, dataclass, fields
from pathlib import Path

import numpy as np
import trimesh

from propagation.analytic import linear_to_db
from propagation.backend import ensure_variant
from propagation.pathcache import CacheWarning, solver_versions, values_sha256
from propagation.patterns import PATTERNS, POLARIZATIONS, sionna_orientation
from propagation.sionna_scene import (
    check_antenna_positions,
    clear_devices,
    device_point,
    load_sionna_scene,
)
from scenes.fileio import atomic_save_npz, atomic_write_text, read_npz
from scenes.geometry import in_triangles_2d

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
        Reader antenna used (a circular one's map is halved: :func:`rssi_field`).
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
        with read_npz(path) as z:
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


def _grid_over_faces(tri: np.ndarray, normal: np.ndarray, max_edge_m: float, offset_m: float) -> np.ndarray:
    """Regular grid of square-ish cells over coplanar vertical triangles ``tri`` (k, 3, 3).

    Cells span the faces' bounding rectangle in the plane (u horizontal, v = z) with edges
    of at most ``max_edge_m``; a cell is kept when its centre lies in one of the triangles.
    Returns triangles (2 per cell) moved ``offset_m`` along ``normal``, shape (c, 3, 3),
    wound counter-clockwise about ``normal``.
    """
    v_ax = np.array([0.0, 0.0, 1.0])
    u_ax = np.cross(v_ax, normal)
    u_ax /= np.linalg.norm(u_ax)
    origin = tri[0, 0] + offset_m * normal
    uv = np.stack([(tri - tri[0, 0]) @ u_ax, (tri - tri[0, 0]) @ v_ax], axis=-1)  # (k, 3, 2)
    lo, hi = uv.reshape(-1, 2).min(0), uv.reshape(-1, 2).max(0)
    nu, nv = (max(1, int(np.ceil((b - a) / max_edge_m - 1e-9))) for a, b in zip(lo, hi, strict=True))
    us, vs = np.linspace(lo[0], hi[0], nu + 1), np.linspace(lo[1], hi[1], nv + 1)
    cu, cv = np.meshgrid((us[:-1] + us[1:]) / 2, (vs[:-1] + vs[1:]) / 2, indexing="ij")
    c = np.stack([cu.ravel(), cv.ravel()], axis=1)
    inside = in_triangles_2d(c, uv)
    iu, iv = np.unravel_index(np.flatnonzero(inside), (nu, nv))
    u0, u1, v0, v1 = us[iu], us[iu + 1], vs[iv], vs[iv + 1]

    def pt(u, v):
        return origin + u[:, None] * u_ax + v[:, None] * v_ax

    p00, p10, p11, p01 = pt(u0, v0), pt(u1, v0), pt(u1, v1), pt(u0, v1)
    # u x v = normal, so (p00, p10, p11) is counter-clockwise seen from the normal side
    return np.concatenate([np.stack([p00, p10, p11], 1), np.stack([p00, p11, p01], 1)])


def wall_surface_mesh(scene, max_edge_m: float = 0.1, offset_m: float = 0.01) -> trimesh.Trimesh:
    """Measurement surface over the walls where tags sit: a regular grid per wall face.

    Built on the scene's solid meshes (where tags sit), not on its radio surfaces: a
    generated wall's radio surface lies on the solid's inner face, so the grid is
    ``offset_m`` in front of what the tracer sees (of a stud wall's inner leaf, of a
    recessed door leaf's face).

    Vertical faces (|n_z| < 0.1) of every mesh whose face centre, moved ``offset_m`` along
    the face normal, stays inside the scene bounds (inner faces of the corridor walls,
    cabinet and box sides; not the outside of the outer walls) are grouped by plane; each
    plane gets a regular grid of cells with edges of at most ``max_edge_m`` (two triangles
    per cell, kept where the cell centre lies on a face), moved ``offset_m`` into free
    space. Coplanar faces of different meshes share one grid (no double triangles).

    Returns
    -------
    trimesh.Trimesh
        Unmerged triangles (3 vertices each), normals pointing into free space; for
        ``corridor_lab`` at 0.1 m about 39k triangles (subdividing the faces, which also
        splits the short edges of long triangles, gave 174k).
    """
    if not max_edge_m > 0:
        raise ValueError(f"wall_max_edge_m must be > 0, got {max_edge_m!r}")
    mesh = scene.combined_mesh()
    n = mesh.face_normals
    c = mesh.triangles_center + offset_m * n
    lo, hi = scene.bounds_m
    keep = (np.abs(n[:, 2]) < 0.1) & np.all((c > lo) & (c < hi), axis=1)
    if not np.any(keep):
        raise ValueError(f"scene {scene.name!r} has no inner vertical wall faces")
    tri_all = mesh.triangles[keep]
    n_h = n[keep].copy()
    n_h[:, 2] = 0.0
    n_h /= np.linalg.norm(n_h, axis=1, keepdims=True)
    plane = np.column_stack([n_h[:, :2], np.einsum("ij,ij->i", n_h, tri_all[:, 0])])
    _, group = np.unique(np.round(plane, 6), axis=0, return_inverse=True)
    parts = [_grid_over_faces(tri_all[group.reshape(-1) == g], n_h[group.reshape(-1) == g][0],
                              max_edge_m, offset_m)
             for g in range(int(group.max()) + 1)]
    tri = np.concatenate(parts)
    return trimesh.Trimesh(tri.reshape(-1, 3), np.arange(len(tri) * 3).reshape(-1, 3), process=False)


def rssi_field(scene, antenna_pose, frequency_hz: float = 865e6, cell_size_m: float = 0.1,
               plane_height_m: float = 1.0, samples_per_tx: int = 1_000_000, max_depth: int = 5,
               include_walls: bool = True, wall_samples_per_tx: int | None = None,
               wall_max_edge_m: float = 0.1, plane_bounds_m=None,
               reader_pattern: str = "tr38901", reader_polarization: str = "RHCP",
               seed: int = 42, cache_dir=None) -> RssiField:
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
        Reader antenna. A radio map's receiver takes the whole wave (Sionna's radio maps
        have no receiver antenna): for a linear reader that is what a co-polar tag takes
        on the direct path. A linear tag takes half of a circular wave whatever its
        orientation (exactly, on the direct path), and a circular and a linear panel of
        one pattern radiate the same power in every direction, so a circular reader's
        map (``"RHCP"``, ``"LHCP"``; Sionna's arrays are linear) is the map of the ``"V"``
        panel, halved: a local mean, blind to the depolarisation of reflections as
        every radio map is to the tag's orientation.
    seed : int
        Sionna sampling seed.
    cache_dir : str or Path, optional
        Folder of an on-disk cache: the field is stored as
        ``<cache_dir>/rssi_field-<key>.npz`` (:meth:`RssiField.save`), ``key`` hashing the
        scene's content hash, the pose and every setting above; a second call traces
        nothing. An unreadable file gives a :class:`~propagation.CacheWarning` naming it
        and is computed again.

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
    if reader_polarization not in POLARIZATIONS:
        raise ValueError(f"unknown reader_polarization {reader_polarization!r}; known: {', '.join(POLARIZATIONS)}")
    circular = reader_polarization in ("RHCP", "LHCP")
    if not cell_size_m > 0:
        raise ValueError(f"cell_size_m must be > 0, got {cell_size_m!r}")
    check_antenna_positions(scene, pose[None, :3])
    if plane_bounds_m is None:
        lo, hi = scene.bounds_m
        x0, y0, x1, y1 = (float(v) for v in (lo[0], lo[1], hi[0], hi[1]))
    else:
        bounds = np.asarray(plane_bounds_m, dtype=float).reshape(-1)
        if bounds.shape != (4,) or not np.all(np.isfinite(bounds)) or not (
                bounds[2] > bounds[0] and bounds[3] > bounds[1]):
            raise ValueError(f"plane_bounds_m must be finite (xmin, ymin, xmax, ymax) with "
                             f"xmax > xmin and ymax > ymin, got {plane_bounds_m!r}")
        x0, y0, x1, y1 = (float(v) for v in bounds)
    wall_spp = int(wall_samples_per_tx or 10 * samples_per_tx)
    cache_file = None
    if cache_dir is not None:
        key = {"format": 1, "scene": scene.content_hash(), "pose": pose.tobytes().hex(),
               "versions": solver_versions(),
               "frequency_hz": float(frequency_hz), "cell_size_m": float(cell_size_m),
               "plane_height_m": float(plane_height_m), "samples_per_tx": int(samples_per_tx),
               "max_depth": int(max_depth), "include_walls": bool(include_walls),
               "wall_samples_per_tx": wall_spp, "wall_max_edge_m": float(wall_max_edge_m),
               "plane_bounds_m": [x0, y0, x1, y1], "reader_pattern": reader_pattern,
               "reader_polarization": reader_polarization, "seed": int(seed)}
        digest = hashlib.sha256(json.dumps(key, sort_keys=True).encode()).hexdigest()[:32]
        cache_file = Path(cache_dir) / f"rssi_field-{digest}.npz"
        if cache_file.exists():
            try:
                return _load_checked(cache_file)
            except Exception as exc:  # noqa: BLE001 - any damage means "recompute"
                warnings.warn(f"unreadable field cache file {cache_file} ({exc}); computing it again",
                              CacheWarning, stacklevel=2)
                cache_file.unlink(missing_ok=True)
    ensure_variant()
    import mitsuba as mi
    import sionna.rt as rt

    # Sionna's scene as loaded: a radio map has one transmitter, nothing to gain from the
    # fast tracer's endpoint builder (propagation.sionna_internals)
    rt_scene = load_sionna_scene(scene, frequency_hz, public_api=True)
    rt_scene.tx_array = rt.PlanarArray(num_rows=1, num_cols=1, pattern=reader_pattern,
                                       polarization="V" if circular else reader_polarization)
    rt_scene.rx_array = rt.PlanarArray(num_rows=1, num_cols=1, pattern="iso", polarization="V")
    ori = sionna_orientation(pose[3], pose[4], pose[5])
    rt_scene.add(rt.Transmitter("reader", position=device_point(pose[:3]),
                                orientation=device_point(ori)))
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
                        samples_per_tx=wall_spp, **common)
            wall_gain = wm.path_gain.numpy()[0].astype(np.float64)
        wall_centers = surf.triangles_center
        wall_normals = surf.face_normals
    clear_devices(rt_scene)
    if circular:  # what a linear tag takes of a circular wave (the docstring)
        plane_gain, wall_gain = 0.5 * plane_gain, 0.5 * wall_gain
    out = RssiField(
        antenna_pose=pose, frequency_hz=float(frequency_hz), plane_gain=plane_gain,
        plane_centers_m=plane_centers, wall_gain=wall_gain, wall_centers_m=wall_centers,
        wall_normals=wall_normals, cell_size_m=float(cell_size_m),
        plane_height_m=float(plane_height_m), samples_per_tx=int(samples_per_tx),
        max_depth=int(max_depth), reader_pattern=reader_pattern,
        reader_polarization=reader_polarization,
    )
    if cache_file is not None:
        _save_checked(out, cache_file)
    return out


def _checksum_file(cache_file: Path) -> Path:
    return cache_file.with_suffix(".sha256.json")


def _field_sha256(field: RssiField) -> str:
    return values_sha256({k: np.asarray(v) for k, v in asdict(field).items()})


def _save_checked(field: RssiField, cache_file: Path) -> None:
    """Save a cached field and, beside it, the checksum of its values (written last)."""
    field.save(cache_file)
    atomic_write_text(_checksum_file(cache_file),
                      json.dumps({"format": 1, "values_sha256": _field_sha256(field)}) + "\n")


def _load_checked(cache_file: Path) -> RssiField:
    """A cached field whose values match the checksum saved beside it (as the path cache
    checks its packs): a file re-saved with other values, or without its checksum, is
    refused with a ValueError naming it, and the caller recomputes it."""
    meta = json.loads(_checksum_file(cache_file).read_text(encoding="utf-8"))
    field = RssiField.load(cache_file)
    if not isinstance(meta, dict) or meta.get("values_sha256") != _field_sha256(field):
        raise ValueError(f"{cache_file}: its values do not match the checksum saved with it")
    return field
