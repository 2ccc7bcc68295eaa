"""The handoff bench keeps the recording of a run that fell short of the goal, every part of it, and only
of such a run."""

from __future__ import annotations

import importlib.util
from pathlib import Path

from monitor import recording

ROOT = Path(__file__).resolve().parents[2]


def load_bench():
    spec = importlib.util.spec_from_file_location("handoff_bench", ROOT / "bench" / "handoff.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def test_a_run_short_of_the_goal_keeps_every_part_of_its_recording(tmp_path, monkeypatch):
    bench = load_bench()
    monkeypatch.setattr(bench, "ROOT", tmp_path)
    monkeypatch.setattr(bench, "SHORT", tmp_path / "runs" / "handoff_short")
    first = tmp_path / "rec" / "run.mcap"
    first.parent.mkdir()
    parts = [first, recording.part_path(first, 2), recording.part_path(first, 3)]
    for n, part in enumerate(parts):
        part.write_bytes(bytes([n]) * 8)

    kept = bench.keep_if_short(
        {"success_by_quarter": [0.3, 0.8, 0.9, 0.87]}, [str(p) for p in parts], "franky_sim", "scratch", 2
    )

    assert kept == "runs/handoff_short/franky_sim/scratch_s2.mcap"
    copies = recording.parts(tmp_path / kept)
    assert [c.read_bytes() for c in copies] == [p.read_bytes() for p in parts]


def test_a_run_that_met_the_goal_keeps_nothing(tmp_path, monkeypatch):
    bench = load_bench()
    monkeypatch.setattr(bench, "SHORT", tmp_path / "short")
    kept = bench.keep_if_short({"success_by_quarter": [0.3, 0.8, 0.9, 0.9]}, [], "slow_arm", "handoff", 0)
    assert kept is None and not (tmp_path / "short").exists()


def test_runs_of_another_length_are_named_not_mixed(tmp_path):
    """One --out folder holds runs of one length: the bench names those of another before running any."""
    bench = load_bench()
    for name, steps in (("scratch_s0", 6000), ("scratch_s1", 1000)):
        path = bench.run_file(tmp_path, "franky_sim", *name.split("_s"))
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_text(f'{{"steps": {steps}}}')
    assert bench.other_lengths(tmp_path, 6000) == [tmp_path / "franky_sim" / "scratch_s1.json"]
    assert bench.other_lengths(tmp_path, 1000) == [tmp_path / "franky_sim" / "scratch_s0.json"]
