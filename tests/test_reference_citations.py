"""Code and docs cite docs/reference.md (which users have), by anchors that exist.

Every ``reference.md#<anchor>`` in the project's .py and .md files names an ``<a id>`` of
docs/reference.md, and nothing cites the internal "conventions section N" any more.
"""

from __future__ import annotations

import re
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
REFERENCE = ROOT / "docs" / "reference.md"
_CITE = re.compile(r"reference\.md#([A-Za-z0-9_-]+)")
_OLD = re.compile(r"conventions\s+(section|s\.|§)\s*\d+|conventions\s+\d+:", re.I)
_SKIP = {".git", "venv", ".venv", "node_modules", "build", "dist"}


def _sources() -> list[Path]:
    return [
        p
        for p in ROOT.rglob("*")
        if p.suffix in (".py", ".md")
        and p.is_file()
        and not any(part in _SKIP or part.endswith(".egg-info") for part in p.parts)
    ]


def anchors() -> set[str]:
    return set(re.findall(r'<a id="([^"]+)"></a>', REFERENCE.read_text(encoding="utf-8")))


def test_the_reference_has_its_sections() -> None:
    assert {"models", "rest", "norms", "positions", "coefficients", "kvh", "effects", "cli",
            "csv", "api"} <= anchors()  # fmt: skip


def test_every_citation_names_an_existing_section() -> None:
    known = anchors()
    bad = [
        f"{p.relative_to(ROOT)}: #{a}"
        for p in _sources()
        for a in _CITE.findall(p.read_text(encoding="utf-8", errors="replace"))
        if a not in known
    ]
    assert not bad, bad


def test_nothing_cites_the_internal_conventions_document() -> None:
    this = Path(__file__).resolve()
    old = [
        f"{p.relative_to(ROOT)}:{n}"
        for p in _sources()
        if p.resolve() != this
        for n, line in enumerate(p.read_text(encoding="utf-8", errors="replace").splitlines(), 1)
        if _OLD.search(line)
    ]
    assert not old, old
