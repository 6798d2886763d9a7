"""Export a :class:`~scenes.scene.Scene` as a Sionna-loadable Mitsuba XML scene.

Sionna RT assigns one radio material per shape, the slab thickness belongs to the
radio material, and it refuses ``<bsdf>`` ids that look like ITU names without the
``itu_`` prefix. So the export writes one shape per (material, thickness) of the
scene's traced surfaces (:func:`scenes.radio.radio_groups`: the radio surfaces, or the
solid meshes with library thicknesses when there are none), each with a custom
``radio-material`` whose id is ``uhf-<name>-t<thickness>`` (``uhf-brick-t0p120`` for
0.12 m of brick) and float properties ``relative_permittivity``, ``conductivity`` and
``thickness`` evaluated at the study frequency (see ``docs/physics.md``, "Materials at 865 MHz").
"""

from __future__ import annotations

from pathlib import Path
from xml.sax.saxutils import quoteattr

from scenes.fileio import atomic_write_bytes
from scenes.materials import get_material, material
from scenes.radio import radio_groups, thickness_token

__all__ = ["export_mitsuba", "material_bsdf_id", "material_of_bsdf_id"]


def material_bsdf_id(name: str, thickness_m: float) -> str:
    """The Mitsuba ``<bsdf>`` id of library material ``name`` at slab ``thickness_m`` [m]."""
    return f"uhf-{get_material(name).name}-{thickness_token(thickness_m)}"


def material_of_bsdf_id(bsdf_id: str) -> str:
    """The library material of a :func:`material_bsdf_id` (``"uhf-brick-t0p120"`` ->
    ``"brick"``).

    Raises
    ------
    ValueError
        Not an id :func:`material_bsdf_id` makes.
    """
    name, sep, _ = bsdf_id.removeprefix("uhf-").rpartition("-t")
    if not (bsdf_id.startswith("uhf-") and sep and name):
        raise ValueError(f"{bsdf_id!r} is not a radio material id of this export (uhf-<material>-t<thickness>)")
    return get_material(name).name


def export_mitsuba(scene, directory: str | Path, frequency_hz: float) -> Path:
    """Write ``scene.xml`` and ``meshes/<material>-t<thickness>.ply`` into ``directory``.

    Parameters
    ----------
    scene : scenes.Scene
        The scene to export: its ``radio_surfaces``, or its solid meshes when it has none.
    directory : str or Path
        Output folder, created if missing.
    frequency_hz : float
        Frequency at which material properties are evaluated (P.2040-3).

    Returns
    -------
    Path
        Path of the XML file, loadable by ``sionna.rt.load_scene(path, merge_shapes=False)``.
        Each shape's id is ``mesh-<material>-t<thickness>`` (Sionna's object name drops
        the ``mesh-`` prefix), e.g. ``mesh-brick-t0p120``.

    Notes
    -----
    ``scene.metadata["material_overrides"]`` (``{name: {"thickness_m": ...,
    "relative_permittivity": ..., "conductivity_s_per_m": ...}}``, any subset) replaces
    the library values for that scene (set from a spec's ``[material_overrides.<name>]``);
    an overridden ``thickness_m`` applies to every surface of that material.
    """
    directory = Path(directory)
    (directory / "meshes").mkdir(parents=True, exist_ok=True)
    lines = ['<scene version="2.1.0">']
    overrides = scene.metadata.get("material_overrides", {})
    groups = radio_groups(scene)
    for g in groups:
        eps_r, sigma = material(g.material, frequency_hz)
        ov = overrides.get(g.material, {})
        eps_r = ov.get("relative_permittivity", eps_r)
        sigma = ov.get("conductivity_s_per_m", sigma)
        lines += [
            f'  <bsdf type="radio-material" id={quoteattr(material_bsdf_id(g.material, g.thickness_m))}>',
            f'    <float name="relative_permittivity" value="{eps_r:.9g}"/>',
            f'    <float name="conductivity" value="{sigma:.9g}"/>',
            f'    <float name="thickness" value="{g.thickness_m:.9g}"/>',
            "  </bsdf>",
        ]
    for g in groups:
        ply = directory / "meshes" / f"{g.token}.ply"
        atomic_write_bytes(ply, g.mesh.export(file_type="ply", encoding="binary"))
        lines += [
            f'  <shape type="ply" id={quoteattr("mesh-" + g.token)}>',
            f'    <string name="filename" value={quoteattr("meshes/" + ply.name)}/>',
            '    <boolean name="face_normals" value="true"/>',
            f'    <ref id={quoteattr(material_bsdf_id(g.material, g.thickness_m))} name="bsdf"/>',
            "  </shape>",
        ]
    lines.append("</scene>")
    xml = directory / "scene.xml"
    atomic_write_bytes(xml, ("\n".join(lines) + "\n").encode())
    return xml
