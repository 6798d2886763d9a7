"""Issue 33's fault battery against the command line: one scratch directory, every case of
the issue's list, each run as ``python -m pipeline ...`` with a timeout, classified.

    python tests/reliability/battery.py [--scratch DIR] [--keep] [--only NAME,...]

Not collected by pytest (no ``test_`` prefix); the cases it names have tests in
``tests/reliability/`` (fast ones in ``make test``, slow ones marked). It makes one tiny
study (``configs/tiny.toml``, propagation cache under the scratch directory through
``$RFIDSTUDY_CACHE``) and works on copies of it, so it touches nothing outside the
scratch directory (the ``figures /`` case checks that nothing appeared in ``/``). The
disk-full case mounts a 64 KiB tmpfs and is reported ``n/a`` where mounting is not
permitted (not root).

Outcomes: ``ok`` (the case should succeed and did, every check holding), ``clear error``
(refused in one ``error:`` line naming the expected key, file or value, nothing damaged),
``unclear`` (refused, but the line names none of them, or several lines), ``data loss``
(a file outside the run, or a user's file, changed or vanished), ``hang`` (timeout),
``traceback``, ``silent accept`` (a value that must be refused ran with exit 0),
``silent wrong`` (exit 0 with a wrong result), ``n/a`` (cannot be staged here).
It prints one line per case and the counts per outcome; about 6.5 minutes on 2 shared cores.
"""

from __future__ import annotations

import argparse
import base64
import collections
import json
import os
import shutil
import signal
import subprocess
import sys
import tempfile
import time
from dataclasses import dataclass, field
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
TINY = ROOT / "configs" / "tiny.toml"
OUTCOMES = ("ok", "clear error", "unclear", "data loss", "hang", "traceback", "silent accept",
            "silent wrong", "n/a")


@dataclass
class Result:
    rc: int | None  # None: timed out
    out: str
    seconds: float


@dataclass
class Case:
    name: str
    expect: str  # "error": must be refused; "ok": must succeed
    words: tuple[str, ...] = ()  # an error must name one of these (key, file, value)
    outcome: str = ""
    detail: str = ""
    extra: dict = field(default_factory=dict)


class Battery:
    def __init__(self, scratch: Path, timeout: float):
        self.scratch = scratch
        self.timeout = timeout
        self.env = {**os.environ, "RFIDSTUDY_CACHE": str(scratch / "cache"), "COLUMNS": "100",
                    "PYTHONPATH": f"{ROOT}{os.pathsep}{os.environ.get('PYTHONPATH', '')}"}
        self.base = scratch / "base"
        self.n = 0

    # -- running -------------------------------------------------------------------------
    def cli(self, *args, timeout: float | None = None, env=None) -> Result:
        t0 = time.monotonic()
        proc = subprocess.Popen([sys.executable, "-m", "pipeline", *map(str, args)], cwd=self.scratch,
                                env=env or self.env, stdout=subprocess.PIPE, stderr=subprocess.STDOUT,
                                text=True, start_new_session=True)
        try:
            out, _ = proc.communicate(timeout=timeout or self.timeout)
            return Result(proc.returncode, out, time.monotonic() - t0)
        except subprocess.TimeoutExpired:
            os.killpg(proc.pid, signal.SIGKILL)  # the process group this call started
            out, _ = proc.communicate()
            return Result(None, out, time.monotonic() - t0)

    def run(self, out: Path, *extra, **kw) -> Result:
        return self.cli("run", TINY, "--no-progress", "--out", out, *extra, **kw)

    def copy(self, name: str) -> Path:
        dest = self.scratch / "cases" / name
        shutil.copytree(self.base, dest, symlinks=True)
        (dest / ".rfidstudy.lock").unlink(missing_ok=True)
        return dest

    def place(self, name: str) -> Path:
        d = self.scratch / "cases" / name
        d.mkdir(parents=True)
        return d

    # -- classification ------------------------------------------------------------------
    @staticmethod
    def classify(case: Case, res: Result, intact: bool = True, right: bool = True) -> None:
        lines = [ln for ln in res.out.strip().splitlines() if ln.strip()]
        err_lines = [ln for ln in lines if ln.startswith("error:")]
        last = err_lines[-1] if err_lines else (lines[-1] if lines else "")
        case.detail = last[:200]
        if res.rc is None:
            case.outcome = "hang"
        elif not intact:
            case.outcome = "data loss"
        elif "Traceback (most recent call last)" in res.out:
            case.outcome = "traceback"
        elif res.rc == 0:
            if case.expect == "error":
                case.outcome = "silent accept"
            else:
                case.outcome = "ok" if right else "silent wrong"
        elif len(err_lines) == 1 and (not case.words or any(w in err_lines[0] for w in case.words)):
            case.outcome = "clear error"
        else:
            case.outcome = "unclear"


def _edit_json(path: Path, fn) -> None:
    path.write_text(json.dumps(fn(json.loads(path.read_text()))))


def _snapshot(d: Path) -> dict:
    return {str(p.relative_to(d)): p.read_bytes() for p in sorted(d.rglob("*")) if p.is_file()
            and not p.is_symlink()}


def _kept(d: Path, before: dict) -> bool:
    """Every file of ``before`` still there with its bytes (new files, such as the font
    cache Matplotlib writes into a $HOME, are no loss)."""
    return all((d / k).is_file() and (d / k).read_bytes() == v for k, v in before.items())


# -- the cases -----------------------------------------------------------------------------
def containment_cases(b: Battery) -> list[Case]:
    out = []
    for how in ("relative", "absolute"):
        c = Case(f"record names {how} path outside (canary)", "ok")
        run = b.copy(f"canary_{how}")
        canary = run.parent / f"canary_{how}.txt"
        canary.write_text("the user's file")
        rel = f"../{canary.name}" if how == "relative" else str(canary)
        _edit_json(run / "stages" / "report.json",
                   lambda r, rel=rel: {**r, "outputs": {**r["outputs"], rel: "0" * 64}})
        res = b.run(run)
        b.classify(c, res, intact=canary.exists() and canary.read_text() == "the user's file")
        out.append(c)
    c = Case("record output is a FIFO", "ok")
    run = b.copy("fifo")
    (run / "report.html").unlink()
    os.mkfifo(run / "report.html")
    res = b.run(run, timeout=240)
    b.classify(c, res, right=(run / "report.html").is_file())
    out.append(c)
    c = Case('record "outputs": []', "ok")
    run = b.copy("outputs_list")
    _edit_json(run / "stages" / "report.json", lambda r: {**r, "outputs": []})
    res = b.run(run)
    man = json.loads((run / "manifest.json").read_text())
    b.classify(c, res, right=man.get("status") == "complete")
    out.append(c)
    for link in (".staging", "figures", "scene", "stages"):
        c = Case(f"{link}/ a link to an outside dir", "error", ("symbolic link", link))
        run = b.copy(f"link_{link.strip('.')}")
        outside = run.parent / f"outside_{link.strip('.')}"
        outside.mkdir()
        for name in ("scene.json", "baselines.png", "figures.json", "mine.txt"):
            (outside / name).write_text("the user's")
        before = _snapshot(outside)
        if (run / link).exists():
            shutil.rmtree(run / link)
        (run / link).symlink_to(outside, target_is_directory=True)
        res = b.run(run, "--force", "figures")
        b.classify(c, res, intact=_snapshot(outside) == before)  # nothing written there either
        out.append(c)
    c = Case("figures/x.png a link to a secret: report", "ok")
    run = b.copy("secret")
    secret = run.parent / "secret.png"
    secret.write_bytes(b"\x89PNG the user's secret bytes")
    (run / "figures" / "leak.png").symlink_to(secret)
    res = b.cli("report", run)
    html = (run / "report.html").read_text(errors="replace")
    b.classify(c, res, right=base64.b64encode(secret.read_bytes()).decode() not in html)
    out.append(c)
    return out


def writer_cases(b: Battery) -> list[Case]:
    c = Case("two runs into one --out at once", "ok")
    run = b.scratch / "cases" / "two_runs"
    procs = [subprocess.Popen([sys.executable, "-m", "pipeline", "run", str(TINY), "--no-progress",
                               "--out", str(run)], cwd=b.scratch, env=b.env, stdout=subprocess.PIPE,
                              stderr=subprocess.STDOUT, text=True) for _ in range(2)]
    results = []
    for p in procs:
        try:
            o, _ = p.communicate(timeout=b.timeout)
            results.append(Result(p.returncode, o, 0.0))
        except subprocess.TimeoutExpired:
            p.kill()
            results.append(Result(None, p.communicate()[0], 0.0))
    rcs = sorted(r.rc if r.rc is not None else -1 for r in results)
    again = b.run(run)
    refused = [r for r in results if r.rc == 2]
    good = rcs == [0, 2] and "in use by process" in refused[0].out and again.rc == 0 \
        and "stages run: none" in again.out
    combined = Result(None if -1 in rcs else 0, "\n".join(r.out for r in results) + again.out, 0.0)
    b.classify(c, combined, right=good)
    c.detail = (refused[0].out.strip().splitlines() or [""])[-1][:200] if refused else f"rcs {rcs}"
    return [c]


def non_run_dir_cases(b: Battery) -> list[Case]:
    out = []
    for command in ("report", "figures"):
        c = Case(f"{command} DIR of a user", "error", ("not a run directory",))
        d = b.place(f"user_{command}")
        (d / "report.html").write_text("my report")
        (d / "summary.csv").write_text("my table")
        before = _snapshot(d)
        res = b.cli(command, d)
        b.classify(c, res, intact=_kept(d, before))
        out.append(c)
    c = Case("sweep --out DIR of a user", "error", ("not a sweep directory", "sweep"))
    d = b.place("user_sweep")
    (d / "summary.csv").write_text("my table")
    (d / "report.html").write_text("my report")
    before = _snapshot(d)
    res = b.cli("sweep", ROOT / "configs" / "sweep_example.toml", "--out", d)
    b.classify(c, res, intact=_kept(d, before))
    out.append(c)
    c = Case("figures /", "error", ("not a run directory",))
    existed = {p for p in ("/figures", "/report.html", "/paper_figures") if os.path.lexists(p)}
    res = b.cli("figures", "/")
    appeared = {p for p in ("/figures", "/report.html", "/paper_figures") if os.path.lexists(p)} - existed
    b.classify(c, res, intact=not appeared)
    out.append(c)
    c = Case("report $HOME", "error", ("not a run directory",))
    home = b.place("home")
    (home / "report.html").write_text("my report")
    (home / ".bashrc").write_text("# mine")
    before = _snapshot(home)
    res = b.cli("report", home, env={**b.env, "HOME": str(home)})
    b.classify(c, res, intact=_kept(home, before))
    out.append(c)
    c = Case("--force-dir over a user's metrics/config/report", "error",
             ("a file of yours", "metrics.json", "config.toml", "report.html"))
    d = b.place("force_dir")
    for name in ("metrics.json", "config.toml", "report.html", "notes.md"):
        (d / name).write_text(f"my {name}")
    before = _snapshot(d)
    res = b.run(d, "--force-dir")
    b.classify(c, res, intact=_kept(d, before))
    out.append(c)
    return out


SIZES = [
    ("tracing.max_depth=1000", "max_depth"),
    ("tracing.max_depth=10", None),  # within its bound: must run or say the memory (tiny rays)
    ("tracing.samples_per_src=1e12", "samples_per_src"),
    ("tracing.samples_per_src=1000000000000", "samples_per_src"),
    ("tracing.samples_per_src=5000000", "samples_per_src"),
    ("tracing.memory_budget_mb=1e30", "memory_budget_mb"),
    ("tour.n_passes=1000000000", "n_passes"),
    ("downstream.robot_particles=1000000000", "robot_particles"),
    ("downstream.robot_runs=1000000000", "robot_runs"),
    ("evaluation.n_eval_tags=100000", "n_eval_tags"),
    ("training.epochs=1000000000", "epochs"),
    ("localisation.n_particles=1000000000", "n_particles"),
    ("tour.n_eval_poses=1000000000", "n_eval_poses"),
    ("evaluation.grid_n_d=1000000000", "grid_n_d"),
]


def size_cases(b: Battery) -> list[Case]:
    out = []
    for setting, key in SIZES:
        c = Case(setting, "error" if key else "ok", (key,) if key else ())
        d = b.scratch / "cases" / f"size_{len(out)}"
        res = b.run(d, "--set", setting, timeout=300)
        b.classify(c, res)
        if key and c.outcome == "clear error" and (d / "stages" / "tour.json").exists():
            c.outcome, c.detail = "unclear", "refused only after work: " + c.detail
        out.append(c)
    c = Case("robot.antennas: 10,000 entries", "error", ("antennas",))
    cfg = b.scratch / "cases" / "antennas.toml"
    ants = "".join(f'[[robot.antennas]]\nname = "a{i}"\nz_m = 0.7\n' for i in range(10_000))
    cfg.write_text(TINY.read_text() + "\n" + ants)
    res = b.cli("run", cfg, "--no-progress", "--out", b.scratch / "cases" / "antennas", timeout=300)
    b.classify(c, res)
    out.append(c)
    return out


def cache_cases(b: Battery) -> list[Case]:
    import numpy as np

    c = Case("RSSI-field cache re-saved with gains x10", "ok")
    run = b.copy("field_cache")
    with np.load(run / "fields" / "field_00.npz") as z:
        want = z["plane_gain"].copy()
    files = sorted((b.scratch / "cache").glob("rssi_field-*.npz"))
    if not files:
        c.outcome, c.detail = "n/a", "no rssi_field cache file"
        return [c]
    for f in files:
        with np.load(f) as z:
            data = dict(z)
        data["plane_gain"] = data["plane_gain"] * 10
        np.savez_compressed(f, **data)
    res = b.run(run, "--force", "truth_traces")
    with np.load(run / "fields" / "field_00.npz") as z:
        got = z["plane_gain"]
    b.classify(c, res, right=np.allclose(got, want, rtol=1e-4))
    return [c]


def traceback_cases(b: Battery) -> list[Case]:
    out = []
    for content, label in (("[]", "[]"), ("[" * 100_000 + "]" * 100_000, "deeply nested")):
        c = Case(f"metrics.json {label}: report", "error", ("metrics.json",))
        run = b.copy(f"metrics_{len(out)}")
        (run / "metrics.json").write_text(content)
        b.classify(c, b.cli("report", run))
        out.append(c)
    c = Case("scene.json [1]: figures", "error", ("scene.json",))
    run = b.copy("scene_json")
    (run / "scene" / "scene.json").write_text("[1]")
    b.classify(c, b.cli("figures", run))
    out.append(c)
    c = Case("sweep --out FILE", "error", ("not a directory", "--out"))
    f = b.scratch / "cases" / "afile"
    f.write_text("mine")
    b.classify(c, b.cli("sweep", ROOT / "configs" / "sweep_example.toml", "--out", f),
               intact=f.read_text() == "mine")
    out.append(c)
    for n in ("-3", "0"):
        c = Case(f"sweep --workers {n}", "error", ("--workers", "workers"))
        b.classify(c, b.cli("sweep", ROOT / "configs" / "sweep_example.toml", "--workers", n, "--out",
                            b.scratch / "cases" / f"sweep_w{n}"))
        out.append(c)
    c = Case("sweep point with NaN power", "error", ("point 1", "tx_power_dbm"))
    sw = b.scratch / "cases" / "nan_sweep.toml"
    sw.write_text(f'base = "{TINY}"\nmode = "zip"\n[parameters]\ntx_power_dbm = [27.0, nan]\n')
    res = b.cli("sweep", sw, "--out", b.scratch / "cases" / "nan_sweep")
    b.classify(c, res)
    if not list((b.scratch / "cases" / "nan_sweep").glob("runs/*/stages")) and c.outcome == "clear error":
        pass
    elif c.outcome == "clear error":
        c.outcome, c.detail = "unclear", "a point ran before the refusal"
    out.append(c)
    c = Case("--out through a symlink loop", "error", ("loop", "cannot be resolved"))
    loop = b.scratch / "cases" / "loop"
    loop.symlink_to(loop)
    b.classify(c, b.run(loop / "run"))
    out.append(c)
    c = Case("report on a manifest []", "error", ("manifest.json",))
    run = b.copy("manifest_list")
    (run / "manifest.json").write_text("[]")
    b.classify(c, b.cli("report", run))
    out.append(c)
    return out


ACCEPTS = [
    ("reader.gen2.q_step=0.9", "q_step"),
    ('reader.detuning_materials=["unobtainium"]', "unobtainium"),
    ("evaluation.n_field_poses=5", "n_field_poses"),
    ("reader.read_rate_hz=1e300", "read_rate_hz"),
    ("reader.tx_power_dbm=1000", "tx_power_dbm"),
    ('tracing.reader_pattern="nope"', "reader_pattern"),
]


def value_cases(b: Battery) -> list[Case]:
    out = []
    for setting, key in ACCEPTS:
        c = Case(setting, "error", (key,))
        d = b.scratch / "cases" / f"value_{len(out)}"
        res = b.run(d, "--set", setting, timeout=300)
        b.classify(c, res)
        if c.outcome == "clear error" and (d / "stages" / "tour.json").exists():
            c.outcome, c.detail = "unclear", "refused only after work: " + c.detail
        out.append(c)
    afile = b.scratch / "cases" / "cache_is_a_file"
    afile.write_text("mine")
    for value, label in ((str(afile), "a file"), ("/proc/rfidstudy-cache", "under /proc")):
        c = Case(f"cache_dir {label}", "error", ("cache_dir",))
        res = b.run(b.scratch / "cases" / f"cache_{len(out)}", "--set", f'tracing.cache_dir="{value}"')
        b.classify(c, res, intact=afile.read_text() == "mine")
        if "File exists" in res.out:
            c.outcome = "unclear"
        out.append(c)
    return out


def file_cases(b: Battery) -> list[Case]:
    import numpy as np

    out = []
    c = Case("mesh path is a directory", "error", ("is a directory",))
    d = b.place("mesh_dir")
    (d / "meshdir").mkdir()
    (d / "scene.toml").write_text('[mesh]\npath = "meshdir"\nmaterial = "concrete"\n')
    b.classify(c, b.cli("run", d / "scene.toml", "--no-progress", "--out", d / "run"))
    out.append(c)
    for command in ("report", "figures"):
        c = Case(f"bad config.toml in the run dir: {command}", "error", ("config.toml",))
        run = b.copy(f"bad_config_{command}")
        (run / "config.toml").write_text("this is [ not toml")
        b.classify(c, b.cli(command, run))
        out.append(c)
    c = Case("pickled .npz in the run dir: figures", "error", ("field_00.npz",))
    run = b.copy("pickled")
    with np.load(run / "fields" / "field_00.npz") as z:
        data = dict(z)
    data["plane_gain"] = np.array([{"runs": "code"}], dtype=object)
    np.savez(run / "fields" / "field_00.npz", **data)
    b.classify(c, b.cli("figures", run))
    out.append(c)
    for fmt, size in (("", "64k"), ("pdf", "200k")):
        c = Case(f"disk full during figures{' (' + fmt + ')' if fmt else ''}", "error",
                 ("the disk holding it is full",))
        mnt = b.place(f"full_{fmt or 'default'}")
        mounted = subprocess.run(["mount", "-t", "tmpfs", "-o", f"size={size}", "tmpfs", str(mnt)],
                                 capture_output=True).returncode == 0
        if not mounted:
            c.outcome, c.detail = "n/a", "cannot mount a small tmpfs here (needs root)"
            out.append(c)
            continue
        try:
            res = b.cli("figures", b.base, *(["--format", fmt] if fmt else []), "--out", mnt / "figs")
            b.classify(c, res)
            if c.outcome == "clear error" and str(mnt) not in c.detail:
                c.outcome = "unclear"
        finally:
            subprocess.run(["umount", str(mnt)], check=False)
        out.append(c)
    return out


def _group_alive(pgid: int) -> bool:
    try:
        os.killpg(pgid, 0)
        return True
    except ProcessLookupError:
        return False


def sweep_interrupt_case(b: Battery) -> list[Case]:
    # Ctrl-C in a terminal signals the whole foreground process group: the sweep and its
    # worker processes; the sweep runs in a session of its own so that only it is signalled
    c = Case("Ctrl-C of a sweep", "error", ("resume", "interrupted"))
    d = b.scratch / "cases" / "sweep_int"
    proc = subprocess.Popen([sys.executable, "-m", "pipeline", "sweep", str(ROOT / "configs" /
                             "sweep_example.toml"), "--out", str(d), "--workers", "1"], cwd=b.scratch,
                            env=b.env, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True,
                            start_new_session=True)
    time.sleep(20)
    os.killpg(proc.pid, signal.SIGINT)
    try:
        o, _ = proc.communicate(timeout=120)
        res = Result(proc.returncode, o, 0.0)
    except subprocess.TimeoutExpired:
        os.killpg(proc.pid, signal.SIGKILL)
        res = Result(None, proc.communicate()[0], 0.0)
    time.sleep(2)
    orphans = _group_alive(proc.pid)
    if orphans:
        os.killpg(proc.pid, signal.SIGKILL)  # the group this case started
    b.classify(c, res)
    lines = [ln for ln in res.out.strip().splitlines() if ln.strip()]
    if res.rc == 130 and c.outcome == "unclear" and lines and any(w in lines[-1] for w in c.words):
        c.outcome, c.detail = "clear error", lines[-1][:200]  # its message is no "error:" line
    if orphans:
        c.outcome, c.detail = "hang", "worker processes still running after the sweep exited"
    return [c]


GROUPS = {"containment": containment_cases, "writers": writer_cases, "non_run_dirs": non_run_dir_cases,
          "sizes": size_cases, "caches": cache_cases, "tracebacks": traceback_cases,
          "values": value_cases, "files": file_cases, "sweep_interrupt": sweep_interrupt_case}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--scratch", type=Path, help="scratch directory (default: a new temporary one)")
    ap.add_argument("--keep", action="store_true", help="keep the scratch directory")
    ap.add_argument("--only", help=f"comma-separated groups: {', '.join(GROUPS)}")
    ap.add_argument("--timeout", type=float, default=180.0, help="seconds per command (hang beyond)")
    args = ap.parse_args(argv)
    scratch = (args.scratch or Path(tempfile.mkdtemp(prefix="rfidstudy-battery-"))).resolve()
    scratch.mkdir(parents=True, exist_ok=True)
    (scratch / "cases").mkdir(exist_ok=True)
    b = Battery(scratch, args.timeout)
    t0 = time.monotonic()
    try:
        res = b.run(b.base, timeout=900)
        if res.rc != 0:
            print(f"the base study failed:\n{res.out}")
            return 1
        print(f"base study in {res.seconds:.0f} s; scratch {scratch}")
        groups = args.only.split(",") if args.only else list(GROUPS)
        cases: list[Case] = []
        for g in groups:
            for c in GROUPS[g](b):
                cases.append(c)
                print(f"{c.outcome:13s} {c.name[:50]:50s} {c.detail[:110]}", flush=True)
        counts = collections.Counter(c.outcome for c in cases)
        print(f"\n{len(cases)} cases in {time.monotonic() - t0:.0f} s")
        for o in OUTCOMES:
            print(f"  {o:13s} {counts.get(o, 0)}")
        bad = [c for c in cases if c.outcome not in ("ok", "clear error", "n/a")]
        for c in bad:
            print(f"  ! {c.outcome}: {c.name}: {c.detail}")
        return 1 if bad else 0
    finally:
        if not args.keep:
            shutil.rmtree(scratch, ignore_errors=True)


if __name__ == "__main__":
    sys.exit(main())
