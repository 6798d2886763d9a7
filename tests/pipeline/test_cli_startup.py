"""`rfidstudy --help` stays light (issue 55): importing the command line loads none of the
study's stages, figures (matplotlib), tracer (Sionna, Mitsuba, Dr.Jit) or cluster (Dask);
the imports that would are inside the commands, each marked `# lazy: start-up time`."""

from __future__ import annotations

import ast
import json
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
HEAVY = ("matplotlib", "sionna", "mitsuba", "drjit", "dask", "distributed", "pipeline.stages",
         "pipeline.figures", "pipeline.report", "pipeline.apps.placement", "pipeline.apps.studyrun")


def test_importing_the_command_line_loads_nothing_heavy():
    code = ("import json, sys; import pipeline.apps.cli; "
            "print(json.dumps(sorted(sys.modules)))")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                         cwd=ROOT, check=True).stdout
    loaded = set(json.loads(out.splitlines()[-1]))
    heavy = sorted(m for m in loaded if any(m == h or m.startswith(h + ".") for h in HEAVY))
    assert not heavy, f"importing pipeline.apps.cli loads {heavy}"


def test_every_lazy_project_import_says_why():
    from tests.test_import_graph import import_edges

    lines = {}
    for src, _, line, in_function in import_edges():
        if in_function and src.startswith("pipeline"):
            lines.setdefault(src, set()).add(line)
    unmarked = []
    for module, nums in lines.items():
        parts = module.split(".")
        path = ROOT.joinpath(*parts)
        path = path / "__init__.py" if path.is_dir() else path.with_suffix(".py")
        source = path.read_text(encoding="utf-8")
        text = source.splitlines()
        ends = {node.lineno: node.end_lineno for node in ast.walk(ast.parse(source))
                if isinstance(node, ast.Import | ast.ImportFrom)}
        for n in sorted(nums):
            stmt = "\n".join(text[n - 1: ends[n]])  # the marker anywhere in the statement
            if "# lazy:" not in stmt:
                unmarked.append(f"{module}:{n}: {text[n - 1].strip()}")
    assert not unmarked, "imports of the project inside functions without a reason:\n" + "\n".join(unmarked)
