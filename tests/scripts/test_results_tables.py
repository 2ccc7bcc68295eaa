"""The README's and docs' headline tables are the results files' numbers, regenerated, never hand-typed."""

from __future__ import annotations

import copy
import json
from pathlib import Path

import pytest
from repo_scripts import load_script

ROOT = Path(__file__).resolve().parents[2]
tables = load_script("scripts/results_tables.py")


def test_every_table_in_the_readme_and_docs_matches_its_results_file():
    blocks = {doc.name: tables.BLOCK.findall(doc.read_text()) for doc in tables.DOCS}
    assert blocks["README.md"], "the README's headline table is generated (a <!-- table: NAME --> block)"
    stale = [doc.name for doc in tables.DOCS if tables.refreshed(doc.read_text()) != doc.read_text()]
    assert not stale, f"tables out of date with results/ in {stale}: run python scripts/results_tables.py"


def test_a_changed_result_changes_its_table():
    data = json.loads((ROOT / "results" / "stack_robustness.json").read_text())
    before = tables.stack_robustness(data)
    changed = copy.deepcopy(data)
    label = next(iter(changed["table"]))
    changed["table"][label]["last_quarter_success_median"] = 0.01
    assert tables.stack_robustness(changed) != before
    assert "| 1 (" in tables.stack_robustness(changed)
    with pytest.raises(KeyError, match="no such table"):
        tables.render("nonsense")


# -- the results pages (results/*.md, the docs site's results/) -------------------------------------


def test_every_results_page_is_what_its_results_files_say():
    pages = tables.rendered_pages()
    assert set(pages) == {*tables.PAGES, tables.INDEX}
    stale = tables.stale_pages(pages)
    assert not stale, f"results pages out of date: {stale}: run python scripts/results_tables.py"


def test_a_changed_result_makes_its_page_stale(monkeypatch, tmp_path):
    pages = tables.rendered_pages()
    for name, text in pages.items():
        (tmp_path / name).write_text(text)
    assert tables.stale_pages(pages, tmp_path) == []
    path, _ = tables.TABLES["handoff"]
    monkeypatch.setitem(tables.TABLES, "handoff", (path, lambda data: "| a changed number |\n"))
    changed = tables.rendered_pages()
    assert tables.stale_pages(changed, tmp_path) == ["handoff.md"]
    assert "| a changed number |" in changed["handoff.md"]
    (tmp_path / "vision.md").unlink()
    assert tables.stale_pages(changed, tmp_path) == ["handoff.md", "vision.md"]


def test_the_index_lists_every_results_file(tmp_path):
    (tmp_path / "new_bench.json").write_text("{}")
    (tmp_path / "handoff.json").write_text("{}")
    index = tables.render_index(results=tmp_path)
    assert "| `new_bench.json` | - |" in index  # a results file nothing shows says so
    assert "| `handoff.json` | [From the simulator to the arm: handoffs](handoff.md) |" in index


def test_every_results_page_is_in_the_docs_nav():
    nav = (ROOT / "mkdocs.yml").read_text()
    missing = [name for name in tables.rendered_pages() if f"results/{name}" not in nav]
    assert not missing, f"results pages missing from mkdocs.yml's nav: {missing}"
