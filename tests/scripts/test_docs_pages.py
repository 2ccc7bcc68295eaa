"""Every docs page is short enough to read: at most 300 lines (issue #48). docs/reference/ is generated and
docs/results/ is the results folder seen from the site, so neither counts."""

from __future__ import annotations

from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
DOCS = ROOT / "docs"
MAX_LINES = 300
NOT_PAGES = ("reference", "results")  # generated, and a link to results/


def pages(docs: Path = DOCS) -> list[Path]:
    """The hand-written pages under ``docs``: every .md but those under docs/reference/ and docs/results/."""
    return sorted(p for p in docs.rglob("*.md") if p.relative_to(docs).parts[0] not in NOT_PAGES)


def too_long(paths: list[Path], max_lines: int = MAX_LINES) -> dict[str, int]:
    """Each page over ``max_lines`` lines, with its line count."""
    counts = {str(p): len(p.read_text(encoding="utf-8").splitlines()) for p in paths}
    return {name: n for name, n in counts.items() if n > max_lines}


def test_no_docs_page_is_over_300_lines():
    found = pages()
    assert DOCS / "stack.md" in found and not any("reference" in p.parts for p in found)
    long = too_long(found)
    assert not long, f"split these pages along their headings (at most {MAX_LINES} lines each): {long}"


def test_a_page_of_301_lines_is_too_long_and_one_of_300_is_not(tmp_path):
    docs = tmp_path / "docs"
    (docs / "reference").mkdir(parents=True)
    (docs / "long.md").write_text("line\n" * (MAX_LINES + 1))
    (docs / "ok.md").write_text("line\n" * MAX_LINES)
    (docs / "reference" / "generated.md").write_text("line\n" * 1000)
    found = pages(docs)
    assert found == [docs / "long.md", docs / "ok.md"]
    assert too_long(found) == {str(docs / "long.md"): MAX_LINES + 1}
