"""The manual holds today's figures; the history of runs sits in dated notes.

* README.md fits in :data:`README_MAX_LINES` lines.
* Every note of docs/results/ is named ``YYYY-MM-DD-<topic>.md`` and has one row in the
  index, docs/results/README.md (date, question, answer, link), and every row's note exists.
* The manual pages (README.md, docs/*.md) carry no date outside a link to a dated note:
  measurements of a day go to docs/results, the page links there.
"""

from __future__ import annotations

import re
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
README_MAX_LINES = 180
NOTE = re.compile(r"^\d{4}-\d{2}-\d{2}-[\w.-]+\.md$")
DATE = re.compile(r"\b20\d\d-\d\d-\d\d\b")
#: the target of a markdown link to a dated note (the link's text may start a line before)
NOTE_LINK = re.compile(r"\]\((?:\.\./)*(?:docs/)?results/[^)]*\)")


def index_rows(index: Path) -> dict[str, str]:
    """note file name -> the row's date, from the index table."""
    rows = {}
    for line in index.read_text().splitlines():
        cells = [c.strip() for c in line.strip().strip("|").split("|")]
        link = re.search(r"\]\(([^)]+\.md)\)", line)
        if len(cells) == 4 and link and DATE.fullmatch(cells[0]):
            rows[link.group(1)] = cells[0]
    return rows


def dated_lines(page: Path) -> list[str]:
    """``file:line: text`` of each line holding a date that is not part of a note link."""
    out = []
    for i, line in enumerate(page.read_text().splitlines(), 1):
        if DATE.search(NOTE_LINK.sub("", line)):
            out.append(f"{page.name}:{i}: {line.strip()[:120]}")
    return out


def test_the_readme_fits():
    n = len((REPO / "README.md").read_text().splitlines())
    assert n <= README_MAX_LINES, f"README.md has {n} lines (at most {README_MAX_LINES})"


def test_every_results_note_is_dated_and_indexed():
    results = REPO / "docs" / "results"
    notes = sorted(p.name for p in results.glob("*.md") if p.name != "README.md")
    assert notes and all(NOTE.match(n) for n in notes), [n for n in notes if not NOTE.match(n)]
    rows = index_rows(results / "README.md")
    assert sorted(set(rows)) == notes, "index rows vs notes differ"
    assert all(rows[n] == n[:10] for n in notes), {n: rows[n] for n in notes if rows[n] != n[:10]}


def test_manual_pages_carry_no_dated_measurements():
    pages = [REPO / "README.md", *sorted((REPO / "docs").glob("*.md"))]
    bad = [hit for page in pages for hit in dated_lines(page)]
    assert bad == [], "dates in the manual (move the run to docs/results):\n" + "\n".join(bad)


def test_the_checks_see_a_dated_line_and_an_unindexed_note(tmp_path):
    page = tmp_path / "page.md"
    page.write_text("Run on 2026-12-01: 0.8.\nSee [the run](results/2026-12-01-x.md).\n")
    assert dated_lines(page) == ["page.md:1: Run on 2026-12-01: 0.8."]
    index = tmp_path / "README.md"
    index.write_text("| date | q | a | note |\n|---|---|---|---|\n"
                     "| 2026-12-01 | q? | a. | [n](2026-12-01-x.md) |\n")
    assert index_rows(index) == {"2026-12-01-x.md": "2026-12-01"}
