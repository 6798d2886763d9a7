"""The registry of scene sources: every way a scene's geometry comes into the study.

A source is one row of :data:`SOURCES`, a :class:`SceneSource`: the scene-TOML table
that names it and the dataclass the table is read into, the builder of a spec with that
table, the file suffixes :func:`scenes.load` reads on their own and how, a cheap check of
such a file before a run, and how the pipeline treats a scene the source made
(:class:`SceneTraits`). The catalog (:mod:`scenes.catalog`), the scene-TOML reader
(:mod:`scenes.spec_toml`), the run target (:mod:`pipeline.apps.targets`, :mod:`pipeline.config`)
and the pipeline (the robot's map, the route, the top view) ask the registry; none of them
names a source. A new source is one module (its spec class, builder and file loader) and
one row here.

==========  ==================  ==================  =================================
name        table               files               scene
==========  ==================  ==================  =================================
corridor    ``[corridor]``      (none)              generated (:mod:`scenes.generator`)
mesh        ``[mesh]``          .ply .obj .glb ...  imported (:mod:`scenes.importers`)
mitsuba     ``[mitsuba]``       .xml                imported (:mod:`scenes.importers`)
map         ``[map]``, [tags]   .yaml .yml          a ROS map (:mod:`scenes.mapscene`)
==========  ==================  ==================  =================================

::

    from scenes.sources import SOURCES, source_of_file, traits_of

    SOURCES["map"].suffixes             # (".yaml", ".yml")
    source_of_file("site.yaml").name    # "map"
    traits_of(scene).plans_route        # True for a map scene
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

from scenes.generator import build_corridor
from scenes.importers import MESH_SUFFIXES, import_mesh, load_mitsuba_xml
from scenes.mapscene import build_map_scene, load_map
from scenes.mapspec import MapSpec, parse_map_table, parse_tags_table
from scenes.rosmap import check_map
from scenes.spec import (
    CorridorSpec,
    MeshSpec,
    MitsubaSpec,
    SceneSpec,
    overrides_metadata,
    parse_item,
)

__all__ = [
    "PLAIN",
    "SOURCES",
    "ExtraTable",
    "SceneSource",
    "SceneTraits",
    "file_suffixes",
    "register_source",
    "source_of_file",
    "source_of_spec",
    "traits_of",
    "unregister_source",
]


def _never(scene) -> bool:
    return False


def _no_grid(scene):
    return None


@dataclass(frozen=True)
class SceneTraits:
    """How the pipeline treats a scene a source built.

    The defaults (:data:`PLAIN`) are those of a generated corridor or an imported mesh.
    """

    holds: Callable[[object], bool] = _never
    """``holds(scene) -> bool``: whether ``scene`` is one of this source's. The rows are
    asked in registry order (:func:`traits_of`); a scene no row holds gets :data:`PLAIN`."""

    grid: Callable[[object], object] = _no_grid
    """``grid(scene) -> scenes.rosmap.RosMap or None``: the occupancy grid the scene was
    made from, as given. The robot's map is drawn from it (the outline of its obstacle
    cells, on its own grid: :mod:`pipeline.robot.robotmap`), its outside is closed to the
    robot (:func:`pipeline.robot.occupancy.map_boundary_segments`) and the top view shows
    it under the plan. ``None``: the robot's map is the cut of the meshes."""

    plans_route: bool = False
    """The scene is a building the robot covers: without ``route_m`` a coverage route is
    planned past its tags (:func:`pipeline.studyscene.map_route`, also for
    ``rfidstudy scenes show``), and its route is the path driven: the tour's lanes keep
    within ``DriveProfile.map_band_half_width_m`` of it. False: the route is a corridor's
    centre line (lanes up to 6 m off it), and a scene without one has none."""


#: The traits of a scene no source holds: a generated corridor, an imported mesh.
PLAIN = SceneTraits()


@dataclass(frozen=True)
class ExtraTable:
    """A top-level scene-TOML table that only one source reads (the map's ``[tags]``)."""

    name: str
    """TOML table name (``"tags"``)."""

    attr: str
    """The :class:`~scenes.spec.SceneSpec` attribute it fills (``"tag_layout"``)."""

    parse: Callable[[object, str], object]
    """``parse(table, where) -> value``; raises :class:`~scenes.spec.SpecError`."""

    what: str = ""
    """What it is for, said when the source's own table is missing
    (``"[tags] needs a [map] (tag layouts on shelves)"``)."""


@dataclass(frozen=True)
class SceneSource:
    """One source of scenes: a row of :data:`SOURCES` (see the module docstring)."""

    name: str
    """The scene-TOML table that names the source (``[map]``) and its key in :data:`SOURCES`."""

    spec_class: type
    """The dataclass the table is read into (:attr:`scenes.spec.SceneSpec.source_tables`)."""

    build: Callable[[SceneSpec], object]
    """``build(spec) -> Scene`` for a spec whose source table is this one's (relative paths
    against ``spec.base_dir``); :func:`scenes.catalog.build` adds ``metadata["spec"]`` and
    the material overrides."""

    suffixes: tuple[str, ...] = ()
    """Lower-case file suffixes :func:`scenes.load` reads with :attr:`load_file` (one row
    each); a study's ``scene`` with one is a path, resolved against the study file."""

    load_file: Callable[..., object] | None = None
    """``load_file(path, **kwargs) -> Scene``: a file with one of :attr:`suffixes` given
    alone (``scenes.load("site.yaml", height_m=4.0)``)."""

    precheck: Callable[[Path], object] | None = None
    """``precheck(path)``: a cheap read of the source's file before a run writes anything
    (:func:`scenes.catalog.check_source`); raises its one-line error. ``path``: a file
    with one of :attr:`suffixes`, or the ``path`` key of a scene TOML's table."""

    parse: Callable[[object, str], object] | None = None
    """``parse(table, where) -> spec``: reads the TOML table; ``None``:
    :func:`scenes.spec.parse_item` into :attr:`spec_class`."""

    extra_tables: tuple[ExtraTable, ...] = ()
    """Other top-level tables that need this source's table (the map's ``[tags]``)."""

    bundled_suffix: str | None = None
    """Files ``scenes/data/<name><suffix>`` are bundled scenes of their own (the map's
    ``.yaml``; a bundled scene TOML wins over one of the same name)."""

    run_profile: str | None = None
    """Study keys ``rfidstudy run FILE`` sets for a file of this source given alone: a
    profile of :mod:`pipeline.apps.profiles` (the map: ``"map_scale"``); ``None``: the default
    study."""

    traits: SceneTraits = field(default=PLAIN)
    """How the pipeline treats a scene of this source."""

    def read_table(self, table, where: str):
        """The spec of TOML ``table`` (``where`` names it in messages)."""
        if self.parse is not None:
            return self.parse(table, where)
        return parse_item(self.spec_class, table, where)

    def table(self, spec: SceneSpec):
        """This source's table of ``spec``, or None."""
        return spec.source_tables.get(self.name)

    def file_of(self, spec: SceneSpec) -> Path | None:
        """The file this source's table of ``spec`` names (its ``path`` key, relative to
        ``spec.base_dir``), or None."""
        path = getattr(self.table(spec), "path", None)
        return None if path is None else Path(spec.base_dir) / path


#: The registered sources by name, in registry order (the order of messages and of
#: :func:`traits_of`): see :func:`register_source`.
SOURCES: dict[str, SceneSource] = {}


def register_source(source: SceneSource) -> SceneSource:
    """Add a row to :data:`SOURCES`; returns it.

    Raises
    ------
    ValueError
        A name, a suffix or an extra table another row has, or a suffix that is not
        lower case with its dot.
    """
    if source.name in SOURCES:
        raise ValueError(f"scene source {source.name!r} is registered already")
    for s in source.suffixes:
        if not s.startswith(".") or s != s.lower():
            raise ValueError(f"scene source {source.name!r}: suffix {s!r} must be lower case, with its dot")
        other = source_of_file(f"x{s}")
        if other is not None:
            raise ValueError(f"scene source {source.name!r}: suffix {s!r} is {other.name!r}'s")
    taken = {t.name for row in SOURCES.values() for t in row.extra_tables} | set(SOURCES)
    for t in source.extra_tables:
        if t.name in taken or t.name == source.name:
            raise ValueError(f"scene source {source.name!r}: table [{t.name}] is taken")
    SOURCES[source.name] = source
    return source


def unregister_source(name: str) -> SceneSource:
    """Remove row ``name`` from :data:`SOURCES` (a test's fake source); returns it."""
    return SOURCES.pop(name)


def source_of_spec(spec: SceneSpec) -> SceneSource:
    """The row of the one source table of ``spec``.

    Raises
    ------
    ValueError
        ``spec`` has no source table, several, or one no row reads.
    """
    names = list(spec.source_tables)
    if len(names) != 1 or names[0] not in SOURCES:
        raise ValueError(f"{spec.source or spec.name}: a scene spec needs exactly one source table "
                         f"of {', '.join(f'[{n}]' for n in SOURCES)}, got {names or 'none'}")
    return SOURCES[names[0]]


def source_of_file(path: str | Path) -> SceneSource | None:
    """The row that reads ``path`` on its own, by its suffix (any case); None if none."""
    suffix = Path(path).suffix.lower()
    return next((row for row in SOURCES.values() if suffix in row.suffixes), None)


def file_suffixes() -> tuple[str, ...]:
    """Every suffix :func:`scenes.load` reads on its own, besides ``.toml``, in registry order."""
    return tuple(s for row in SOURCES.values() for s in row.suffixes)


def traits_of(scene) -> SceneTraits:
    """How the pipeline treats ``scene``: the traits of the first row that holds it, else
    :data:`PLAIN`."""
    return next((row.traits for row in SOURCES.values() if row.traits.holds(scene)), PLAIN)


# ----------------------------------------------------------------------------- the rows


def _radio_options(src) -> dict:
    return {"radio_geometry": src.radio_geometry, "thin_box_max_m": src.thin_box_max_m,
            "thin_box_face": src.thin_box_face}


def _build_mesh(spec: SceneSpec):
    m = spec.mesh
    return import_mesh(Path(spec.base_dir) / m.path, material=m.material, material_map=m.material_map,
                       tags=spec.tags, name=spec.name, route_m=spec.route_m, **_radio_options(m))


def _build_mitsuba(spec: SceneSpec):
    x = spec.mitsuba
    return load_mitsuba_xml(Path(spec.base_dir) / x.path, tags=spec.tags, route_m=spec.route_m,
                            name=spec.name, **_radio_options(x))


def _build_map(spec: SceneSpec):
    return build_map_scene(spec.map, name=spec.name, base_dir=spec.base_dir, tags=spec.tags,
                           tag_layout=spec.tag_layout, route_m=spec.route_m,
                           source=spec.source or spec.name,
                           material_overrides=overrides_metadata(spec).get("material_overrides"))


def _holds_map(scene) -> bool:
    return getattr(scene, "rosmap", None) is not None


def _map_grid(scene):
    return scene.rosmap


register_source(SceneSource("corridor", CorridorSpec, build_corridor))
register_source(SceneSource("mesh", MeshSpec, _build_mesh, suffixes=MESH_SUFFIXES, load_file=import_mesh))
register_source(SceneSource("mitsuba", MitsubaSpec, _build_mitsuba, suffixes=(".xml",),
                            load_file=load_mitsuba_xml))
register_source(SceneSource(
    "map", MapSpec, _build_map, suffixes=(".yaml", ".yml"), load_file=load_map, precheck=check_map,
    parse=parse_map_table,
    extra_tables=(ExtraTable("tags", "tag_layout", parse_tags_table, "tag layouts on shelves"),),
    bundled_suffix=".yaml", run_profile="map_scale",
    traits=SceneTraits(holds=_holds_map, grid=_map_grid, plans_route=True)))
