"""The registry of scene sources (scenes.sources): one row per source, nothing else names one.

Two guards of issue 55's "a new source is one module plus one row": no module outside the
registry branches on ``rosmap`` (read with ``ast``), and a source registered in a test is
found by every entry point (suffix, scene TOML table, pre-check, run target, traits)
without a change anywhere else.
"""

from __future__ import annotations

import ast
from dataclasses import dataclass
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest

import scenes
from scenes.catalog import check_source
from scenes.geometry import box_mesh
from scenes.scene import Scene, TagSet
from scenes.sources import (
    PLAIN,
    SOURCES,
    SceneSource,
    SceneTraits,
    file_suffixes,
    register_source,
    source_of_file,
    source_of_spec,
    traits_of,
    unregister_source,
)
from tests.conftest import ROOT

#: The registry's own module: the only one whose rows may ask whether a scene has a map.
REGISTRY = ROOT / "scenes" / "sources.py"


def _is_rosmap(node: ast.AST, names: set[str]) -> bool:
    """``x.rosmap``, ``getattr(x, "rosmap", ...)`` or a name in ``names`` (``rosmap`` and
    its aliases: ``rm = scene.rosmap``)."""
    if isinstance(node, ast.Attribute) and node.attr == "rosmap":
        return True
    if isinstance(node, ast.Name) and node.id in names:
        return True
    return (isinstance(node, ast.Call) and isinstance(node.func, ast.Name) and node.func.id == "getattr"
            and len(node.args) > 1 and isinstance(node.args[1], ast.Constant)
            and node.args[1].value == "rosmap")


def _aliases(tree: ast.AST) -> set[str]:
    """``rosmap`` and every name assigned a scene's map (``rm = getattr(scene, "rosmap", None)``,
    ``rm, m = scene.rosmap, ...``), anywhere in the module."""
    names = {"rosmap"}
    for node in ast.walk(tree):
        if isinstance(node, ast.Assign):
            for target in node.targets:
                pairs = [(target, node.value)]
                if isinstance(target, ast.Tuple) and isinstance(node.value, ast.Tuple):
                    pairs = list(zip(target.elts, node.value.elts, strict=False))
                names |= {t.id for t, v in pairs if isinstance(t, ast.Name) and _is_rosmap(v, {"rosmap"})}
    return names


def _decides_on_rosmap(test: ast.AST, names: set[str]) -> bool:
    """Whether condition ``test`` asks about the map itself (``scene.rosmap is None``,
    ``if rm is None``), not about its data (``rosmap.cell_class == OBSTACLE``)."""
    parents = {child: node for node in ast.walk(test) for child in ast.iter_child_nodes(node)}
    return any(_is_rosmap(n, names)
               and not (isinstance(parents.get(n), ast.Attribute) and parents[n].value is n)
               for n in ast.walk(test))


def rosmap_branches(source: str, filename: str = "<src>") -> list[int]:
    """Lines where code decides on ``rosmap``: the test of an ``if``/``while``/conditional
    expression, a comprehension's condition, a comparison (``rosmap is None``), a
    ``not``/``and``/``or`` or a ``match`` subject that asks about the map itself."""
    tree = ast.parse(source, filename=filename)
    names = _aliases(tree)
    lines = []
    for node in ast.walk(tree):
        tests: list[ast.AST] = []
        if isinstance(node, ast.If | ast.IfExp | ast.While):
            tests.append(node.test)
        elif isinstance(node, ast.comprehension):
            tests.extend(node.ifs)
        elif isinstance(node, ast.Compare | ast.BoolOp) or (
                isinstance(node, ast.UnaryOp) and isinstance(node.op, ast.Not)):
            tests.append(node)
        elif isinstance(node, ast.Match):
            tests.append(node.subject)
        lines += [t.lineno for t in tests if _decides_on_rosmap(t, names)]
    return sorted(set(lines))


def test_the_scan_sees_the_branches_it_forbids():
    snippets = ['if scene.rosmap is not None:\n    pass\n',
                'half = 0.3 if getattr(scene, "rosmap", None) is not None else 6.0\n',
                'ok = scene.route_m is None and scene.rosmap\n',
                'has = scene.rosmap is None\n',
                'xs = [s for s in scenes if s.rosmap]\n',
                'rm = getattr(scene, "rosmap", None)\nif rm is None:\n    pass\n']
    for text in snippets:
        assert rosmap_branches(text), text
    # reading the map as data is no branch
    assert rosmap_branches("rm = scene.rosmap\nd = rm.digest()\nscene = Scene(rosmap=rm)\n"
                           "free = rosmap.cell_class == FREE\nif scene.rosmap.resolution_m > 0.1:\n"
                           "    pass\n") == []


def test_no_module_outside_the_registry_branches_on_rosmap():
    found = {}
    for pkg in ("scenes", "pipeline", "propagation", "fuzzymodel"):
        for path in sorted((ROOT / pkg).rglob("*.py")):
            if path == REGISTRY:
                continue
            lines = rosmap_branches(path.read_text(encoding="utf-8"), str(path))
            if lines:
                found[str(path.relative_to(ROOT))] = lines
    assert not found, ("branches on rosmap outside scenes/sources.py (ask "
                       f"scenes.sources.traits_of(scene) instead): {found}")


def test_the_rows_and_their_order():
    assert list(SOURCES)[:4] == ["corridor", "mesh", "mitsuba", "map"]  # more may follow
    assert source_of_file("a/site.YAML").name == "map" and source_of_file("x.yml").name == "map"
    assert source_of_file("scene.xml").name == "mitsuba" and source_of_file("room.glb").name == "mesh"
    assert source_of_file("scene.toml") is None and source_of_file("notes.txt") is None
    assert len(file_suffixes()) == len(set(file_suffixes()))
    with pytest.raises(ValueError, match="registered already"):
        register_source(SOURCES["map"])
    with pytest.raises(ValueError, match="'.xml' is 'mitsuba'"):
        register_source(SceneSource("other", object, lambda spec: None, suffixes=(".xml",)))
    with pytest.raises(ValueError, match="lower case"):
        register_source(SceneSource("other", object, lambda spec: None, suffixes=(".XYZ",)))
    assert "other" not in SOURCES


def test_traits_of_a_map_scene_and_of_a_plain_one():
    grid = object()
    assert traits_of(SimpleNamespace(rosmap=grid)).grid(SimpleNamespace(rosmap=grid)) is grid
    assert traits_of(SimpleNamespace(rosmap=grid)).plans_route
    assert traits_of(SimpleNamespace(rosmap=None)) is PLAIN
    assert traits_of(scenes.load("corridor_lab")) is PLAIN
    assert PLAIN.grid(None) is None and not PLAIN.plans_route


def test_a_map_scene_hashes_its_map(tmp_path):
    from tests.scenes.maphelpers import building, write_map

    sc = scenes.load(write_map(tmp_path, building(4.0, 3.0)))
    assert sc.source_digest == sc.rosmap.digest()
    assert traits_of(sc).grid(sc) is sc.rosmap
    other = Scene(sc.name, sc.meshes, sc.tags, metadata=sc.metadata, radio_surfaces=sc.radio_surfaces)
    assert other.content_hash() != sc.content_hash()


# ----------------------------------------------------------------------------- a fake source


@dataclass(frozen=True)
class FakeSpec:
    """``[fake]``: a box ``size_m`` wide, from file ``path``."""

    path: str
    size_m: float = 2.0


def _box_scene(name: str, size_m: float, source: str) -> Scene:
    return Scene(name, {"concrete": box_mesh([0.0, 0.0, 0.0], [size_m, size_m, 3.0])},
                 TagSet(np.zeros(0, dtype=str), np.zeros((0, 3)), np.zeros((0, 3))), source=source,
                 metadata={"fake": True})


@pytest.fixture
def fake_source():
    checked = []
    row = register_source(SceneSource(
        "fake", FakeSpec, lambda spec: _box_scene(spec.name, spec.source_tables["fake"].size_m, "toml"),
        suffixes=(".fake",), load_file=lambda path, **kw: _box_scene(Path(path).stem, 1.0, str(path)),
        precheck=lambda path: checked.append(Path(path)), run_profile="map_scale",
        traits=SceneTraits(holds=lambda s: bool(getattr(s, "metadata", {}).get("fake")), plans_route=True)))
    try:
        yield row, checked
    finally:
        unregister_source("fake")
    assert "fake" not in SOURCES


def test_a_registered_source_is_found_by_suffix_table_precheck_and_target(tmp_path, fake_source):
    row, checked = fake_source
    f = tmp_path / "hall.FAKE"
    f.write_text("any")
    sc = scenes.load(f)
    assert sc.name == "hall" and sc.bounds_m[1, 0] == 1.0
    assert source_of_file(f) is row and ".fake" in file_suffixes()
    assert traits_of(sc).plans_route and traits_of(sc) is row.traits
    check_source(f)
    toml = tmp_path / "hall.toml"
    toml.write_text('name = "hall"\n[fake]\npath = "hall.FAKE"\nsize_m = 3.0\n')
    spec = scenes.load_spec(toml)
    assert source_of_spec(spec) is row and spec.source_tables["fake"] == FakeSpec("hall.FAKE", 3.0)
    built = scenes.load(toml)
    assert built.bounds_m[1, 0] == 3.0 and built.metadata["spec"]["fake"] == {"path": "hall.FAKE",
                                                                            "size_m": 3.0}
    check_source(toml)
    assert checked == [f, tmp_path / "hall.FAKE"]
    with pytest.raises(scenes.SpecError, match=r"exactly one of \[corridor\], \[mesh\], \[mitsuba\], "
                                               r"\[map\], .*\[fake\] is needed"):
        scenes.spec_from_dict({"name": "x"})
    from pipeline.apps.targets import resolve_target
    from pipeline.config import ConfigError

    cfg = resolve_target(str(f))  # a file of a source with a run profile: that profile
    assert cfg.scene == str(f.resolve()) and cfg.tracing.max_depth == 2
    with pytest.raises(ConfigError, match="no such file"):
        resolve_target(str(tmp_path / "gone.fake"))


def test_without_the_row_the_suffix_is_refused(tmp_path):
    f = tmp_path / "hall.fake"
    f.write_text("any")
    with pytest.raises(ValueError, match=r"unsupported scene file type '\.fake' \(\.toml, \.ply"):
        scenes.load(f)
