"""A run directory from someone else cannot touch anything outside it (issue 33's battery).

Every case plants something in a finished run directory of small fake stages (the engine
is what is under test; tests/pipeline/test_study_runner.py has the same stages' basics)
and checks that a canary file outside the run is intact, that the tool says what it
refused, and that the directory stays usable.
"""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest
from typer.testing import CliRunner

from pipeline.config import StudyConfig
from pipeline.engine.runstore import RunDirError, RunDirLocked, RunStore, UnsafePathError, inside
from pipeline.engine.study import Stage, run_study

ROOT = Path(__file__).resolve().parents[2]


def _a(ctx):
    ctx.out("a/value.json").write_text(json.dumps({"seed": ctx.config.seed}))


def _b(ctx):
    v = json.loads(ctx.input("a/value.json").read_text())["seed"]
    ctx.out("figures/b.txt").write_text(str(v))


STAGES = (Stage("a", _a, ("seed",)), Stage("b", _b, ("training.epochs",), ("a",)))


def _run(d, **kw):
    return run_study(StudyConfig(), d, stages=STAGES, manifest_extra=None,
                     command_line=["test"], **kw)


@pytest.fixture
def run_and_canary(tmp_path):
    run = tmp_path / "run"
    _run(run)
    canary = tmp_path / "canary.txt"
    canary.write_text("the user's file")
    return run, canary


def _edit_record(run: Path, stage: str, **changes) -> None:
    p = run / "stages" / f"{stage}.json"
    rec = json.loads(p.read_text())
    rec.update(changes)
    p.write_text(json.dumps(rec))


@pytest.mark.parametrize("how", ["relative", "absolute"])
def test_a_record_naming_a_path_outside_deletes_nothing(run_and_canary, how, caplog):
    run, canary = run_and_canary
    rel = "../canary.txt" if how == "relative" else str(canary)
    rec = json.loads((run / "stages" / "b.json").read_text())
    _edit_record(run, "b", outputs={**rec["outputs"], rel: "0" * 64})
    res = _run(run)
    assert canary.read_text() == "the user's file"
    assert "b" in res.ran and "a" in res.cached  # the tampered record is corrupt: b re-ran
    assert "leads outside the run directory" in caplog.text and rel in caplog.text
    assert rel not in json.loads((run / "stages" / "b.json").read_text())["outputs"]


def test_a_fifo_named_by_a_record_is_not_waited_on(run_and_canary):
    run, _ = run_and_canary
    (run / "figures" / "b.txt").unlink()
    os.mkfifo(run / "figures" / "b.txt")
    res = _run(run)  # would hang reading a FIFO
    assert "b" in res.ran and (run / "figures" / "b.txt").read_text() == str(StudyConfig().seed)


@pytest.mark.parametrize("outputs", [[], "x", {"a/value.json": 5}, None])
def test_a_record_of_the_wrong_shape_is_corrupt_not_a_traceback(run_and_canary, outputs, caplog):
    run, _ = run_and_canary
    _edit_record(run, "a", outputs=outputs)
    res = _run(run)
    assert res.ran == ["a"] and "is corrupt" in caplog.text
    assert json.loads((run / "manifest.json").read_text())["status"] == "complete"


@pytest.mark.parametrize("link", [".staging", "figures", "stages", "a"])
def test_a_symbolic_link_inside_the_run_is_refused_and_the_outside_is_intact(tmp_path, link):
    run = tmp_path / "run"
    _run(run)
    outside = tmp_path / "outside"
    outside.mkdir()
    (outside / "b.txt").write_text("mine")
    (outside / "value.json").write_text("mine")
    (outside / "b.json").write_text("mine")
    target = run / link
    if target.exists():
        import shutil

        shutil.rmtree(target)
    target.symlink_to(outside, target_is_directory=True)
    with pytest.raises(RunDirError, match="symbolic link"):
        _run(run, force=["a"])
    if link != "stages":  # (with stages/ a link, the manifest's stage list is unreadable too)
        man = json.loads((run / "manifest.json").read_text())
        assert man["status"] == "failed" and "symbolic link" in man["failure"]["error"]
    assert sorted(p.name for p in outside.iterdir()) == ["b.json", "b.txt", "value.json"]
    assert all(p.read_text() == "mine" for p in outside.iterdir())
    target.unlink()  # the user removes the link: the directory resumes
    _run(run)
    assert (run / "figures" / "b.txt").read_text() == str(StudyConfig().seed)


def test_inside_refuses_escapes_and_links(tmp_path):
    (tmp_path / "d").mkdir()
    (tmp_path / "l").symlink_to(tmp_path / "d")
    assert inside(tmp_path, "d/x.json") == tmp_path / "d" / "x.json"
    for bad in ("../x", "/etc/passwd", "d/../../x", "", "d//x", "./x", "l/x", "l"):
        with pytest.raises(UnsafePathError):
            inside(tmp_path, bad)


def test_report_does_not_embed_a_linked_figure(run_and_canary, tmp_path):
    from pipeline.report.html import write_report

    run, canary = run_and_canary
    secret = tmp_path / "secret.png"
    secret.write_bytes(b"\x89PNG secret bytes")
    (run / "figures" / "leak.png").symlink_to(secret)
    html = write_report(run).read_text()
    import base64

    assert base64.b64encode(secret.read_bytes()).decode() not in html
    assert "leak" not in html


@pytest.mark.parametrize("content", ["[]", "[1]", "[" * 100_000 + "]" * 100_000])
def test_report_on_a_metrics_file_that_is_no_object_is_one_line(run_and_canary, content):
    from pipeline.apps.cli import app

    run, _ = run_and_canary
    (run / "metrics.json").write_text(content)
    res = CliRunner().invoke(app, ["report", str(run)])
    assert res.exit_code == 1 and "Traceback" not in res.output
    assert "metrics.json" in res.output


@pytest.mark.parametrize("command", ["report", "figures"])
def test_figures_and_report_refuse_a_directory_that_is_not_a_run(tmp_path, command):
    from pipeline.apps.cli import app

    d = tmp_path / "home"
    d.mkdir()
    (d / "report.html").write_text("my report")
    res = CliRunner().invoke(app, [command, str(d)])
    assert res.exit_code == 2 and "not a run directory" in res.output
    assert (d / "report.html").read_text() == "my report"
    assert sorted(p.name for p in d.iterdir()) == ["report.html"]


def test_force_dir_never_replaces_a_users_file(tmp_path):
    d = tmp_path / "mine"
    d.mkdir()
    (d / "notes.md").write_text("mine")
    (d / "config.toml").write_text("my config")
    with pytest.raises(RunDirError, match=r"config\.toml: a file of yours"):
        _run(d, force_dir=True)
    assert (d / "config.toml").read_text() == "my config" and not (d / "stages").exists()
    (d / "config.toml").unlink()
    (d / "figures").mkdir()
    (d / "figures" / "b.txt").write_text("my figure")
    for _ in range(2):  # the same command again: the directory now looks like a run's
        with pytest.raises(RunDirError, match=r"figures/b\.txt: a file of yours"):
            _run(d, force_dir=True)
        assert (d / "figures" / "b.txt").read_text() == "my figure"
    (d / "figures" / "b.txt").unlink()
    _run(d, force_dir=True)  # the tool's own outputs only; the user's notes stay
    assert (d / "notes.md").read_text() == "mine" and (d / "figures" / "b.txt").read_text() == str(StudyConfig().seed)


_HOLD = """
import sys, time
from pipeline.engine.runstore import RunStore
with RunStore(sys.argv[1]).lock("rfidstudy run --out elsewhere"):
    print("held", flush=True)
    time.sleep(120)
"""


def test_a_second_writer_is_refused_naming_the_holder_and_a_dead_ones_lock_is_taken(tmp_path):
    run = tmp_path / "run"
    _run(run)
    holder = subprocess.Popen([sys.executable, "-c", _HOLD, str(run)], stdout=subprocess.PIPE,
                              text=True, cwd=ROOT)
    try:
        assert holder.stdout.readline().strip() == "held"
        with pytest.raises(RunDirLocked, match=rf"in use by process {holder.pid} \(rfidstudy run"):
            _run(run, force=["b"])
        from pipeline.apps.cli import app

        res = CliRunner().invoke(app, ["figures", str(run)])
        assert res.exit_code == 2 and f"process {holder.pid}" in res.output
    finally:
        holder.send_signal(signal.SIGKILL)  # dies holding the lock: the kernel releases it
        holder.wait(timeout=30)
    t0 = time.monotonic()
    res = _run(run, force=["b"])  # stale lock taken over; nothing was wedged
    assert res.ran == ["b"] and time.monotonic() - t0 < 30
    assert json.loads((run / "manifest.json").read_text())["status"] == "complete"


def test_the_lock_file_must_not_be_a_link(tmp_path):
    run = tmp_path / "run"
    _run(run)
    victim = tmp_path / "victim.txt"
    victim.write_text("keep me")
    (run / ".rfidstudy.lock").unlink()
    (run / ".rfidstudy.lock").symlink_to(victim)
    with pytest.raises(UnsafePathError):
        _run(run)
    assert victim.read_text() == "keep me"


def test_a_symlink_loop_as_out_is_one_line(tmp_path):
    from pipeline.apps.cli import app

    loop = tmp_path / "loop"
    loop.symlink_to(loop)
    with pytest.raises(RunDirError, match="cannot be resolved"):
        _run(loop / "run")
    res = CliRunner().invoke(app, ["report", str(loop)])
    assert res.exit_code == 2 and "Traceback" not in res.output and len(res.output.splitlines()) == 1
    # placement --out through the loop: one line too (it was a RuntimeError traceback)
    for out in (loop, loop / "x"):
        res = CliRunner().invoke(app, ["placement", "configs/placement_example.toml", "--out", str(out)])
        assert res.exit_code == 2, res.output
        err = [line for line in res.output.splitlines() if line.startswith("error:")]
        assert len(err) == 1 and "Symlink loop" in err[0] and "Traceback" not in res.output


@pytest.mark.parametrize("manifest", ["[" * 100_000 + "]" * 100_000,
                                      '{"status": "failed", "failure": "a string"}', "[]"])
def test_a_malformed_manifest_is_no_traceback_for_the_next_run(run_and_canary, manifest):
    run, _ = run_and_canary
    (run / "manifest.json").write_text(manifest)
    res = _run(run)
    assert res.ran == [] and json.loads((run / "manifest.json").read_text())["status"] == "complete"
    assert isinstance(RunStore(run).records(), dict)


def test_folder_listings_skip_links_and_fifos_and_refuse_a_linked_folder(tmp_path, caplog):
    from pipeline.engine.runstore import run_files

    (tmp_path / "fields").mkdir()
    (tmp_path / "fields" / "field_00.npz").write_bytes(b"ours")
    secret = tmp_path.parent / f"{tmp_path.name}-secret.npz"
    secret.write_bytes(b"secret")
    (tmp_path / "fields" / "field_01.npz").symlink_to(secret)
    os.mkfifo(tmp_path / "fields" / "field_02.npz")
    assert run_files(tmp_path, "fields", "field_*.npz") == [tmp_path / "fields" / "field_00.npz"]
    assert "field_01.npz is not a regular file" in caplog.text
    (tmp_path / "truth").symlink_to(tmp_path / "fields")
    with pytest.raises(UnsafePathError, match="truth is a symbolic link"):
        run_files(tmp_path, "truth", "*.npz")


@pytest.mark.parametrize("kind", ["fifo", "link"])
def test_run_log_is_never_written_through_a_fifo_or_a_link(tmp_path, kind):
    # a FIFO named run.log used to block the run forever, holding the directory's lock
    import os

    from pipeline.engine.runlog import log_to_file
    from pipeline.engine.runstore import UnsafePathError

    outside = tmp_path / "outside.txt"
    outside.write_text("keep\n")
    path = tmp_path / "run.log"
    if kind == "fifo":
        os.mkfifo(path)
    else:
        path.symlink_to(outside)
    for mode in ("w", "a"):
        with pytest.raises(UnsafePathError, match="run.log"):
            with log_to_file(path, mode=mode):
                pass
    assert outside.read_text() == "keep\n"


@pytest.mark.parametrize("plant", ["web app manifest", "empty stages"])
def test_a_folder_is_a_run_directory_only_by_a_manifest_the_tool_wrote(tmp_path, plant):
    """A web app's own ``manifest.json``, or an empty ``stages/`` folder, does not make a
    folder a run directory: ``report``, ``figures`` and ``run --out`` refuse it and the
    user's ``report.html`` is unchanged (they overwrote it, exit 0)."""
    from pipeline.engine.runstore import is_run_dir

    user = tmp_path / "site"
    user.mkdir()
    if plant == "web app manifest":
        (user / "manifest.json").write_text(json.dumps({"name": "My App", "icons": []}))
    else:
        (user / "stages").mkdir()
    (user / "report.html").write_text("<p>my page</p>")
    before = sorted(p.name for p in user.rglob("*"))
    assert not is_run_dir(user)
    runner = CliRunner()
    for args in (["report", str(user)], ["figures", str(user)],
                 ["run", str(ROOT / "configs" / "tiny.toml"), "--out", str(user), "--no-progress"]):
        res = runner.invoke(app_cli(), args)
        assert res.exit_code == 2, (args, res.output)
        assert "not a run directory" in res.output and "Traceback" not in res.output
    assert (user / "report.html").read_text() == "<p>my page</p>"
    assert sorted(p.name for p in user.rglob("*")) == before


def test_a_run_directory_is_known_by_its_manifest_or_its_records(run_and_canary):
    from pipeline.engine.runstore import is_run_dir

    run, _ = run_and_canary
    man = json.loads((run / "manifest.json").read_text())
    assert man["tool"] == "rfidstudy" and man["kind"] == "run" and is_run_dir(run)
    (run / "manifest.json").write_text("[]")  # damaged: its stage records still say whose it is
    assert is_run_dir(run)


def app_cli():
    from pipeline.apps.cli import app

    return app
