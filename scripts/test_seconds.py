"""Seconds each test module took, from a pytest JUnit XML report, for the suite's schedule.

``make test`` hands whole modules to its two xdist workers (``--dist loadscope``), each
taking the next module when it runs out. Handed out longest first (tests/conftest.py reads
``tests/module_seconds.json``), the last modules are short and the workers finish
together; in pytest-xdist's own order (most tests first) the single-test whole-study
modules came last and one worker ran them alone for about a minute.

Usage::

    .venv/bin/python -m pytest -m "not slow and not gpu" -n 2 --dist loadscope \\
        --junitxml=/tmp/suite.xml
    .venv/bin/python scripts/test_seconds.py /tmp/suite.xml --write tests/module_seconds.json

A module missing from the file is scheduled after every listed one, so a stale file only
costs balance, never a test.
"""

from __future__ import annotations

import argparse
import json
import sys
import xml.etree.ElementTree as ET
from collections import Counter
from pathlib import Path


def module_seconds(junit_xml: Path) -> dict[str, float]:
    """``{"tests/x/test_y.py": seconds}`` summed over the module's test cases (setup, call
    and teardown, as pytest reports them), longest first, to 0.1 s."""
    total: Counter[str] = Counter()
    for case in ET.parse(junit_xml).iter("testcase"):
        parts = (case.get("classname") or "").split(".")
        # the dotted path of the module, then a test class's name where there is one
        n = next((i + 1 for i, p in enumerate(parts) if p.startswith("test_")), len(parts))
        path = "/".join(parts[:n]) + ".py"
        if not path.startswith("tests/"):
            continue
        total[path] += float(case.get("time") or 0.0)
    return {k: round(v, 1) for k, v in sorted(total.items(), key=lambda kv: (-kv[1], kv[0]))}


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("junit_xml", type=Path)
    ap.add_argument("--write", type=Path, help="write the JSON here (default: print it)")
    args = ap.parse_args(argv)
    seconds = module_seconds(args.junit_xml)
    if not seconds:
        print(f"{args.junit_xml}: no test cases of tests/", file=sys.stderr)
        return 1
    text = json.dumps(seconds, indent=1) + "\n"
    if args.write:
        args.write.write_text(text)
    else:
        sys.stdout.write(text)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
