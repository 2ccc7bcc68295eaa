"""The real-arm rehearsal runs the product: ``adaptiveh up configs/franka_sim.yaml`` against franky-sim.

robot-io drives franky-sim (MuJoCo FR3 speaking libfranka's protocol) through franky; the actor beside it
plays plans with the plan retreat; the target reaches the learner through vision, from the sim camera's
replica of franky-sim's world. Checked from the run's own files: plans played through franky, a retreat
dropping planned motion, the replica camera's target against the scripted one, the summary naming the
policy it started from (an empty one here; ``test_handoff_stack`` hands one over).
"""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import yaml
from loopback import free_endpoint, unique_name
from stack_helpers import run_up

from bus import messages as m
from deploy.config import compose_stack_yaml
from monitor import recording

pytest.importorskip("franky")
pytest.importorskip("franky_sim")
from franka_simulators import FrankySimServer  # noqa: E402

STEPS = 300
HOST = f"127.0.{np.random.randint(1, 250)}.{np.random.randint(2, 250)}"


def franka_sim_config(directory: Path, host: str, steps: int = STEPS, **learner) -> Path:
    """``configs/franka_sim.yaml`` made private to one test (name, hub, franky-sim's address, folders)."""
    cfg = compose_stack_yaml("configs/franka_sim.yaml")
    cfg["name"] = unique_name("fsim")
    cfg["zenoh"]["hub"] = free_endpoint()
    cfg["robot"]["franka"]["ip"] = host
    cfg["vision"]["rate_hz"] = 15.0  # two cores run franky-sim's 1 kHz loop and every part besides
    cfg["learner"].update({"steps": steps, "checkpoint_dir": str(directory / "learner"), **learner})
    cfg["monitor"]["port"] = 0
    cfg["monitor"]["foxglove_port"] = 0
    cfg["recording"]["dir"] = str(directory / "rec")
    path = directory / "franka_sim.yaml"
    path.write_text(yaml.safe_dump(cfg))
    return path


def replica_errors(records: list) -> np.ndarray:
    """For every fresh fix vision published where the target was in plain view, its distance (m) from the
    scripted target at the fix's frame time: the truth message just before (robot-io publishes one each
    tick), moved on at its velocity. Left out: fixes while the arm homed (no tick: the truth stood still),
    within 0.5 s of a new episode's target (the tracker re-acquires), and with the hand within 15 cm of
    the target (the replica arm covers part of it, as a real arm would)."""
    truth, hand, fixes = [], [], []
    for topic, _, _, data in records:
        if topic.endswith("/" + m.TARGET_TRUTH.name):
            t = m.Target.FromString(data)
            truth.append((t.frame_stamp, np.asarray(t.position), np.asarray(t.velocity)))
        elif topic.endswith("/" + m.STATE.name):
            s = m.RobotState.FromString(data)
            hand.append((s.stamp, np.asarray(s.ee_pos)))
        elif topic.endswith("/" + m.TARGET.name):
            t = m.Target.FromString(data)
            if t.valid and t.status == m.Target.TRACKING:
                fixes.append((t.frame_stamp, np.asarray(t.position)))
    truth.sort(key=lambda x: x[0])
    hand.sort(key=lambda x: x[0])
    t_stamps, h_stamps = np.array([x[0] for x in truth]), np.array([x[0] for x in hand])
    jumps = np.array(
        [
            b[0]
            for a, b in zip(truth, truth[1:], strict=False)
            if np.linalg.norm(b[1] - a[1] - a[2] * (b[0] - a[0])) > 0.01
        ]
    )
    errors = []
    for stamp, position in fixes:
        i, j = int(np.searchsorted(t_stamps, stamp)) - 1, int(np.searchsorted(h_stamps, stamp)) - 1
        if i < 0 or j < 0 or stamp - t_stamps[i] > 0.06:
            continue
        t0, p0, v0 = truth[i]
        seen = p0 + v0 * (stamp - t0)
        recent = np.any((jumps <= stamp) & (jumps > stamp - 0.5))
        if recent or np.linalg.norm(hand[j][1] - seen) < 0.15:
            continue
        errors.append(float(np.linalg.norm(position - seen)))
    return np.asarray(errors)


@pytest.mark.timeout(600)
def test_the_rehearsal_plays_plans_through_franky_and_sees_its_target(tmp_path):
    with FrankySimServer(HOST):
        summary = run_up(franka_sim_config(tmp_path, HOST))
    actor = json.loads((tmp_path / "learner" / "actor.json").read_text())
    print(json.dumps({k: summary[k] for k in ("global_step", "reasons", "safety_events", "H")}, indent=1))
    print(json.dumps(actor, indent=1))
    assert summary["global_step"] == STEPS
    assert actor["plan_starts"] > 10  # plans played through franky, each from its first action
    assert summary["reasons"].get("retreat", 0) > 0
    assert actor["retreat_dropped"] > 0 and actor["dropped_planned_moving"] > 0
    assert summary["started_from"] is None
    assert (
        "an empty policy"
        in subprocess.run(
            [
                sys.executable,
                "-c",
                "import json,sys; from deploy.run_report import summary_table; "
                f"print(summary_table(json.load(open({str(tmp_path / 'summary.json')!r}))))",
            ],
            capture_output=True,
            text=True,
            check=True,
        ).stdout
    )
    errors = replica_errors(recording.read(summary["recording"]))
    print(
        f"replica target error: {len(errors)} fixes, median {1000 * np.median(errors):.1f} mm, "
        f"p90 {1000 * np.percentile(errors, 90):.1f} mm, max {1000 * errors.max():.1f} mm"
    )
    assert len(errors) > 100
    assert np.median(errors) < 0.005
