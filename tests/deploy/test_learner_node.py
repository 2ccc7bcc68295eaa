"""Learner checkpoint and resume over Zenoh: robot-io and the learner run as processes; the learner is
killed (SIGKILL: no goodbye, no final checkpoint), the robot holds on the lost liveliness token, and a new
learner loads the last periodic checkpoint and keeps learning from its step, not from 0."""

from __future__ import annotations

import json
import signal
import subprocess
import sys
import time
from pathlib import Path

import yaml
from bus_probe import BusProbe
from loopback import unique_name

from bus import messages as m
from bus.transport import Bus, ZenohConfig, open_session
from deploy.config import compose_stack_yaml

EVERY = 50  # checkpoint_every = one episode, so checkpoints fall on episode boundaries


class Watch(BusProbe):
    """The test's own peer on the bus: robot states, safety events, learner telemetry."""

    def __init__(self, hub: str, robot: str) -> None:
        super().__init__(Bus(open_session(ZenohConfig(hub=hub)), robot))
        self.states = self.collect(m.STATE)
        self.safety = self.collect(m.EVENTS_SAFETY, arrival=False)
        self.telemetry = self.collect(m.TELEMETRY_LEARNER, arrival=False)

    @property
    def step(self) -> int:
        """The learner's highest global step seen."""
        with self.lock:
            return max((t.global_step for t in self.telemetry), default=0)


def _learn(cfg: Path, *extra: str) -> subprocess.Popen:
    return subprocess.Popen(
        [sys.executable, "-m", "deploy.cli", "learn", "--config", str(cfg), "--log-level", "WARNING", *extra],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )


def test_killed_learner_holds_robot_and_resumes_from_checkpoint(tmp_path: Path, endpoint: str) -> None:
    cfg = compose_stack_yaml("configs/sim.yaml")
    cfg["name"] = unique_name("ck")
    cfg["zenoh"]["hub"] = endpoint
    cfg.pop("vision")
    ckdir = tmp_path / "l"
    cfg["learner"].update(
        steps=100000,
        target_topic="sim/target_truth",
        checkpoint_dir=str(ckdir),
        checkpoint_every=EVERY,
        execution="closed_loop",  # the learner drives the arm (an actor's: tests/deploy/test_actor_node.py)
    )
    assert EVERY % cfg["learner"]["max_episode_steps"] == 0
    path = tmp_path / "c.yaml"
    path.write_text(yaml.safe_dump(cfg))
    robot = subprocess.Popen(
        [sys.executable, "-m", "deploy.cli", "robot-io", "--config", str(path), "--log-level", "WARNING"]
    )
    time.sleep(1.0)  # robot-io owns the hub; the test and the learners join it
    watch = Watch(cfg["zenoh"]["hub"], cfg["name"])
    first = _learn(path)
    second = None
    try:
        watch.wait(lambda: watch.step >= 2 * EVERY + 10, 120, "two checkpoints' worth of steps")
        seen = watch.step
        first.send_signal(signal.SIGKILL)
        first.wait(timeout=10)
        lost = m.SafetyEvent.LIVELINESS
        watch.wait(lambda: any(e.kind == lost and e.held for e in watch.safety), 10, "a liveliness hold")
        t_lost = time.time()  # the probe stamps arrivals with wall-clock time
        time.sleep(1.5)
        with watch.lock:
            late = [s for t, s in watch.states if t > t_lost + 0.5]
        assert late and all(s.mode == m.RobotState.HELD for s in late), {s.mode for s in late}
        assert max(abs(v) for s in late for v in s.dq) < 0.02  # rad/s: the arm stands still
        ee = [s.ee_pos for s in late]
        assert max(abs(a - b) for p in ee for a, b in zip(p, ee[0], strict=True)) < 0.002

        total = seen + 60 + (seen % 2 == 0)  # odd: the final save lands mid-episode
        second = _learn(path, "--steps", str(total))
        out, err = second.communicate(timeout=120)
        assert second.returncode == 0, err[-2000:]
        res = json.loads((ckdir / "result.json").read_text())
        resumed = res["resumed_from"]
        # The last periodic checkpoint before the kill: at least the last multiple of EVERY we saw.
        assert resumed % EVERY == 0 and resumed >= (seen // EVERY) * EVERY >= 2 * EVERY
        assert res["global_step"] == total and res["steps_this_session"] == total - resumed
        assert len(res["episodes"]) >= resumed // cfg["learner"]["max_episode_steps"] + 1  # old ones kept
        assert any(s["global_step"] > resumed for s in res["segments"])  # it kept learning
        with watch.lock:
            running, release = m.RobotState.RUNNING, m.SafetyEvent.RELEASE
            assert any(s.mode == running for t, s in watch.states if t > t_lost + 2.0)  # released
            assert any(e.kind == release and "liveliness" in e.detail for e in watch.safety)  # it is back
        # A clean stop saves mid-episode (total is not a multiple of the episode length here); resuming
        # from it abandons that stale episode and carries on from exactly that step.
        third = _learn(path, "--steps", str(total + 60))
        _, err = third.communicate(timeout=120)
        assert third.returncode == 0, err[-2000:]
        res3 = json.loads((ckdir / "result.json").read_text())
        assert res3["resumed_from"] == total and res3["global_step"] == total + 60
        # The interrupted episode is dropped, not stitched onto a fresh reset of the robot.
        assert all(e["length"] <= cfg["learner"]["max_episode_steps"] for e in res3["episodes"])
    finally:
        for p in (first, second):
            if p is not None and p.poll() is None:
                p.kill()
                p.wait()
        watch.bus.close()
        robot.terminate()
        robot.wait(timeout=20)
