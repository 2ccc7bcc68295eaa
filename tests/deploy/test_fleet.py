"""Several arms, one learner (``configs/fleet.yaml``), over real Zenoh with PyBullet arms.

Each arm's robot-io and actor run as processes; the learner learns from every arm's ticks and publishes one
policy to all. What is checked: two arms feed one learner and both play plans from its snapshots, and a
learner killed mid-run and restarted loses no transition of either arm (``adaptiveh up``); an arm that
joins late plays its first plan from the newest snapshot; an arm that dies has its open segment closed
and the other goes on; an arm's own stop stops it alone, the fleet's E-STOP stops both, and a control
signed for one arm is refused on another's key.
"""

from __future__ import annotations

import json
import os
import pickle
import secrets
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest
import yaml
from bus_probe import BusProbe
from polling import wait_until
from stack_helpers import parts_of, running_part, write_fleet_config

from bus import messages as m
from bus.signing import mac_key
from bus.transport import Bus, ZenohConfig, open_session, wait_listening
from monitor.recording import read

pytestmark = pytest.mark.skipif(not sys.platform.startswith("linux"), reason="reads /proc")


def test_two_arms_feed_one_learner_both_play_its_snapshots_and_a_learner_kill_loses_nothing(tmp_path):
    path, _ = write_fleet_config(tmp_path, "fl", steps=500)
    out = tmp_path / "summary.json"
    up = subprocess.Popen(
        [sys.executable, "-m", "deploy.cli", "up", str(path), "--summary", str(out)],
        stdout=subprocess.DEVNULL,
        stderr=subprocess.DEVNULL,
    )
    ckpt = tmp_path / "learner" / "checkpoint.pkl"
    try:
        wait_until(ckpt.exists, 120, "the learner's first checkpoint")
        learner = parts_of(path)["learn"]
        os.kill(learner, signal.SIGKILL)  # mid-run: both actors go on and keep what it has not saved
        wait_until(lambda: parts_of(path).get("learn") not in (None, learner), 30, "the learner restarted")
        assert up.wait(timeout=300) == 0
    finally:
        if up.poll() is None:
            up.kill()
        for pid in parts_of(path).values():
            os.kill(pid, signal.SIGKILL)
    summary = json.loads(out.read_text())
    result = json.loads((tmp_path / "learner" / "result.json").read_text())
    assert summary["restarts"] == {"learner": 1}
    arms = summary["arms"]
    assert set(arms) == {"arm0", "arm1"}
    for arm, row in arms.items():
        assert row["episodes"] >= 2 and row["segments"] > 0, (arm, row)
        assert row["policy_version"] > 0, f"{arm} never played a plan from the learner's snapshot"
        assert row["transitions_lost"] == 0 and not row["error"], (arm, row)
    actors = [json.loads((tmp_path / "learner" / f"actor-{a}.json").read_text()) for a in arms]
    assert all(a["preemptions"] > 0 for a in actors), actors  # robot-io played plans, newer ones followed
    # Every step the learner took is one transition of one arm's stream, learned in order, none skipped:
    # the restarted learner resumed from its checkpoint and the actors sent it the rest.
    learned = result["transitions_learned"]
    assert set(learned) == {a["stream"] for a in actors}
    assert sum(learned.values()) == result["global_step"] == 500
    assert result["transitions_lost"] == 0
    assert {e["arm"] for e in result["episodes"]} == {"arm0", "arm1"}
    # The recording keeps each arm's channels apart: its states and plans under its own key.
    keys = {key for key, *_ in read(summary["recording"])}
    for arm in arms:
        assert {m.STATE.key(f"{_name(path)}/{arm}"), m.CMD_CHUNK.key(f"{_name(path)}/{arm}")} <= keys
    assert m.TRANSITIONS.key(_name(path)) in keys  # the fleet's: one stream topic for all arms


class Operator(BusProbe):
    """The test's peer on the fleet's keys: sees every arm's states and the learner's snapshots, sends the
    operator's stops (signed, as the monitor does)."""

    def __init__(self, cfg: dict, token: str) -> None:
        super().__init__(Bus(open_session(ZenohConfig(hub=cfg["zenoh"]["hub"])), cfg["name"], mac_key(token)))
        self.transitions = self.collect(m.TRANSITIONS, arrival=False)
        self.snapshots = self.collect(m.POLICY, arrival=False)
        self.modes: dict[str, str] = {}
        for arm in ("arm0", "arm1"):
            self.bus.subscribe(m.STATE, lambda s, a=arm: self._mode(a, s), arm=arm)

    def _mode(self, arm: str, state: m.RobotState) -> None:
        self.modes[arm] = m.label(state, "mode")

    def of_arm(self, arm: str) -> list[m.Transition]:
        with self.lock:
            return [t for t in self.transitions if t.arm == arm]

    def newest_snapshot(self) -> int:
        with self.lock:
            return max((s.version for s in self.snapshots), default=-1)


def _arm_parts(cfg: dict, arm: str, directory: Path, ready, token: str):
    """robot-io and the actor of ``arm``, as ``adaptiveh up`` starts them."""
    robot = running_part("robot-io", cfg, directory, lambda: None, token, ("--arm", arm, "--watch", "actor"))
    actor = running_part("act", cfg, directory, ready, token, ("--arm", arm))
    return robot, actor


def _plans(op: Operator, arm: str) -> list[m.Transition]:
    """The arm's transitions that played a plan's action (a hold's carries no prediction)."""
    return [t for t in op.of_arm(arm) if t.predicted]


def test_a_late_arm_plays_the_newest_snapshot_a_dead_arm_leaves_the_other_going_and_stops_obey_scope(
    tmp_path,
):
    path, cfg = write_fleet_config(tmp_path, "fj", steps=100_000, checkpoint_every=50)
    token = secrets.token_urlsafe(12)
    joined: list[Operator] = []

    def learner_up() -> None:
        wait_listening(cfg["zenoh"]["hub"])
        joined.append(Operator(cfg, token))

    # The learner owns the hub here (as the supervisor would): every other part joins through it.
    cfg["zenoh"]["listen"] = [cfg["zenoh"]["hub"]]
    learner_cfg = {**cfg, "zenoh": dict(cfg["zenoh"])}
    cfg["zenoh"]["listen"] = []
    with running_part("learn", learner_cfg, tmp_path, learner_up, token):
        op = joined[0]
        robot0, actor0 = _arm_parts(
            cfg, "arm0", tmp_path, lambda: op.wait(lambda: op.newest_snapshot() > 100, 90, "snapshots"), token
        )
        with robot0, actor0:
            before = op.newest_snapshot()
            robot1, actor1 = _arm_parts(
                cfg, "arm1", tmp_path, lambda: op.wait(lambda: _plans(op, "arm1"), 60, "arm1's plans"), token
            )
            with robot1, actor1 as arm1_actor:
                # Its first plan (a tick before it, while the offered snapshot loads, holds the arm: no plan).
                first = _plans(op, "arm1")[0]
                assert first.policy_version >= before > 0  # its first plan: the newest policy, not an empty
                # arm1's actor dies: the learner closes its open segment; arm0 goes on untouched.
                stream1 = first.stream
                arm1_actor.kill()
                ckpt = tmp_path / "learner" / "checkpoint.pkl"
                had = len(op.of_arm("arm0"))
                op.wait(lambda: len(op.of_arm("arm0")) > had + 60, 30, "arm0 acting on")
                wait_until(lambda: stream1 not in _streams(ckpt), 30, "arm1's open segment closed")
                # arm1's own stop stops it alone; the fleet's E-STOP stops every arm.
                stop = m.Control(command=m.Control.ESTOP, jog=[0.0] * 3, arm="arm1")
                op.bus.publisher(m.CONTROL, arm="arm1")(stop)
                op.wait(lambda: op.modes.get("arm1") == "estop", 10, "arm1 e-stopped")
                time.sleep(0.5)
                assert op.modes.get("arm0") == "running"
                op.bus.publisher(m.CONTROL)(m.Control(command=m.Control.ESTOP, jog=[0.0] * 3))
                op.wait(lambda: op.modes.get("arm0") == "estop", 10, "arm0 e-stopped by E-STOP all")
                # A release signed for arm1, put on arm0's key (a replay), is refused; arm0's own is obeyed.
                release = op.bus.publisher(m.CONTROL, arm="arm0")
                release(m.Control(command=m.Control.RELEASE, jog=[0.0] * 3, arm="arm1"))
                time.sleep(1.0)
                assert op.modes.get("arm0") == "estop"
                release(m.Control(command=m.Control.RELEASE, jog=[0.0] * 3, arm="arm0"))
                op.wait(lambda: op.modes.get("arm0") != "estop", 10, "arm0 released")
        op.bus.close()


def _name(config: Path) -> str:
    return yaml.safe_load(config.read_text())["name"]


def _streams(ckpt: Path) -> dict:
    try:
        return pickle.loads(ckpt.read_bytes()).get("streams", {})
    except (OSError, EOFError, pickle.UnpicklingError):
        return {}
