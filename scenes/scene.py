"""The scene: meshes grouped by material, radio surfaces, tags, and the metadata every later stage needs.

A :class:`Scene` is the contract between ``scenes`` (which builds or loads it),
``propagation`` (which ray-traces it) and ``pipeline`` (which drives a robot in it).
It holds two geometries: closed solids, one triangle mesh per material (collision,
laser, free space, where tags sit), and the radio surfaces the ray tracer sees, each
physical layer once (:mod:`scenes.radio`; ``None``: trace the solids as they are).
"""

from __future__ import annotations

import hashlib
import json
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import trimesh

from scenes.export import export_mitsuba as _export_mitsuba
from scenes.radio import RadioSurface, hash_radio_surfaces

__all__ = ["Scene", "TagSet"]


def _few(ids, n: int = 5) -> str:
    """The first ``n`` of ``ids`` for a one-line message, with how many more there are."""
    ids = [str(i) for i in np.asarray(ids).reshape(-1)]
    more = f" and {len(ids) - n:,} more" if len(ids) > n else ""
    return f"{ids[:n]}{more}"


@dataclass(frozen=True)
class TagSet:
    """Passive UHF tags placed in a scene.

    Attributes
    ----------
    ids : numpy.ndarray
        Tag identifiers, shape (n_tags,), dtype str (unique).
    positions_m : numpy.ndarray
        Tag centres, shape (n_tags, 3), float64, metres, world frame (z up).
    normals : numpy.ndarray
        Unit normals of the surface each tag is stuck on, pointing into free space,
        shape (n_tags, 3), float64.
    """

    ids: np.ndarray
    positions_m: np.ndarray
    normals: np.ndarray

    def __post_init__(self) -> None:
        ids = np.asarray(self.ids, dtype=str).reshape(-1)
        pos = np.asarray(self.positions_m, dtype=float).reshape(-1, 3)
        nrm = np.asarray(self.normals, dtype=float).reshape(-1, 3)
        if not (len(ids) == len(pos) == len(nrm)):
            raise ValueError(
                f"TagSet: ids ({len(ids)}), positions_m ({len(pos)}) and normals ({len(nrm)}) "
                "must have the same length"
            )
        uniq, counts = np.unique(ids, return_counts=True)  # O(n log n): scenes of 10^4 tags
        if np.any(counts > 1):
            raise ValueError(f"TagSet: duplicate tag ids {_few(uniq[counts > 1])}")
        bad = ~np.all(np.isfinite(pos), axis=1)
        if np.any(bad):
            raise ValueError(f"TagSet: positions_m of tags {_few(ids[bad])} contain NaN or inf")
        bad = ~np.all(np.isfinite(nrm), axis=1)
        if np.any(bad):
            raise ValueError(f"TagSet: normals of tags {_few(ids[bad])} contain NaN or inf")
        norms = np.linalg.norm(nrm, axis=1)
        if np.any(norms < 1e-9):
            raise ValueError(f"TagSet: zero normal for tags {_few(ids[norms < 1e-9])}")
        object.__setattr__(self, "ids", ids)
        object.__setattr__(self, "positions_m", pos)
        object.__setattr__(self, "normals", nrm / norms[:, None])

    def __len__(self) -> int:
        return len(self.ids)

    def subset(self, index: np.ndarray) -> TagSet:
        """Tags selected by an integer or boolean index."""
        return TagSet(self.ids[index], self.positions_m[index], self.normals[index])


@dataclass
class Scene:
    """A radio scene: one solid triangle mesh per material, radio surfaces, tags.

    Attributes
    ----------
    name : str
        Scene name (bundled name or file stem).
    meshes : dict[str, trimesh.Trimesh]
        Material name (a key of the UHF material library, see
        :func:`scenes.materials.material`) to the mesh of every surface made of it.
        World frame, metres, z up; the floor is at z = 0.
    tags : TagSet
        Tags in the scene.
    source : str
        Where the scene came from (file path or ``"generated"``), for error messages.
    metadata : dict
        Free-form JSON-able description (generator parameters, spec); enters the hash.
    route_m : numpy.ndarray or None
        Centre line of the walkable corridor as a polyline, shape (n_points, 2), float64,
        metres (x, y); guided robot tours follow it. ``None`` when unknown (imported meshes
        without a route), in which case tours need a route given explicitly.
    free_space_m : numpy.ndarray or None
        The free (walkable) volume as a union of axis-aligned boxes, shape (k, 2, 3),
        float64, metres: ``[[x_min, y_min, z_min], [x_max, y_max, z_max]]`` per box.
        Generated scenes set it; ``None`` means "the scene's bounding box" (imported
        meshes). Solids inside it (boxes, cabinets) are not free: see
        :func:`scenes.geometry.is_free`.
    radio_surfaces : tuple of RadioSurface or None
        What the ray tracer sees (:mod:`scenes.radio`): single-sided surfaces, each
        physical layer once with its thickness (a solid wall: one surface on its inner
        face), closed shells for hollow furniture. ``None``: trace ``meshes`` as they are,
        every face with its material's library thickness (a closed box counts twice).
        Generated scenes set it; imports only when asked (``radio_geometry=``).
        Geometric queries (collision, laser, tags) always use ``meshes``.
    rosmap : scenes.rosmap.RosMap or None
        The occupancy-grid map the scene was extracted from (:mod:`scenes.mapscene`):
        the robot localises in it as it is; ``None`` for every other scene. How the
        pipeline uses it is the map source's row of :data:`scenes.sources.SOURCES`.
    source_digest : str
        Digest of what the scene was made from beyond its geometry and tags (a map
        scene: its map's, :meth:`scenes.rosmap.RosMap.digest`); part of
        :meth:`content_hash`. ``""``: nothing (it then adds nothing to the hash).
    """

    name: str
    meshes: dict[str, trimesh.Trimesh]
    tags: TagSet
    source: str = "generated"
    metadata: dict = field(default_factory=dict)
    route_m: np.ndarray | None = None
    free_space_m: np.ndarray | None = None
    radio_surfaces: tuple[RadioSurface, ...] | None = None
    rosmap: object | None = None
    source_digest: str = ""

    @property
    def materials(self) -> list[str]:
        """Material names used by the scene, sorted."""
        return sorted(self.meshes)

    @property
    def bounds_m(self) -> np.ndarray:
        """Axis-aligned bounds of all meshes, shape (2, 3): [min xyz, max xyz], metres."""
        lo = np.min([m.bounds[0] for m in self.meshes.values()], axis=0)
        hi = np.max([m.bounds[1] for m in self.meshes.values()], axis=0)
        return np.stack([lo, hi])

    def combined_mesh(self) -> trimesh.Trimesh:
        """All meshes concatenated (for ray casting and containment queries)."""
        return trimesh.util.concatenate(list(self.meshes.values()))

    def content_hash(self) -> str:
        """SHA-256 of geometry, materials and tags: the cache key of everything traced here.

        Covers the solid meshes, the radio surfaces (materials, thicknesses, triangles;
        nothing is added when they are ``None``, so imported scenes keep their hash), the
        tags, ``metadata["material_overrides"]`` and :attr:`source_digest` (the map of a
        map scene).
        """
        h = hashlib.sha256()
        for name in self.materials:
            mesh = self.meshes[name]
            h.update(name.encode())
            h.update(np.ascontiguousarray(np.round(mesh.vertices, 6) + 0.0, dtype=np.float64).tobytes())
            h.update(np.ascontiguousarray(mesh.faces, dtype=np.int64).tobytes())
        h.update("\n".join(self.tags.ids.tolist()).encode())
        h.update((np.round(self.tags.positions_m, 6) + 0.0).tobytes())
        h.update((np.round(self.tags.normals, 6) + 0.0).tobytes())  # +0.0: -0.0 -> 0.0
        h.update(json.dumps(self.metadata.get("material_overrides", {}), sort_keys=True).encode())
        if self.radio_surfaces is not None:
            hash_radio_surfaces(h, self.radio_surfaces)
        h.update(self.source_digest.encode())  # b"": the hash of a scene without one is unchanged
        return h.hexdigest()

    def export_mitsuba(self, directory: str | Path, frequency_hz: float) -> Path:
        """Write a Sionna-loadable Mitsuba XML scene plus one PLY per (material, thickness).

        See :func:`scenes.export.export_mitsuba`.
        """
        return _export_mitsuba(self, directory, frequency_hz)
