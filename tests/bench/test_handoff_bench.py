"""The handoff bench keeps the recording of a run that fell short of the goal, every part of it, and only
of such a run."""

from __future__ import annotations

from repo_scripts import load_script

from monitor import recording


def test_a_run_short_of_the_goal_keeps_every_part_of_its_recording(tmp_path, monkeypatch):
    bench = load_script("bench/handoff.py")
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
    bench = load_script("bench/handoff.py")
    monkeypatch.setattr(bench, "SHORT", tmp_path / "short")
    kept = bench.keep_if_short({"success_by_quarter": [0.3, 0.8, 0.9, 0.9]}, [], "slow_arm", "handoff", 0)
    assert kept is None and not (tmp_path / "short").exists()


def test_runs_of_another_length_or_agent_are_named_not_mixed(tmp_path):
    """One --out folder holds runs of one length and one set of --agent keys: the bench names the others
    before running any."""
    bench = load_script("bench/handoff.py")
    runs = {"scratch_s0": '{"steps": 6000}', "scratch_s1": '{"steps": 1000}'}
    runs["handoff_s0"] = '{"steps": 6000, "agent": {"h_max": 20}}'
    for name, text in runs.items():
        path = bench.run_file(tmp_path, "franky_sim", *name.split("_s"))
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_text(text)
    folder = tmp_path / "franky_sim"
    assert bench.other_runs(tmp_path, 6000, {}) == [folder / "handoff_s0.json", folder / "scratch_s1.json"]
    assert bench.other_runs(tmp_path, 1000, {}) == [folder / "handoff_s0.json", folder / "scratch_s0.json"]
    assert bench.other_runs(tmp_path, 6000, {"h_max": 20}) == [
        folder / "scratch_s0.json",
        folder / "scratch_s1.json",
    ]


def test_the_handoff_is_compared_on_the_seeds_both_starts_ran():
    """Success rates pooled over the shared seeds' episodes (a quarter: episodes // 4 of them)."""
    bench = load_script("bench/handoff.py")
    run = {"setting": "slow_arm", "episodes": 120}
    runs = [
        run | {"variant": "handoff", "seed": 0, "success_by_quarter": [1.0, 0.9, 0.9, 0.8]},
        run | {"variant": "handoff", "seed": 1, "success_by_quarter": [1.0, 1.0, 1.0, 1.0]},
        run | {"variant": "fixed_h", "seed": 0, "success_by_quarter": [1.0, 1.0, 1.0, 1.0]},
    ]
    (c,) = [c for s in bench.SETTINGS if (c := bench.compare(runs, s, "handoff", "fixed_h"))]
    assert c["setting"] == "slow_arm" and c["seeds"] == [0]
    assert c["last_quarter"]["n_a"] == 30 and abs(c["last_quarter"]["diff"] + 0.2) < 1e-12
    assert abs(c["whole_run"]["diff"] + 0.1) < 1e-12 and c["whole_run"]["hi"] < 0
    assert bench.compare(runs, "slow_arm", "handoff", "frozen") is None


def test_the_hand_outside_the_workspace_box_is_counted_by_how_far():
    """Over the ticks that played an action, each once: a hand within 1 cm of the box counts as inside (the
    clip's own rounding); one 4 cm under its floor is out, and the deepest excursion is reported. States while
    homing count apart."""
    from bus import messages as m

    hands = [(0.5, 0.0, 0.3), (0.5, 0.0, 0.045), (0.5, 0.0, 0.01), (0.85, 0.0, 0.3)]
    records = [
        ("arm/state", "RobotState", 0, m.RobotState(ee_pos=h, tick=t, played_index=0).SerializeToString())
        for t, h in enumerate(hands)
    ]
    # a state published again for the same tick, and states while homing (no action played)
    records.append(("arm/state", "RobotState", 0, m.RobotState(ee_pos=hands[2], tick=2).SerializeToString()))
    for h in [(0.5, 0.0, 0.9), (0.5, 0.0, 0.9)]:
        records.append(
            ("arm/state", "RobotState", 0, m.RobotState(ee_pos=h, played_index=-1).SerializeToString())
        )
    records.append(("arm/target", "Target", 0, b"not a state"))
    out = load_script("bench/handoff.py").hand_outside_box(records, [0.2, -0.45, 0.05], [0.8, 0.45, 0.7])
    assert out == {
        "hand_outside_box_share": 0.5,
        "hand_outside_box_max_m": 0.05,
        "hand_outside_box_not_playing_max_m": 0.2,
    }
