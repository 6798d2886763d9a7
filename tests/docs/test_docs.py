"""The README reads in five minutes and its links lead somewhere; benchmarks are recorded
from the scripts' own output."""

from __future__ import annotations

import re
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]


def test_readme_is_short_and_every_link_resolves():
    readme = ROOT / "README.md"
    assert readme.stat().st_size <= 10 * 1024, readme.stat().st_size  # issue 40: <= 10 KB
    text = readme.read_text()
    links = re.findall(r"\]\(([^)#]+)\)", text)
    assert links
    missing = [ln for ln in links if not ln.startswith("http") and not (ROOT / ln).exists()]
    assert missing == [], missing


def test_docs_links_resolve():
    bad = []
    for doc in (ROOT / "docs").glob("*.md"):
        for ln in re.findall(r"\]\(([^)#]+)\)", doc.read_text()):
            if not ln.startswith("http") and not (doc.parent / ln).exists():
                bad.append(f"{doc.name}: {ln}")
    assert bad == [], bad


def test_bench_record_replaces_only_its_own_section(tmp_path):
    import importlib.util

    spec = importlib.util.spec_from_file_location("record", ROOT / "bench" / "record.py")
    record = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(record)
    doc = tmp_path / "benchmarks.md"
    record.write_section(doc, "a", record.section("a", [], "first a", 1.0))
    record.write_section(doc, "b", record.section("b", ["--x"], "only b", 2.0))
    record.write_section(doc, "a", record.section("a", [], "second a", 1.0))
    text = doc.read_text()
    assert "second a" in text and "first a" not in text and "only b" in text
    assert text.index("## a") < text.index("## b")  # a's section stays where it was
    assert "`python bench/b.py --x`" in text
