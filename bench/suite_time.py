"""The README's test command, ``make test``, from clean clones of two or more commits.

    python bench/suite_time.py [--commits 7d9aa90 HEAD] [--kernels warm|cold|both] [--keep DIR]

Each commit is cloned from this repository into a folder of its own and ``make test``
runs there as a new user would run it: its own ``.venv`` set up by ``scripts/setup.sh``
(pip's cache and configuration as this machine has them), then the suite. The commits
run one after the other, nothing else beside them, so their ratios are measured in one
run (machines of one kind differ by up to 2.5x; seconds across machines are not
comparable). The first commit is the reference of the ratios; the default is the
commit at which the suite's time was reported as 380 s (issue 55).

``--kernels cold`` gives each run the empty per-user caches of a fresh machine (a CI
runner): ``HOME`` is a new folder, so Dr.Jit's LLVM kernels (``~/.drjit``) and
matplotlib's font list are built anew, with ``PIP_CACHE_DIR`` and ``PIP_CONFIG_FILE``
pointing at this user's so that pip installs what it would have (a legacy
``~/.pip/pip.conf`` is not carried over). ``warm`` (the default) shares this user's caches
as they are: a commit's first run compiles the kernels no earlier run did, so run it twice
for warm numbers. ``both`` runs every commit warm, then every commit cold.

Prints per commit: the wall time of ``make test`` (set-up included), pytest's own time,
the count of tests passed, failed and skipped, and both times as ratios to the first
commit's. A commit whose suite fails is reported with its exit status, not left out, and
the clones and logs are then kept (their folder is printed). Every commit is looked up
before the first run.
"""

from __future__ import annotations

import argparse
import os
import re
import shutil
import subprocess
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
#: Main when issue 55 reported ``make test`` at 380 s from a clean clone (its suite then:
#: 880 tests; the issue says 860).
REFERENCE = "7d9aa90"


@dataclass(frozen=True)
class SuiteRun:
    """One ``make test`` from a clean clone."""

    commit: str
    """The commit as given, and its abbreviated hash in brackets."""
    wall_s: float
    """``make test``'s wall time, set-up and suite [s]."""
    pytest_s: float
    """The suite's own time, from pytest's summary line [s] (nan where none was printed)."""
    counts: dict
    """Tests per outcome (passed, failed, skipped, error), from the summary line."""
    returncode: int
    """``make test``'s exit status."""


def _summary(output: str) -> tuple[float, dict]:
    """pytest's last summary line: its seconds and the counts per outcome."""
    lines = [ln for ln in output.splitlines() if re.search(r"=+ .* in [\d.]+s", ln)]
    if not lines:
        return float("nan"), {}
    last = lines[-1]
    seconds = float(re.search(r" in ([\d.]+)s", last).group(1))
    counts = {k: int(n) for n, k in re.findall(r"(\d+) (passed|failed|skipped|errors?|deselected)", last)}
    return seconds, counts


def _env(home: Path | None) -> dict:
    env = dict(os.environ)
    if home is not None:  # an empty kernel cache; pip's own cache and config kept
        real = Path.home()
        env["HOME"] = str(home)
        env.setdefault("PIP_CACHE_DIR", str(real / ".cache" / "pip"))
        conf = real / ".config" / "pip" / "pip.conf"
        if conf.is_file():
            env.setdefault("PIP_CONFIG_FILE", str(conf))
    return env


def run_commit(commit: str, sha: str, work: Path, cold_kernels: bool) -> SuiteRun:
    """Clone this repository at ``sha`` (what ``commit`` named when the bench started: a
    commit made meanwhile does not change it) into a new folder of ``work`` and time
    ``make test`` there."""
    sha = sha[:7]
    tag = f"{sha}-{'cold' if cold_kernels else 'warm'}"
    clone = work / tag
    subprocess.run(["git", "clone", "-q", str(ROOT), str(clone)], check=True)
    subprocess.run(["git", "checkout", "-q", sha], cwd=clone, check=True)
    home = None
    if cold_kernels:
        home = work / f"home-{tag}"
        home.mkdir()
    t0 = time.perf_counter()
    proc = subprocess.run(["make", "test"], cwd=clone, env=_env(home), capture_output=True,
                          text=True)
    wall = time.perf_counter() - t0
    (work / f"{tag}.log").write_text(proc.stdout + proc.stderr)
    seconds, counts = _summary(proc.stdout)
    return SuiteRun(f"{commit} ({sha})", wall, seconds, counts, proc.returncode)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--commits", nargs="+", default=[REFERENCE, "HEAD"],
                    help="commits to time, the first the reference of the ratios")
    ap.add_argument("--kernels", choices=("warm", "cold", "both"), default="warm",
                    help="Dr.Jit's kernel cache: this user's (warm), an empty one per run as on "
                    "a fresh machine (cold), or each commit both ways")
    ap.add_argument("--keep", type=Path, default=None,
                    help="keep the clones and their logs in this new folder")
    a = ap.parse_args()
    shas = []
    for c in a.commits:  # a wrong name stops here, not after the first commits' runs
        found = subprocess.run(["git", "rev-parse", "--verify", "--quiet", f"{c}^{{commit}}"],
                               cwd=ROOT, capture_output=True, text=True)
        if found.returncode != 0:
            raise SystemExit(f"suite_time: no commit {c!r} in {ROOT}")
        shas.append(found.stdout.strip())
    if len(set(shas)) != len(shas):
        raise SystemExit("suite_time: a commit is named twice (each has one clone)")
    if a.keep is not None:
        a.keep.mkdir(parents=True)  # a new folder: nothing of the user's is overwritten
        work = a.keep
    else:
        work = Path(tempfile.mkdtemp(prefix="suite_time-"))
    modes = {"warm": [False], "cold": [True], "both": [False, True]}[a.kernels]
    tables = []
    try:
        tables = [(cold, [run_commit(c, sha, work, cold) for c, sha in zip(a.commits, shas, strict=True)])
                  for cold in modes]
    finally:
        failed = any(r.returncode != 0 for _, runs in tables for r in runs)
        if a.keep is None and not failed:
            shutil.rmtree(work, ignore_errors=True)
        elif failed:
            print(f"a suite failed: its clone and log (<commit>-<warm|cold>.log) are in {work}")
    for cold, runs in tables:
        cache = "an empty Dr.Jit kernel cache each" if cold else "this user's Dr.Jit kernel cache"
        print(f"make test from a clean clone, {cache}; ratios to {runs[0].commit}")
        print(f"{'commit':>22} {'make test':>10} {'pytest':>8} {'ratio':>6} {'pytest ratio':>13}  tests")
        for r in runs:
            counts = ", ".join(f"{n} {k}" for k, n in r.counts.items()) or "no summary"
            status = "" if r.returncode == 0 else f"  (exit {r.returncode})"
            print(f"{r.commit:>22} {r.wall_s:>9.1f}s {r.pytest_s:>7.1f}s {r.wall_s / runs[0].wall_s:>6.2f} "
                  f"{r.pytest_s / runs[0].pytest_s:>13.2f}  {counts}{status}")
        print()


if __name__ == "__main__":
    main()
