"""Scenes: UHF material library, corridor generator, scene specs, import and export.

Public entry points::

    scenes.load("corridor_lab")          # bundled name, scene TOML, Mitsuba XML, mesh file
    scenes.load("site.yaml")             # a ROS map_server map (scenes.rosmap, scenes.mapscene)
    scenes.list_bundled()
    scenes.corridor(length_m=25, width_m=2.4, height_m=3.0, doors=[...], tags=[...])
    scenes.load_spec(path) / scenes.build(spec) / scenes.save_spec(spec, path)
    scenes.import_mesh(path, material=... | material_map={...}, tags=[...])
    scenes.load_mitsuba_xml(path, tags=[...])
    scenes.is_free(scene, points) / scenes.floor_plan_segments(scene, z_m) / scenes.raycast(...)
    scenes.material("concrete", 865e6) -> (relative_permittivity, conductivity_s_per_m)
    scene.radio_surfaces / scenes.radio_groups(scene)   # what the ray tracer sees
    scenes.SOURCES / scenes.register_source(...)         # where scenes come from (scenes.sources)
"""

from scenes.catalog import SceneSummary, build, bundled_path, list_bundled, load, summarize
from scenes.export import export_mitsuba
from scenes.generator import build_corridor, corridor, corridor_route
from scenes.geometry import (
    SurfaceQuery,
    closest_surface,
    floor_plan_segments,
    in_free_space,
    inside_solid,
    is_free,
    raycast,
    solid_material_at,
)
from scenes.importers import import_mesh, load_mitsuba_xml, read_sidecar
from scenes.mapextract import ExtractionRules, MapObstacle, extract_obstacles
from scenes.mapscene import build_map_scene, load_map
from scenes.mapspec import MapOverride, MapSpec, TagLayoutSpec
from scenes.materials import (
    ITU_NAME_MAP,
    MATERIALS,
    FrequencyRangeWarning,
    Material,
    UnknownMaterialError,
    get_material,
    material,
    resolve_material_name,
)
from scenes.radio import CONSTRUCTIONS, RadioGroup, RadioSurface, radio_groups, tracing_surfaces
from scenes.rosmap import RosMap, RosMapError, read_map
from scenes.scene import Scene, TagSet
from scenes.sources import SOURCES, SceneSource, SceneTraits, register_source
from scenes.spec import (
    BoxSpec,
    CabinetSpec,
    CorridorSpec,
    DoorSpec,
    MaterialOverride,
    MeshSpec,
    MitsubaSpec,
    PanelSpec,
    SceneSpec,
    SegmentSpec,
    SpecError,
    TagSpec,
)
from scenes.spec_toml import load_spec, save_spec, spec_from_dict, spec_to_dict
from scenes.tags import make_tags, validate_tags

__all__ = [
    "ExtractionRules",
    "MapObstacle",
    "MapOverride",
    "MapSpec",
    "RosMap",
    "RosMapError",
    "TagLayoutSpec",
    "build_map_scene",
    "extract_obstacles",
    "load_map",
    "read_map",
    "SOURCES",
    "SceneSource",
    "SceneTraits",
    "register_source",
    "CONSTRUCTIONS",
    "ITU_NAME_MAP",
    "MATERIALS",
    "BoxSpec",
    "CabinetSpec",
    "CorridorSpec",
    "DoorSpec",
    "FrequencyRangeWarning",
    "Material",
    "MaterialOverride",
    "MeshSpec",
    "MitsubaSpec",
    "PanelSpec",
    "RadioGroup",
    "RadioSurface",
    "Scene",
    "SceneSpec",
    "SceneSummary",
    "SegmentSpec",
    "SpecError",
    "SurfaceQuery",
    "TagSet",
    "TagSpec",
    "UnknownMaterialError",
    "build",
    "build_corridor",
    "bundled_path",
    "closest_surface",
    "corridor",
    "corridor_route",
    "export_mitsuba",
    "floor_plan_segments",
    "get_material",
    "import_mesh",
    "in_free_space",
    "inside_solid",
    "is_free",
    "list_bundled",
    "load",
    "load_mitsuba_xml",
    "load_spec",
    "make_tags",
    "material",
    "radio_groups",
    "raycast",
    "read_sidecar",
    "resolve_material_name",
    "save_spec",
    "solid_material_at",
    "spec_from_dict",
    "spec_to_dict",
    "summarize",
    "tracing_surfaces",
    "validate_tags",
]
