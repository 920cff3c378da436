"""Every "SPEC n" (or "SPEC n-m") in the code and the docs names a section of docs/spec.md."""

from __future__ import annotations

import re
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
SEARCHED = ("aia", "conf", "docs", "scripts", "benchmarks", "tests", "README.md")
SUFFIXES = {".py", ".md", ".yaml", ".sh", ".toml"}
REFERENCE = re.compile(r"SPEC (\d+)(?:\s*-\s*(\d+))?")


def _sections() -> set[int]:
    text = (ROOT / "docs" / "spec.md").read_text()
    return {int(n) for n in re.findall(r"^## (\d+)\. ", text, flags=re.MULTILINE)}


def _files() -> list[Path]:
    files = []
    for name in SEARCHED:
        path = ROOT / name
        files += [path] if path.is_file() else [p for p in path.rglob("*") if p.suffix in SUFFIXES]
    return files


def test_every_spec_reference_is_a_section_of_docs_spec():
    sections = _sections()
    assert sections == set(range(1, 12))  # SPEC.md's numbering, which the references were written against
    missing, count = [], 0
    for path in _files():
        for match in REFERENCE.finditer(path.read_text(errors="replace")):
            first, last = int(match[1]), int(match[2] or match[1])
            count += 1
            missing += [f"{path.relative_to(ROOT)}: {match[0]}" for n in range(first, last + 1) if n not in sections]
    assert count > 20 and not missing, missing


def test_no_reference_points_outside_the_repository():
    stale = [str(p.relative_to(ROOT)) for p in _files() if "SPEC.md" in p.read_text(errors="replace")
             and p.name != Path(__file__).name]
    assert not stale, stale
