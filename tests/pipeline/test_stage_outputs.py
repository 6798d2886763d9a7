"""Stages declare their outputs (issue 55): the study's stages name every file they may
write (pipeline/runfiles.py), and the engine fails a stage that writes another."""

from __future__ import annotations

import json

import pytest

from pipeline import stages as study_stages
from pipeline.config import StudyConfig
from pipeline.engine.study import Stage, StageError, run_study
from pipeline.runfiles import STAGE_OUTPUTS, pattern


def _writes(*rels):
    def func(ctx):
        for rel in rels:
            ctx.out(rel).write_text("{}")
    return func


def _run(tmp_path, stage):
    return run_study(StudyConfig(), tmp_path, stages=(stage,), manifest_extra=None,
                     command_line=["test"])


def test_declared_outputs_commit(tmp_path):
    st = Stage("s", _writes("out/a_01.json", "out/a_02.json", "top.json"),
               outputs=("out/a_*.json", "top.json"))
    res = _run(tmp_path, st)
    assert res.ran == ["s"]
    rec = json.loads((tmp_path / "stages" / "s.json").read_text())
    assert sorted(rec["outputs"]) == ["out/a_01.json", "out/a_02.json", "top.json"]


def test_an_undeclared_output_fails_the_stage_naming_it(tmp_path):
    st = Stage("s", _writes("out/a_01.json", "stray.json"), outputs=("out/a_*.json",))
    with pytest.raises(StageError, match=r"stray\.json"):
        _run(tmp_path, st)
    assert not (tmp_path / "stray.json").exists()  # nothing of a failed stage committed
    assert not (tmp_path / "out" / "a_01.json").exists()


def test_a_glob_matches_within_one_folder_only(tmp_path):
    st = Stage("s", _writes("models/sub/x.json"), outputs=("models/*.json",))
    with pytest.raises(StageError, match=r"models/sub/x\.json"):
        _run(tmp_path, st)


def test_every_study_stage_declares_its_outputs():
    for st in study_stages.STAGES + study_stages.RECORDED_STAGES:
        assert st.outputs, f"stage {st.name!r} declares no outputs"
        assert st.outputs == STAGE_OUTPUTS[st.name]
    names = {st.name for st in study_stages.STAGES + study_stages.RECORDED_STAGES}
    assert set(STAGE_OUTPUTS) == names


def test_pattern_of_a_family():
    assert pattern("tour/{tour}_track.npz") == "tour/*_track.npz"
    assert pattern("truth/rho_points_{i:02d}.npz") == "truth/rho_points_*.npz"
    assert pattern("metrics.json") == "metrics.json"


def _string_literals(path):
    """Non-docstring string constants of a module, f-string parts included, with lines."""
    import ast

    tree = ast.parse(path.read_text(encoding="utf-8"))
    docs = set()
    for node in ast.walk(tree):
        body = getattr(node, "body", None)
        if isinstance(body, list):
            for st in body:
                if isinstance(st, ast.Expr) and isinstance(st.value, ast.Constant):
                    docs.add(st.value)
    out = [(n.lineno, n.value) for n in ast.walk(tree)
           if isinstance(n, ast.Constant) and isinstance(n.value, str) and n not in docs]
    # a path built of pieces: run / "scene" / "tags.parquet"
    for n in ast.walk(tree):
        if (isinstance(n, ast.BinOp) and isinstance(n.op, ast.Div)
                and isinstance(n.right, ast.Constant) and isinstance(n.right.value, str)
                and isinstance(n.left, ast.BinOp) and isinstance(n.left.op, ast.Div)
                and isinstance(n.left.right, ast.Constant) and isinstance(n.left.right.value, str)):
            out.append((n.lineno, f"{n.left.right.value}/{n.right.value}"))
    return out


def test_run_directory_files_are_named_once():
    from pathlib import Path

    import pipeline.runfiles as rf

    root = Path(rf.__file__).resolve().parents[1]
    names = [v for k, v in vars(rf).items() if k.isupper() and isinstance(v, str)]
    exact = {n for n in names if "{" not in n}
    prefixes = {n.split("{")[0] for n in names if "{" in n and "/" in n.split("{")[0]}
    spelled = []
    for path in sorted([*(root / "pipeline").rglob("*.py"), *(root / "scripts").glob("*.py"),
                        *(root / "bench").glob("*.py")]):
        if path.name == "runfiles.py":
            continue
        text = path.read_text(encoding="utf-8").splitlines()
        for line, s in _string_literals(path):
            if "# runfiles:" in text[line - 1]:  # a label, or another tool's own file
                continue
            if s in exact or any(s.startswith(p) and s != p.rstrip("/") for p in prefixes):
                spelled.append(f"{path.relative_to(root)}:{line}: {s!r}")
    assert not spelled, ("run-directory files spelled outside pipeline/runfiles.py (use its "
                         "names):\n" + "\n".join(spelled))
