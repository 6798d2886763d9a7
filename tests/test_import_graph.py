"""No import circles between the files of the runtime packages (issue 55).

The graph is read from the source with `ast`, not from `sys.modules`: every
`import x` / `from x import y` of the project's own modules counts, at module
level or inside a function, `if TYPE_CHECKING:` blocks included (a lazy or
type-only import still ties the two files together), and so does the import of every
package above the imported module that is not above the importer (importing
``pipeline.recording.config`` runs ``pipeline/recording/__init__.py`` first). Relative imports are
resolved; `from package import name` where `name` is a submodule counts as
importing that submodule, otherwise as importing the package's `__init__`.
"""

from __future__ import annotations

import ast
import functools
from pathlib import Path

import networkx as nx

ROOT = Path(__file__).resolve().parents[1]
PACKAGES = ("scenes", "propagation", "fuzzymodel", "pipeline")

# Cycles still present, each as the frozenset of its modules: none (issue 55). A cycle
# allowed for a while is listed here and must leave the set once fixed, so it only shrinks.
KNOWN: frozenset[frozenset[str]] = frozenset()


def module_files(root: Path = ROOT) -> dict[str, Path]:
    """Dotted module name -> file, for every .py file of the runtime packages."""
    out: dict[str, Path] = {}
    for pkg in PACKAGES:
        for path in sorted((root / pkg).rglob("*.py")):
            parts = list(path.relative_to(root).with_suffix("").parts)
            if parts[-1] == "__init__":
                parts.pop()
            out[".".join(parts)] = path
    return out


def _is_package(name: str, files: dict[str, Path]) -> bool:
    return files[name].name == "__init__.py"


def _targets(node: ast.Import | ast.ImportFrom, module: str, files: dict[str, Path]) -> set[str]:
    """The project modules one import statement in `module` imports."""
    found: set[str] = set()
    if isinstance(node, ast.Import):
        for alias in node.names:
            parts = alias.name.split(".")
            # the longest prefix that is one of ours (`import a.b.c` imports a.b.c)
            for k in range(len(parts), 0, -1):
                name = ".".join(parts[:k])
                if name in files:
                    found.add(name)
                    break
        return found
    if node.level:
        base = module.split(".")
        if not _is_package(module, files):
            base = base[:-1]
        if node.level > 1:
            base = base[: len(base) - (node.level - 1)]
        source = ".".join(base + ([node.module] if node.module else []))
    else:
        source = node.module or ""
    for alias in node.names:
        sub = f"{source}.{alias.name}"
        if sub in files:
            found.add(sub)
        elif source in files:
            found.add(source)
    return found


def _packages_above(module: str) -> list[str]:
    parts = module.split(".")
    return [".".join(parts[:k]) for k in range(1, len(parts))]


def _is_above(package: str, module: str) -> bool:
    return module == package or module.startswith(package + ".")


@functools.cache
def import_edges(root: Path = ROOT) -> tuple[tuple[str, str, int, bool], ...]:
    """(importer, imported, line, inside a function) for every import of a project module."""
    files = module_files(root)
    edges: list[tuple[str, str, int, bool]] = []
    for module, path in files.items():
        tree = ast.parse(path.read_text(encoding="utf-8"), filename=str(path))

        def visit(node: ast.AST, in_function: bool, module: str = module) -> None:
            for child in ast.iter_child_nodes(node):
                if isinstance(child, ast.Import | ast.ImportFrom):
                    for target in _targets(child, module, files):
                        if target != module:
                            edges.append((module, target, child.lineno, in_function))
                        # importing a.b.c runs a/__init__ and a/b/__init__ first: a hidden
                        # edge to each package above the target that is not above us
                        for parent in _packages_above(target):
                            if parent != module and parent in files and not _is_above(parent, module):
                                edges.append((module, parent, child.lineno, in_function))
                inner = in_function or isinstance(
                    child, ast.FunctionDef | ast.AsyncFunctionDef | ast.Lambda
                )
                visit(child, inner)

        visit(tree, False)
    return tuple(edges)


def import_graph(root: Path = ROOT) -> nx.DiGraph:
    graph = nx.DiGraph()
    graph.add_nodes_from(module_files(root))
    for src, dst, line, _ in import_edges(root):
        if graph.has_edge(src, dst):
            graph[src][dst]["lines"].append(line)
        else:
            graph.add_edge(src, dst, lines=[line])
    return graph


def import_cycles(graph: nx.DiGraph) -> list[frozenset[str]]:
    """The strongly connected components with more than one module."""
    return [frozenset(c) for c in nx.strongly_connected_components(graph) if len(c) > 1]


def describe(graph: nx.DiGraph, cycle: frozenset[str]) -> str:
    """One cycle's members and the imports that bind them (file:line)."""
    lines = [f"cycle of {len(cycle)}: {', '.join(sorted(cycle))}"]
    for src, dst in sorted(graph.subgraph(cycle).edges):
        where = ", ".join(str(n) for n in graph[src][dst]["lines"])
        lines.append(f"    {src} -> {dst} (line {where})")
    return "\n".join(lines)


def test_graph_sees_the_packages():
    graph = import_graph()
    assert graph.number_of_nodes() > 100
    assert graph.has_edge("propagation.tracing", "scenes.scene") or graph.number_of_edges() > 100


def test_relative_and_submodule_imports_resolve(tmp_path):
    pkg = tmp_path / "pipeline" / "sub"
    pkg.mkdir(parents=True)
    (tmp_path / "pipeline" / "__init__.py").write_text("")
    (pkg / "__init__.py").write_text("from . import a\n")
    (pkg / "a.py").write_text(
        "from typing import TYPE_CHECKING\n"
        "if TYPE_CHECKING:\n    from .b import X\n"
        "def f():\n    from pipeline.sub import thing\n"
    )
    (pkg / "b.py").write_text("from .. import sub\nimport pipeline.sub.a\n")
    edges = {(s, d, inside) for s, d, _, inside in import_edges(tmp_path)}
    assert edges == {
        ("pipeline.sub", "pipeline.sub.a", False),
        ("pipeline.sub.a", "pipeline.sub.b", False),
        ("pipeline.sub.a", "pipeline.sub", True),
        ("pipeline.sub.b", "pipeline.sub", False),
        ("pipeline.sub.b", "pipeline.sub.a", False),
    }
    cycles = import_cycles(import_graph(tmp_path))
    assert cycles == [frozenset({"pipeline.sub", "pipeline.sub.a", "pipeline.sub.b"})]


def test_no_import_cycles_but_the_known():
    graph = import_graph()
    cycles = set(import_cycles(graph))
    new = cycles - KNOWN
    gone = KNOWN - cycles
    report = "\n".join(describe(graph, c) for c in sorted(cycles, key=sorted))
    assert not new, f"new import cycle(s):\n{report}"
    assert not gone, (
        f"known cycle(s) no longer present, remove them from KNOWN: "
        f"{[sorted(c) for c in gone]}\n{report}"
    )


# The layers of `pipeline/` (docs/architecture.md): the study library and the shared
# foundation below, the application (engine, stages, outputs, apps) above. Every pipeline
# module belongs to exactly one; a new top-level module or folder must be placed here.
FOUNDATION = ("pipeline.config", "pipeline.configschema", "pipeline.sceneconfig", "pipeline.figureconfig", "pipeline.runfiles",
              "pipeline.parallel", "pipeline.runpaths", "pipeline.outdirs")
LIBRARY = ("pipeline.robot", "pipeline.acquisition", "pipeline.localisation", "pipeline.studyscene",
           "pipeline.sensormodels", "pipeline.evaluation", "pipeline.recording")
APPLICATION = ("pipeline.engine", "pipeline.stages", "pipeline.figures", "pipeline.report",
               "pipeline.apps")
FACADE = ("pipeline", "pipeline.__main__")


def _under(module: str, prefixes: tuple[str, ...]) -> bool:
    return any(module == p or module.startswith(p + ".") for p in prefixes)


def test_every_pipeline_module_has_a_layer():
    layers = FOUNDATION + LIBRARY + APPLICATION
    stray = [m for m in module_files() if m.startswith("pipeline")
             and m not in FACADE and not _under(m, layers)]
    assert not stray, f"pipeline modules in no layer (place them, then list them here): {stray}"


def test_library_imports_nothing_from_the_application():
    below = FOUNDATION + LIBRARY
    up = sorted({f"{s} -> {d} (line {line})" for s, d, line, _ in import_edges()
                 if _under(s, below) and (_under(d, APPLICATION) or d in FACADE)})
    assert not up, "library or foundation importing the application:\n" + "\n".join(up)


def test_foundation_imports_no_library_but_the_config_sections():
    # pipeline.config gathers the library packages' config sections into StudyConfig; no
    # other foundation module imports the library
    up = sorted({f"{s} -> {d}" for s, d, _, _ in import_edges()
                 if _under(s, FOUNDATION) and s != "pipeline.config" and _under(d, LIBRARY)})
    assert not up, "foundation importing the library:\n" + "\n".join(up)
