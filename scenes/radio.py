"""Radio geometry: the surfaces the ray tracer sees, beside the solid geometry.

Sionna RT applies the ITU-R P.2040 slab model (reflection and transmission of a slab
of the radio material's ``thickness``) at *every* surface a path crosses. A wall built
as a closed box therefore counts its material twice (once at each face): a 0.12 m brick
wall transmits -7.5 dB instead of -3.7 dB at 865 MHz, and its back face adds a ghost
reflection. Sionna's ``PathSolver`` documentation asks for walls "modeled as single flat
surfaces having an attached radio material that accounts for their thickness".

A :class:`~scenes.scene.Scene` therefore keeps two geometries:

- ``meshes``: closed solids (collision, the robot's laser, :func:`scenes.is_free`,
  :func:`scenes.solid_material_at`, where tags sit);
- ``radio_surfaces``: what is traced, a tuple of :class:`RadioSurface` (material,
  thickness, triangles). Each physical layer is crossed once: a solid wall is one
  surface on its inner face carrying the wall's thickness, a stud partition two leaves.
  ``None`` means "trace the solid meshes as they are", each face with the library
  thickness of its material (imported meshes; see ``docs/radio_geometry.md``).

:func:`radio_groups` is what the export writes: one shape per (material, thickness),
since Sionna holds one radio material per shape and the thickness belongs to it.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import trimesh

from scenes.geometry import merge_meshes
from scenes.materials import get_material, resolve_material_name

__all__ = [
    "CONSTRUCTIONS",
    "DEFAULT_CONSTRUCTION",
    "RADIO_GEOMETRIES",
    "THIN_BOX_FACES",
    "RadioGroup",
    "RadioSurface",
    "default_construction",
    "radio_groups",
    "rectangle_mesh",
    "thickness_token",
    "tracing_surfaces",
]

#: Wall constructions of generated walls (per material, per panel, see scenes.spec):
#: ``"solid"``: one surface on the wall's inner face with the wall thickness (brick,
#: concrete, a solid glass block); ``"stud"``: a stud partition, one leaf on each face of
#: the wall with the material's library thickness (the cavity is air); ``"double"``: the
#: same geometry for glazing (two panes of the library thickness); ``"single"``: one leaf
#: of the library thickness on the inner face (a single pane, a lone board).
CONSTRUCTIONS = ("solid", "stud", "double", "single")
#: Default construction per library material; every other material is ``"solid"``.
DEFAULT_CONSTRUCTION = {"plasterboard": "stud"}
#: How imported meshes become radio geometry (see :mod:`scenes.importers`).
RADIO_GEOMETRIES = ("as_is", "single", "thin_boxes")
#: Which face of a thin closed box carries its surface (``"inner"``: the face nearer the
#: centre of the scene's bounds; ``"lower"``/``"upper"``: the face at the smaller/larger
#: coordinate of the thin axis; ``"mid"``: the mid-plane).
THIN_BOX_FACES = ("inner", "lower", "upper", "mid")


def default_construction(material: str) -> str:
    """Default wall construction of a library material (``"stud"`` for plasterboard)."""
    return DEFAULT_CONSTRUCTION.get(resolve_material_name(material), "solid")


def check_choice(value: str, choices: tuple[str, ...], what: str) -> str:
    """Return ``value`` if it is one of ``choices``, else raise ``ValueError`` naming both."""
    if value not in choices:
        raise ValueError(f"{what} must be one of {', '.join(repr(c) for c in choices)}, got {value!r}")
    return value


@dataclass(frozen=True, eq=False)
class RadioSurface:
    """Triangles the ray tracer sees as one layer of one material.

    Attributes
    ----------
    material : str
        Library material name (ITU names are resolved).
    thickness_m : float
        Slab thickness Sionna's P.2040 model applies at each crossing, metres, > 0.
    mesh : trimesh.Trimesh
        The triangles, world frame, metres: single-sided planar triangles for walls,
        floors, ceilings and leaves (normals into the free space for inner faces,
        outwards for outer leaves), or a closed shell for hollow furniture.
    kind : str
        What it models: ``"wall"`` (a solid wall piece), ``"leaf"`` (a stud leaf or
        pane), ``"door"`` (a closed door leaf), ``"floor"``, ``"ceiling"``, ``"shell"``
        (a closed box, e.g. a cabinet) or ``"imported"``.
    """

    material: str
    thickness_m: float
    mesh: trimesh.Trimesh
    kind: str = ""

    def __post_init__(self) -> None:
        object.__setattr__(self, "material", resolve_material_name(self.material))
        t = float(self.thickness_m)
        if not (math.isfinite(t) and t > 0):
            raise ValueError(f"RadioSurface({self.material!r}): thickness_m must be positive, got {t!r}")
        object.__setattr__(self, "thickness_m", t)
        if len(self.mesh.faces) == 0:
            raise ValueError(f"RadioSurface({self.material!r}, {self.kind!r}) has no triangles")

    @property
    def area_m2(self) -> float:
        """Total triangle area, square metres."""
        return float(self.mesh.area)


@dataclass(frozen=True, eq=False)
class RadioGroup:
    """All triangles of one (material, thickness): one Sionna shape and radio material.

    Attributes
    ----------
    material : str
        Library material name.
    thickness_m : float
        Slab thickness after ``material_overrides``, metres (rounded to 1e-6 m).
    mesh : trimesh.Trimesh
        The concatenated triangles.
    token : str
        ``<material>-t<thickness>`` (``"brick-t0p120"``): shape and file name.
    """

    material: str
    thickness_m: float
    mesh: trimesh.Trimesh
    token: str


def thickness_token(thickness_m: float) -> str:
    """``t0p120`` for 0.12 m: at least three decimals, at most six, ``.`` written ``p``."""
    text = f"{float(thickness_m):.6f}".rstrip("0")
    whole, frac = text.split(".")
    return f"t{whole}p{frac.ljust(3, '0')}"


def rectangle_mesh(lo, hi, normal) -> trimesh.Trimesh:
    """An axis-aligned rectangle (2 triangles) between corners ``lo`` and ``hi``.

    Parameters
    ----------
    lo, hi : array_like, shape (3,)
        Opposite corners, metres; exactly one axis has ``lo == hi`` (the plane).
    normal : array_like, shape (3,)
        The face normal, ``+-`` the unit vector of that axis.

    Returns
    -------
    trimesh.Trimesh
        4 vertices, 2 triangles wound counter-clockwise about ``normal``.
    """
    lo, hi = np.asarray(lo, float), np.asarray(hi, float)
    flat = np.flatnonzero(np.isclose(lo, hi, rtol=0.0, atol=1e-12))
    if len(flat) != 1:
        raise ValueError(f"rectangle_mesh: one axis must be flat, got lo={lo.tolist()}, hi={hi.tolist()}")
    k = int(flat[0])
    sign = float(np.sign(np.asarray(normal, float)[k]))
    if sign == 0:
        raise ValueError(f"rectangle_mesh: normal {normal!r} is not along axis {k}")
    u, v = (k + 1) % 3, (k + 2) % 3  # e_u x e_v = e_k
    corners = np.tile(lo, (4, 1))
    corners[[1, 2], u] = hi[u]
    corners[[2, 3], v] = hi[v]
    faces = np.array([[0, 1, 2], [0, 2, 3]]) if sign > 0 else np.array([[0, 2, 1], [0, 3, 2]])
    return trimesh.Trimesh(corners, faces, process=False)


def tracing_surfaces(scene) -> tuple[RadioSurface, ...]:
    """The surfaces traced for ``scene``: its radio surfaces, or its meshes as they are.

    With ``scene.radio_surfaces is None`` every material mesh becomes one surface with the
    library thickness of its material (each face of a closed box applies it once).
    """
    if scene.radio_surfaces is not None:
        return tuple(scene.radio_surfaces)
    return tuple(RadioSurface(name, get_material(name).thickness_m, scene.meshes[name], "imported")
                 for name in scene.materials if len(scene.meshes[name].faces))


def radio_groups(scene) -> list[RadioGroup]:
    """One :class:`RadioGroup` per (material, thickness), sorted by material then thickness.

    ``scene.metadata["material_overrides"][name]["thickness_m"]``, when given, replaces
    the thickness of every surface of that material.
    """
    overrides = scene.metadata.get("material_overrides", {})
    parts: dict[tuple[str, float], list[trimesh.Trimesh]] = {}
    for s in tracing_surfaces(scene):
        t = overrides.get(s.material, {}).get("thickness_m", s.thickness_m)
        parts.setdefault((s.material, round(float(t), 6)), []).append(s.mesh)

    return [RadioGroup(m, t, merge_meshes(ms), f"{m}-{thickness_token(t)}")
            for (m, t), ms in sorted(parts.items())]


def hash_radio_surfaces(h, surfaces) -> None:
    """Feed the radio surfaces (material, thickness, geometry) into a hashlib object."""
    h.update(b"radio-surfaces-v1")
    for s in surfaces:
        h.update(f"{s.material}|{s.thickness_m:.9g}|{s.kind}".encode())
        h.update(np.ascontiguousarray(np.round(s.mesh.vertices, 6) + 0.0, dtype=np.float64).tobytes())
        h.update(np.ascontiguousarray(s.mesh.faces, dtype=np.int64).tobytes())
