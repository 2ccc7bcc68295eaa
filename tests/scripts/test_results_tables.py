"""The README's and docs' headline tables are the results files' numbers, regenerated, never hand-typed."""

from __future__ import annotations

import copy
import importlib.util
import json
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
_spec = importlib.util.spec_from_file_location("results_tables", ROOT / "scripts" / "results_tables.py")
tables = importlib.util.module_from_spec(_spec)
_spec.loader.exec_module(tables)


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
