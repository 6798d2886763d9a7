"""docs/architecture.md stays true (issue 55): every package folder is named on it, every
file its recipes and layers name exists, and its layers are the import test's."""

from __future__ import annotations

import re
from pathlib import Path

from tests.test_import_graph import APPLICATION, FOUNDATION, LIBRARY

ROOT = Path(__file__).resolve().parents[2]
DOC = ROOT / "docs" / "architecture.md"
PACKAGES = ("scenes", "propagation", "fuzzymodel", "pipeline")


def _text() -> str:
    return DOC.read_text(encoding="utf-8")


def _section(text: str, title: str) -> str:
    m = re.search(rf"^## {re.escape(title)}\n(.*?)(?=^## |\Z)", text, re.S | re.M)
    assert m, f"docs/architecture.md has no section '## {title}'"
    return m.group(1)


def package_folders(root: Path = ROOT) -> list[str]:
    return sorted(str(p.parent.relative_to(root)) for pkg in PACKAGES
                  for p in (root / pkg).rglob("__init__.py"))


def named_paths(text: str) -> set[str]:
    """Repository paths in backticks: `a/b.py`, `a/b/` (placeholders like <name> skipped)."""
    out = set()
    for m in re.finditer(r"`([A-Za-z_][\w./-]*(?:/|\.py|\.md|\.toml))`", text):
        if "<" not in m.group(1):
            out.add(m.group(1))
    return out


def test_every_package_folder_is_named():
    text = _section(_text(), "Packages, one line each")
    missing = [f for f in package_folders() if f"`{f}/`" not in text]
    assert not missing, f"package folders docs/architecture.md does not name: {missing}"


def test_every_named_file_exists():
    text = _text()
    paths = {p for p in named_paths(text) if "/" in p}
    assert len(paths) > 20  # the page names files; a regex gone wrong would find none
    missing = sorted(p for p in paths if not (ROOT / p).exists())
    assert not missing, f"docs/architecture.md names files that do not exist: {missing}"


def test_every_recipe_names_its_files_and_they_exist():
    recipes = _section(_text(), "Recipes")
    parts = re.split(r"^### ", recipes, flags=re.M)[1:]
    assert len(parts) >= 4, "the model, scene source, placement objective and stage recipes"
    for part in parts:
        title = part.splitlines()[0]
        files = [p for p in named_paths(part) if p.endswith(".py")]
        assert files, f"recipe '{title}' names no file"
        missing = [p for p in files if not (ROOT / p).is_file()]
        assert not missing, f"recipe '{title}' names missing files: {missing}"


def test_the_layers_are_the_import_tests():
    layers = _section(_text(), "The layers")
    for module in FOUNDATION + LIBRARY + APPLICATION:
        name = module.split(".")[-1]
        assert re.search(rf"\b{re.escape(name)}\b", layers), (
            f"{module} (a layer of tests/test_import_graph.py) is not drawn in docs/architecture.md")


def test_named_paths_finds_files_and_folders():
    found = named_paths("see `pipeline/engine/` and `scenes/sources.py`, not `pipeline/<x>.py` or `a b`")
    assert found == {"pipeline/engine/", "scenes/sources.py"}


def test_every_stage_has_a_row_in_the_data_flow():
    from pipeline.runfiles import STAGE_OUTPUTS

    flow = _section(_text(), "Data flow of a study")
    rows = {line.split("|")[1].strip() for line in flow.splitlines() if line.startswith("| ")}
    missing = sorted(set(STAGE_OUTPUTS) - rows)
    assert not missing, f"stages without a row in the data-flow tables: {missing}"
