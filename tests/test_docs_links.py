"""The manual points only at what a reader has.

* No reference to a document outside the repository ("FACTS §", "house rule", "issue N",
  ARCHITECTURE) in the package sources or the manual (README.md, docs/ outside the dated
  notes of docs/results/, which record what a run was asked).
* Every relative markdown link in README.md and docs/ reaches an existing file, and its
  ``#anchor`` a heading of that file (GitHub's slug of the heading).
* Every ``docs/....md`` path named in the package sources exists.
"""

from __future__ import annotations

import re
from collections import Counter
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]
PACKAGES = ("msta_data", "policies", "collect", "train", "eval")
#: a name for a document the reader does not have
FOREIGN = re.compile(r"\bFACTS\b|house rule|\bissue \d+|\bARCHITECTURE\b")
LINK = re.compile(r"(?<!!)\[[^\]]*\]\(([^)\s]+)\)|!\[[^\]]*\]\(([^)\s]+)\)")
DOC_PATH = re.compile(r"\bdocs/[\w./-]+?\.md\b")


def package_sources(root: Path = REPO) -> list[Path]:
    return sorted(p for pkg in PACKAGES for p in (root / pkg).rglob("*.py"))


def manual_pages(root: Path = REPO, with_results: bool = True) -> list[Path]:
    pages = [root / "README.md", *sorted((root / "docs").rglob("*.md"))]
    if not with_results:
        pages = [p for p in pages if "results" not in p.relative_to(root).parts[:2]]
    return pages


def foreign_references(paths: list[Path], root: Path = REPO) -> list[str]:
    """``file:line: text`` for each line that names a document the reader lacks."""
    hits = []
    for path in paths:
        for n, line in enumerate(path.read_text(encoding="utf-8").splitlines(), 1):
            if FOREIGN.search(line):
                hits.append(f"{path.relative_to(root)}:{n}: {line.strip()[:100]}")
    return hits


def _outside_code(text: str) -> list[str]:
    """The lines of a markdown text outside fenced code blocks (those read as ``''``)."""
    lines, fenced = [], False
    for line in text.splitlines():
        if line.lstrip().startswith("```"):
            fenced = not fenced
            lines.append("")
            continue
        lines.append("" if fenced else line)
    return lines


def slug(heading: str) -> str:
    """GitHub's anchor of a heading: lower case, punctuation dropped, spaces to hyphens."""
    text = re.sub(r"[^\w\- ]", "", heading.strip().lower())
    return text.replace(" ", "-")


def anchors(path: Path) -> set[str]:
    seen: Counter[str] = Counter()
    out = set()
    for line in _outside_code(path.read_text(encoding="utf-8")):
        m = re.match(r"#{1,6} (.+)", line)
        if not m:
            continue
        s = slug(m.group(1))
        out.add(s if not seen[s] else f"{s}-{seen[s]}")
        seen[s] += 1
    return out


def broken_links(pages: list[Path], root: Path = REPO) -> list[str]:
    """``file:line: target (why)`` for each relative link whose file or anchor is missing."""
    bad = []
    for page in pages:
        for n, line in enumerate(_outside_code(page.read_text(encoding="utf-8")), 1):
            for m in LINK.finditer(line):
                target = m.group(1) or m.group(2)
                if re.match(r"[a-z][a-z0-9+.-]*:", target):  # http:, mailto:, ...
                    continue
                file_part, _, anchor = target.partition("#")
                dest = (page.parent / file_part).resolve() if file_part else page
                where = f"{page.relative_to(root)}:{n}: {target}"
                if not dest.exists():
                    bad.append(f"{where} (no such file)")
                elif anchor and dest.suffix == ".md" and anchor not in anchors(dest):
                    bad.append(f"{where} (no such heading)")
    return bad


def missing_doc_paths(paths: list[Path], root: Path = REPO) -> list[str]:
    bad = []
    for path in paths:
        for n, line in enumerate(path.read_text(encoding="utf-8").splitlines(), 1):
            for doc in DOC_PATH.findall(line):
                if not (root / doc).exists():
                    bad.append(f"{path.relative_to(root)}:{n}: {doc}")
    return bad


# ----- the checks see what they look for --------------------------------------------------

def test_the_checks_see_broken_links_and_foreign_references(tmp_path):
    (tmp_path / "docs").mkdir()
    (tmp_path / "docs" / "a.md").write_text(
        "# A page\n\n## Does it work? (2026-12-04)\n\n```bash\n# not a heading\n```\n")
    (tmp_path / "README.md").write_text(
        "[ok](docs/a.md) [ok](docs/a.md#does-it-work-2026-12-04) [x](docs/b.md)\n"
        "[y](docs/a.md#not-a-heading) [z](#a-page) see FACTS §3, issue 12\n"
        "[web](https://example.org/x.md)\n")
    pages = manual_pages(tmp_path)
    assert broken_links(pages, tmp_path) == [
        "README.md:1: docs/b.md (no such file)",
        "README.md:2: docs/a.md#not-a-heading (no such heading)",
        "README.md:2: #a-page (no such heading)",
    ]
    assert foreign_references(pages, tmp_path) == [
        "README.md:2: [y](docs/a.md#not-a-heading) [z](#a-page) see FACTS §3, issue 12"]
    (tmp_path / "m.py").write_text('"""See docs/a.md and docs/gone.md."""\n')
    assert missing_doc_paths([tmp_path / "m.py"], tmp_path) == ["m.py:1: docs/gone.md"]
    assert slug("Training the RMA teacher (`msta-train-teacher`, `train/teacher/`)") == \
        "training-the-rma-teacher-msta-train-teacher-trainteacher"


# ----- the repository ---------------------------------------------------------------------

def test_no_reference_to_a_document_the_reader_does_not_have():
    hits = foreign_references(package_sources() + manual_pages(with_results=False))
    assert not hits, "references to documents outside the repository:\n" + "\n".join(hits)


@pytest.mark.parametrize("with_results", [False, True], ids=["manual", "results"])
def test_every_relative_link_reaches_a_file_and_heading(with_results):
    pages = [p for p in manual_pages() if ("results" in p.parts) == with_results]
    bad = broken_links(pages)
    assert not bad, "broken links:\n" + "\n".join(bad)


def test_every_docs_path_named_in_the_sources_exists():
    bad = missing_doc_paths(package_sources())
    assert not bad, "documents named in the code that do not exist:\n" + "\n".join(bad)
