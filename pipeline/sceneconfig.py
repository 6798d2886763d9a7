"""The study's building as configured: radio properties laid over its materials (``[[materials]]``)."""

from __future__ import annotations

from pipeline.configschema import ConfigError, option, section
from scenes import resolve_material_name

__all__ = ["MaterialConfig", "material_overrides"]


@section
class MaterialConfig:
    """Replacement radio properties of one library material in the study's building
    (``[[materials]]``; what a calibration writes into ``calibrated.toml``)."""

    name: str = option("concrete", "Library material (scenes.MATERIALS, or an ITU alias).")
    relative_permittivity: float = option(
        0.0, "Real relative permittivity at the study's frequency (0: the library's P.2040 value).")
    conductivity_s_per_m: float = option(
        -1.0, "Conductivity at the study's frequency [S/m] (negative: the library's value).")

    def __post_init__(self):
        try:
            resolve_material_name(self.name)
        except KeyError as exc:
            raise ConfigError(f"materials: {exc}") from None
        if self.relative_permittivity != 0.0 and not 1.0 <= self.relative_permittivity <= 1e3:
            raise ConfigError(f"materials: {self.name}'s relative_permittivity must be in [1, 1000] "
                              f"(0: the library's), got {self.relative_permittivity!r}")
        if not self.conductivity_s_per_m <= 1e8:  # NaN fails too
            raise ConfigError(f"materials: {self.name}'s conductivity_s_per_m must be at most 1e8 S/m, "
                              f"got {self.conductivity_s_per_m!r}")


def material_overrides(materials) -> dict:
    """``Scene.metadata["material_overrides"]`` entries of ``materials`` (MaterialConfig
    tuple): {library name: {"relative_permittivity", "conductivity_s_per_m"}}, only the
    values given (:func:`scenes.export.export_mitsuba` reads them).

    Raises
    ------
    ConfigError
        A material listed twice (under any of its names)."""
    out = {}
    for m in materials:
        entry = {}
        if m.relative_permittivity != 0.0:
            entry["relative_permittivity"] = float(m.relative_permittivity)
        if m.conductivity_s_per_m >= 0.0:
            entry["conductivity_s_per_m"] = float(m.conductivity_s_per_m)
        name = resolve_material_name(m.name)
        if name in out:
            raise ConfigError(f"materials: {name} is listed twice")
        out[name] = entry
    return out
