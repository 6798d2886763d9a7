"""Run a bench script and write its output into docs/benchmarks.md.

    python bench/record.py gen2                    # runs bench/gen2.py, records its output
    python bench/record.py study_trace -- --skip-direct

The script's own output (what it printed, unedited) replaces the section between
``<!-- bench:NAME:begin -->`` and ``<!-- bench:NAME:end -->`` in ``docs/benchmarks.md``
(appended if absent), headed by the date, the commit and the machine it ran on: the
document holds each bench's latest run, never numbers copied by hand. Earlier results
stay in git history and CHANGELOG.md. A script that fails records nothing.
"""

from __future__ import annotations

import argparse
import contextlib
import datetime as _dt
import io
import os
import platform
import re
import runpy
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
DOC = ROOT / "docs" / "benchmarks.md"

HEADER = """# Benchmarks

Each section is the latest output of one script in `bench/`, written by
`python bench/record.py NAME` from the script's own output (`make bench` records the quick
ones). Machines of the same kind differ by up to 2.5x: read the ratios each script
measures within one run, not seconds across sections. Earlier results: git history and
[CHANGELOG.md](../CHANGELOG.md).
"""


class _Tee(io.TextIOBase):
    def __init__(self, *streams):
        self.streams = streams

    def write(self, s):
        for st in self.streams:
            st.write(s)
        return len(s)

    def flush(self):
        for st in self.streams:
            st.flush()


def _machine() -> str:
    cpu = platform.processor() or platform.machine()
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                cpu = line.split(":", 1)[1].strip()
                break
    except OSError:
        pass
    return f"{os.cpu_count()} CPUs ({cpu}), Python {platform.python_version()}"


def _commit() -> str:
    try:
        out = subprocess.run(["git", "rev-parse", "--short", "HEAD"], cwd=ROOT,
                             capture_output=True, text=True, timeout=10)
        dirty = subprocess.run(["git", "status", "--porcelain", "--untracked-files=no"],
                               cwd=ROOT, capture_output=True, text=True, timeout=10).stdout
        return out.stdout.strip() + (" (with uncommitted changes)" if dirty.strip() else "")
    except (OSError, subprocess.SubprocessError):
        return "unknown"


def section(name: str, args: list[str], output: str, seconds: float) -> str:
    """The markdown section of one bench run."""
    cmd = " ".join(["python", f"bench/{name}.py", *args])
    when = _dt.datetime.now(_dt.timezone.utc).strftime("%Y-%m-%d %H:%M UTC")
    return (f"<!-- bench:{name}:begin -->\n## {name}\n\n`{cmd}`: {when}, commit {_commit()}, "
            f"{_machine()}, {seconds:.0f} s.\n\n```\n{output.rstrip()}\n```\n"
            f"<!-- bench:{name}:end -->")


def write_section(doc: Path, name: str, text: str) -> None:
    """Replace (or append) bench `name`'s section of `doc`."""
    old = doc.read_text() if doc.exists() else HEADER
    pat = re.compile(rf"<!-- bench:{re.escape(name)}:begin -->.*?<!-- bench:{re.escape(name)}:end -->",
                     re.S)
    new = pat.sub(lambda _: text, old, count=1) if pat.search(old) else (
        old.rstrip() + "\n\n" + text + "\n")
    doc.write_text(new)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("name", help="bench script name (bench/NAME.py)")
    ap.add_argument("args", nargs=argparse.REMAINDER, help="arguments for the script (after --)")
    ap.add_argument("--doc", type=Path, default=DOC)
    a = ap.parse_args(argv)
    script = ROOT / "bench" / f"{a.name}.py"
    if not script.is_file():
        print(f"no bench script {script}", file=sys.stderr)
        return 2
    args = [x for x in a.args if x != "--"]
    buf = io.StringIO()
    import time

    t0 = time.perf_counter()
    old_argv = sys.argv
    sys.argv = [str(script), *args]
    try:
        with contextlib.redirect_stdout(_Tee(sys.stdout, buf)):
            runpy.run_path(str(script), run_name="__main__")
    except SystemExit as exc:
        if exc.code not in (None, 0):
            print(f"bench/{a.name}.py exited with {exc.code}: nothing recorded", file=sys.stderr)
            return 1
    finally:
        sys.argv = old_argv
    write_section(a.doc, a.name, section(a.name, args, buf.getvalue(), time.perf_counter() - t0))
    print(f"recorded in {a.doc}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
