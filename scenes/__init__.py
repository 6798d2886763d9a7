"""Scenes: UHF material library, corridor generator, scene specs, import and export."""

from scenes.materials import (
    MATERIALS,
    FrequencyRangeWarning,
    Material,
    UnknownMaterialError,
    get_material,
    material,
)
from scenes.scene import Scene, TagSet

__all__ = [
    "MATERIALS",
    "FrequencyRangeWarning",
    "Material",
    "Scene",
    "TagSet",
    "UnknownMaterialError",
    "get_material",
    "material",
]
