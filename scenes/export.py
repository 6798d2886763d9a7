"""Export a :class:`~scenes.scene.Scene` as a Sionna-loadable Mitsuba XML scene.

Sionna RT assigns one radio material per shape and refuses ``<bsdf>`` ids that
look like ITU names without the ``itu_`` prefix, so every material is written as a
custom ``radio-material`` with id ``uhf-<name>`` and float properties
``relative_permittivity``, ``conductivity`` and ``thickness`` evaluated at the
study frequency (see ``shared/SIONNA_NOTES.md``).
"""

from __future__ import annotations

from pathlib import Path
from xml.sax.saxutils import quoteattr

from scenes.fileio import atomic_write_bytes
from scenes.materials import get_material, material

__all__ = ["export_mitsuba", "material_bsdf_id"]


def material_bsdf_id(name: str) -> str:
    """The Mitsuba ``<bsdf>`` id used for library material ``name``."""
    return f"uhf-{get_material(name).name}"


def export_mitsuba(scene, directory: str | Path, frequency_hz: float) -> Path:
    """Write ``scene.xml`` and ``meshes/<material>.ply`` into ``directory``.

    Parameters
    ----------
    scene : scenes.Scene
        The scene to export (one mesh per material).
    directory : str or Path
        Output folder, created if missing.
    frequency_hz : float
        Frequency at which material properties are evaluated (P.2040-3).

    Returns
    -------
    Path
        Path of the XML file, loadable by ``sionna.rt.load_scene(path, merge_shapes=False)``.
        Each shape's id is ``mesh-<material>``.

    Notes
    -----
    ``scene.metadata["material_overrides"]`` (``{name: {"thickness_m": ...,
    "relative_permittivity": ..., "conductivity_s_per_m": ...}}``, any subset) replaces
    the library values for that scene (set from a spec's ``[material_overrides.<name>]``).
    """
    directory = Path(directory)
    (directory / "meshes").mkdir(parents=True, exist_ok=True)
    lines = ['<scene version="2.1.0">']
    overrides = scene.metadata.get("material_overrides", {})
    for name in scene.materials:
        eps_r, sigma = material(name, frequency_hz)
        thickness = get_material(name).thickness_m
        ov = overrides.get(get_material(name).name, {})
        eps_r = ov.get("relative_permittivity", eps_r)
        sigma = ov.get("conductivity_s_per_m", sigma)
        thickness = ov.get("thickness_m", thickness)
        lines += [
            f'  <bsdf type="radio-material" id={quoteattr(material_bsdf_id(name))}>',
            f'    <float name="relative_permittivity" value="{eps_r:.9g}"/>',
            f'    <float name="conductivity" value="{sigma:.9g}"/>',
            f'    <float name="thickness" value="{thickness:.9g}"/>',
            "  </bsdf>",
        ]
    for name in scene.materials:
        mesh = scene.meshes[name]
        ply = directory / "meshes" / f"{get_material(name).name}.ply"
        atomic_write_bytes(ply, mesh.export(file_type="ply", encoding="binary"))
        lines += [
            f'  <shape type="ply" id={quoteattr("mesh-" + get_material(name).name)}>',
            f'    <string name="filename" value={quoteattr("meshes/" + ply.name)}/>',
            '    <boolean name="face_normals" value="true"/>',
            f'    <ref id={quoteattr(material_bsdf_id(name))} name="bsdf"/>',
            "  </shape>",
        ]
    lines.append("</scene>")
    xml = directory / "scene.xml"
    atomic_write_bytes(xml, ("\n".join(lines) + "\n").encode())
    return xml
