"""The documentation stays readable and its links hold: the README is a five-minute read (at most 150 lines),
every document in docs/ is at most 600 lines, and every relative link in the README and in docs/ points to a
file that exists."""

from __future__ import annotations

import re
from pathlib import Path
from urllib.parse import unquote

import pytest

ROOT = Path(__file__).resolve().parents[1]
README = ROOT / "README.md"
DOCS = sorted((ROOT / "docs").rglob("*.md"))

README_MAX_LINES = 150
DOC_MAX_LINES = 600

#: A Markdown link or image: ](target) or ](target "title"); the target ends at a space or ")".
LINK = re.compile(r"\]\(\s*<?([^)\s>]+)>?(?:\s+\"[^\"]*\")?\s*\)")
EXTERNAL = ("http://", "https://", "mailto:", "#")


def _lines(path: Path) -> int:
    return len(path.read_text(encoding="utf-8").splitlines())


def _without_code(text: str) -> str:
    """The text with fenced code blocks and inline code spans blanked out: links are not read there."""
    text = re.sub(r"^(```|~~~).*?^\1[^\n]*$", "", text, flags=re.S | re.M)
    return re.sub(r"`[^`\n]*`", "", text)


def relative_links(path: Path) -> list[str]:
    """The relative link targets of a Markdown file (not http/https/mailto, not anchors within the page)."""
    targets = LINK.findall(_without_code(path.read_text(encoding="utf-8")))
    return [t for t in targets if not t.startswith(EXTERNAL)]


def test_the_documents_are_found():
    assert README.is_file()
    assert len(DOCS) >= 10, DOCS


def test_readme_is_a_five_minute_read():
    assert _lines(README) <= README_MAX_LINES, f"README.md has {_lines(README)} lines (at most {README_MAX_LINES})"


@pytest.mark.parametrize("doc", DOCS, ids=lambda p: str(p.relative_to(ROOT)))
def test_every_document_in_docs_is_at_most_600_lines(doc):
    assert _lines(doc) <= DOC_MAX_LINES, f"{doc.relative_to(ROOT)} has {_lines(doc)} lines (at most {DOC_MAX_LINES})"


@pytest.mark.parametrize("doc", [README, *DOCS], ids=lambda p: str(p.relative_to(ROOT)))
def test_every_relative_link_points_to_a_file_that_exists(doc):
    broken = []
    for target in relative_links(doc):
        file = unquote(target.split("#", 1)[0].split("?", 1)[0])
        if not (doc.parent / file).exists():
            broken.append(target)
    assert not broken, f"{doc.relative_to(ROOT)}: links to missing files: {broken}"


def test_the_link_reader_finds_links_and_skips_what_it_should():
    text = ("[a](docs/a.md) ![b](images/b.png \"t\") [c](https://x.org/c) [d](#anchor) [e](mailto:x@y.z)\n"
            "`[f](inline/code.md)`\n```\n[g](fenced/code.md)\n```\n[h](docs/h.md#section)\n")
    found = [t for t in LINK.findall(_without_code(text)) if not t.startswith(EXTERNAL)]
    assert found == ["docs/a.md", "images/b.png", "docs/h.md#section"]
