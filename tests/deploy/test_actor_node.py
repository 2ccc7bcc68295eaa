"""The actor beside the arm (``adaptiveh act``) with robot-io, over real Zenoh, with the stack's key.

robot-io (PyBullet) and the actor run as processes; the test is the vision part (it relays the
simulator's target, and can make it stale) and, where needed, starts a learner. What is checked: plans
are decided and played while the learner is stopped (SIGSTOP) for longer than a plan, and a learner killed
outright and started again loses no transition (it resumes from its checkpoint and the actor sends it
the rest); a policy snapshot that is malformed, unsigned or older is
refused with a safety event while the policy in use keeps running; a stale target is never used as fresh.
"""

from __future__ import annotations

import json
import os
import pickle
import secrets
import signal
import subprocess
import sys
import threading
import time
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

import numpy as np
import pytest
import yaml
from bus_probe import BusProbe
from loopback import free_endpoint, unique_name
from stack_helpers import parts_of, running_part

from bus import messages as m
from bus.learner_session import REFUSALS
from bus.signing import mac_key
from bus.transport import Bus, open_session, wait_listening
from deploy.config import compose_stack_yaml
from deploy.part_env import TOKEN_ENV

STALE_POSITION = (0.5, 0.28, 0.3)  # where the stale fixes say the target is (the truth is elsewhere)


class Bench(BusProbe):
    """The test's peer: relays sim/target_truth as vision's ``target`` (fresh, or stale when asked)."""

    def __init__(self, cfg: dict, token: str) -> None:
        super().__init__(Bus(open_session(_zenoh(cfg)), cfg["name"], mac_key(token)))
        self.stale = threading.Event()
        self.silent = threading.Event()
        self.transitions = self.collect(m.TRANSITIONS, arrival=False)
        self.safety = self.collect(m.EVENTS_SAFETY, arrival=False)
        self.states = self.collect(m.STATE)
        self.chunks = self.collect(m.CMD_CHUNK)
        self.segments = self.collect(m.EVENTS_RETREAT, arrival=False)
        self.acks = self.collect(m.TRANSITION_ACKS, arrival=False)
        self.status = self.collect(m.CHUNK_STATUS, arrival=False)
        self._target = self.bus.publisher(m.TARGET)
        self.bus.subscribe(m.TARGET_TRUTH, self._relay)

    def _relay(self, truth: m.Target) -> None:
        if self.silent.is_set():  # a camera that died: no target at all
            return
        if self.stale.is_set():  # a fix two seconds old, somewhere else: a camera that froze
            msg = m.Target(position=STALE_POSITION, velocity=[0, 0, 0], covariance=[0.0] * 9, valid=True)
            msg.status, msg.frame_stamp = m.Target.TRACKING, time.time() - 2.0
        else:
            msg = m.Target()
            msg.CopyFrom(truth)
            msg.ClearField("mac")
        self._target(msg)

    def versions(self) -> list[int]:
        with self.lock:
            return [t.policy_version for t in self.transitions]

    def refusals(self) -> list[str]:
        with self.lock:
            return [e.detail for e in self.safety if "policy snapshot refused" in e.detail]


def _zenoh(cfg: dict) -> m.Any:
    from bus.transport import ZenohConfig

    return ZenohConfig(hub=cfg["zenoh"]["hub"])


@contextmanager
def _acting(
    tmp_path: Path, agent: dict | None = None, algo: str = "adaptiveh"
) -> Iterator[tuple[dict, Bench, str]]:
    """robot-io (watching the actor) and the actor (``agent`` laid over the stack's agent settings, for
    the learner ``algo``), up and acting; yields (config dict, bench, token). The actor has stopped (and
    written ``actor.json``) when the block ends."""
    cfg = compose_stack_yaml("configs/sim.yaml")
    cfg.pop("vision")
    cfg.pop("monitor")
    cfg["name"] = unique_name("act")
    cfg["zenoh"]["hub"] = free_endpoint()
    cfg["learner"].update(
        steps=100_000, checkpoint_dir=str(tmp_path / "learner"), execution="actor", algo=algo
    )
    cfg["learner"]["agent"].update(agent or {})
    token = secrets.token_urlsafe(12)
    joined: list[Bench] = []

    def robot_up() -> None:
        wait_listening(cfg["zenoh"]["hub"])
        joined.append(Bench(cfg, token))
        joined[0].wait(lambda: len(joined[0].states) > 3, 60, "robot states")

    with running_part("robot-io", cfg, tmp_path, robot_up, token=token, args=("--watch", "actor")):
        bench = joined[0]
        with running_part(
            "act",
            cfg,
            tmp_path,
            lambda: bench.wait(lambda: len(bench.transitions) > 20, 60, "the actor's ticks"),
            token=token,
        ):
            yield cfg, bench, token
        bench.bus.close()


@pytest.fixture
def arm(tmp_path: Path) -> Iterator[tuple[dict, Bench, str]]:
    with _acting(tmp_path) as up:
        yield up


def _learner(cfg: dict, tmp_path: Path, token: str) -> subprocess.Popen:
    path = tmp_path / "learner.yaml"
    path.write_text(yaml.safe_dump(cfg))
    return subprocess.Popen(
        [sys.executable, "-m", "deploy.cli", "learn", "--config", str(path), "--log-level", "WARNING"],
        stdout=subprocess.DEVNULL,
        stderr=subprocess.PIPE,
        text=True,
        env={**os.environ, TOKEN_ENV: token},
    )


def test_plans_play_while_the_learner_is_stopped_and_a_killed_learner_loses_no_transition(arm, tmp_path):
    cfg, bench, token = arm
    learner = _learner(cfg, tmp_path, token)
    try:
        bench.wait(lambda: max(bench.versions()) > 0, 60, "a snapshot of the learner in use")
        os.kill(learner.pid, signal.SIGSTOP)
        t0, stop_s = time.time(), 4.0  # longer than a plan (h_max 50 ticks at 20 Hz: 2.5 s)
        time.sleep(stop_s)
        with bench.lock:
            chunks = {c.seq for t, c in bench.chunks if t0 < t < t0 + stop_s}
            ticks = [s for t, s in bench.states if t0 < t < t0 + stop_s]
            held = [e.detail for e in bench.safety if m.label(e, "kind") in ("watchdog", "liveliness")]
        os.kill(learner.pid, signal.SIGCONT)
        assert len(chunks) >= 2, "the actor made no new plan while the learner was stopped"
        playing = sum(s.played_chunk >= 0 for s in ticks) / max(len(ticks), 1)
        assert len(ticks) >= 60 and playing >= 0.6, f"{playing:.0%} of {len(ticks)} ticks played a plan"
        assert {s.mode for s in ticks} == {m.RobotState.RUNNING}, "the arm was held"
        assert not held, held
        # The learner catches up; then a SIGKILL (no goodbye): its checkpoint is no older than the last
        # segment it announced (each segment end is checkpointed before it is announced).
        n = len(bench.segments)
        bench.wait(lambda: len(bench.segments) > n + 5, 30, "segments after the learner continued")
        os.kill(learner.pid, signal.SIGKILL)
        learner.wait(10)
        with bench.lock:
            announced = max(e.global_step for e in bench.segments)
            played = max(t.step for t in bench.transitions) + 1  # by the actor, when the learner died
            dead = {a.learner for a in bench.acks}
        ckpt = Path(cfg["learner"]["checkpoint_dir"]) / "checkpoint.pkl"
        with open(ckpt, "rb") as fh:
            kept = pickle.load(fh)["log"]["global_step"]
        assert kept >= announced, f"checkpoint at step {kept}, segment announced at {announced}"
        # The actor plays on; a new learner resumes from the checkpoint and gets every transition after
        # it, once each, in order: those the dead one learned unsaved, and those of the outage.
        time.sleep(2.0)
        learner = _learner(cfg, tmp_path, token)
        bench.wait(
            lambda: any(a.learner not in dead and a.learned >= played + 60 for a in bench.acks),
            60,
            "the new learner to learn past the outage",
        )
        learner.terminate()
        assert learner.wait(30) == 0, learner.stderr.read()
        with open(ckpt, "rb") as fh:
            state = pickle.load(fh)
        (learned,) = state["stream_marks"].values()
        assert learned >= played + 60 and state["log"]["global_step"] == learned, (learned, state["log"])
    finally:
        learner.kill()
        learner.wait(10)


def _snapshot(version: int, centers: int = 2) -> m.PolicySnapshot:
    rng = np.random.default_rng(version)
    return m.PolicySnapshot(
        version=version,
        state_dim=15,
        action_dim=3,
        policy_centers=rng.uniform(-1, 1, (centers, 15)).ravel().tolist(),
        policy_weights=(0.1 * rng.standard_normal((centers, 3))).ravel().tolist(),
        field_centers=rng.uniform(-1, 1, (centers, 15)).ravel().tolist(),
        field_weights=rng.standard_normal((centers, 3)).ravel().tolist(),
        sigma=[0.015] * 3,
    )


def test_a_bad_snapshot_is_refused_with_a_safety_event_and_the_policy_in_use_keeps_running(arm):
    cfg, bench, token = arm
    put = bench.bus.publisher(m.POLICY)  # signed with the stack's key
    put(_snapshot(1000))
    bench.wait(lambda: bench.versions()[-1] == 1000, 10, "the signed, newer snapshot in use")
    malformed = _snapshot(2000)
    del malformed.policy_centers[-1]  # 29 values: not rows of 15
    stranger = Bus(open_session(_zenoh(cfg)), cfg["name"])  # no key: its snapshots are unsigned
    try:
        cases = [
            (lambda: put(malformed), "rows of 15"),
            (lambda: stranger.publisher(m.POLICY)(_snapshot(3000)), "not signed"),
            (lambda: put(_snapshot(500)), "not newer than 1000"),
        ]
        for send, why in cases:
            time.sleep(1.1)  # the actor reports at most one refusal a second (a flood must not flood)
            n = len(bench.refusals())
            send()
            bench.wait(lambda n=n: len(bench.refusals()) > n, 5, f"a refusal ({why})")
            assert why in bench.refusals()[-1]
        time.sleep(1.1)
        for _ in range(3):  # a burst: the rest is reported when the throttle's second ends
            put(_snapshot(500))
        late = lambda: [e for e in bench.safety if "2 more refused snapshots" in e.detail]  # noqa: E731
        bench.wait(late, 5, "the refusals held back")
    finally:
        stranger.close()
    n = len(bench.transitions)
    bench.wait(lambda: len(bench.transitions) > n + 40, 10, "ticks after the refusals")
    assert set(bench.versions()[n:]) == {1000}


@pytest.mark.parametrize("outage", ["stale", "silent"])
def test_a_stale_target_is_never_used_as_fresh(arm, outage):
    cfg, bench, token = arm
    limit = cfg["learner"].get("target_timeout_s", 0.5)
    n = len(bench.transitions)
    t0 = time.time()
    getattr(bench, outage).set()
    time.sleep(2.0)
    getattr(bench, outage).clear()
    hold_from = (
        t0 + limit + 0.05 + cfg["robot"]["watchdog_timeout_s"] + 0.3
    )  # a one-tick stay, then the watchdog
    with bench.lock:
        modes = {m.label(s, "mode") for _, s in bench.states if hold_from <= s.stamp <= t0 + 2.0}
    assert modes == {"held"}, f"the arm was {modes} while the target was stale"
    bench.wait(lambda: len(bench.transitions) > n + 40, 20, "the actor acting again on fresh fixes")
    with bench.lock:
        seen = list(bench.transitions)[n:]
    ages = [t.target_age for t in seen]
    assert max(ages) <= limit, f"a transition with a target {max(ages):.2f} s old"
    targets = np.array([t.next_obs[6:9] for t in seen] + [t.obs[6:9] for t in seen])
    assert np.min(np.linalg.norm(targets - STALE_POSITION, axis=1)) > 0.02, "the stale fix was acted on"


def test_the_actor_corrects_its_plan_model_from_the_ticks_it_played(tmp_path):
    with _acting(tmp_path, {"plan_model": "corrected"}) as (cfg, bench, token):
        n = len(bench.transitions)
        bench.wait(lambda: len(bench.transitions) > n + 60, 30, "60 more ticks")
        ticks = len(bench.transitions)
    counts = json.loads((Path(cfg["learner"]["checkpoint_dir"]) / "actor.json").read_text())
    # Each tick that played a plan's action right after the tick it acted from (an episode's first from
    # the reset's tick); never one across a reset or an outage (learner/test_acting.py checks which).
    assert 40 <= counts["plan_model_updates"] <= counts["steps"], (counts, ticks)
    # Every plan that played was seen to start, and how late against the tick it was planned from.
    # (a plan cut before it played, a hold under load, has no start: half is a loose floor)
    assert counts["segments"] / 2 <= counts["plan_starts"] <= counts["segments"] + 1, counts
    assert counts["plan_starts_late"] <= min(counts["late_ticks"], counts["plan_starts"]), counts


def test_the_fixed_h_learners_actor_never_retreats_and_ends_a_segment_every_fixed_h_ticks(tmp_path):
    """``learner.algo: rkhs`` (the paper's fixed-H baseline): the actor playing its segments ends them by
    the learner's rule, not AdaptiveH's retreat test (it once took AdaptiveH's, so the handoff bench's
    fixed-H runs were AdaptiveH's)."""
    with _acting(tmp_path, {"fixed_h": 7}, algo="rkhs") as (cfg, bench, token):
        bench.wait(lambda: len(bench.transitions) > 100, 60, "100 ticks")
        with bench.lock:
            ticks = [(t.segment, m.label(t, "end"), t.HasField("statistic")) for t in bench.transitions]
    ends = {end for _, end, _ in ticks}
    assert "retreat" not in ends and "h_max" in ends, ends
    assert not any(has_statistic for _, _, has_statistic in ticks)  # no retreat test is evaluated
    length = {}
    for segment, _, _ in ticks:
        length[segment] = length.get(segment, 0) + 1
    cut = {segment for segment, end, _ in ticks if end == "h_max"}
    assert cut and all(length[segment] == 7 for segment in cut), {s: length[s] for s in cut}


def test_the_ledger_of_plans_equals_what_robot_io_reported_across_retreats_and_a_robot_io_restart(tmp_path):
    """The actor's one account of planned actions dropped (``PlanBook.counts`` in ``actor.json``) equals
    the sum of robot-io's own chunk statuses for its session, over a run with retreats in which robot-io
    was SIGKILLed and a new robot-io took over."""
    with _acting(tmp_path) as (cfg, bench, token):
        learner = _learner(cfg, tmp_path, token)  # its snapshots give the actor a field: retreats
        try:
            retreats = lambda: [t for t in bench.transitions if m.label(t, "end") == "retreat"]  # noqa: E731
            bench.wait(lambda: len(retreats()) >= 3, 90, "three retreats")
            with bench.lock:
                before = {s.instance for _, s in bench.states}
            os.kill(parts_of(tmp_path / "robot-io.yaml")["robot-io"], signal.SIGKILL)
            new = lambda: {s.instance for _, s in bench.states} - before  # noqa: E731
            (tmp_path / "again").mkdir()
            with running_part(
                "robot-io",
                cfg,
                tmp_path / "again",
                lambda: bench.wait(new, 60, "a new robot-io"),
                token=token,
                args=("--watch", "actor"),
            ):
                n = len(bench.transitions)
                bench.wait(lambda: len(bench.transitions) > n + 100, 90, "acting on the new robot-io")
                bench.wait(lambda: len(retreats()) >= 5, 90, "retreats on the new robot-io")
        finally:
            learner.kill()
            learner.wait(10)
    counts = json.loads((Path(cfg["learner"]["checkpoint_dir"]) / "actor.json").read_text())
    assert counts["robot_restarts"] == 1, counts
    with bench.lock:
        ours = [s for s in bench.status if s.session == counts["session"]]
    assert not [s for s in ours if m.label(s, "verdict") in REFUSALS and s.preempted_by != -1]
    mine = [s for s in ours if s.preempted_by >= 0 and s.dropped]  # a plan cut by a newer one
    by_retreat = [s for s in mine if m.label(s, "preempted_by_opening") == "retreat"]
    assert counts["preemptions"] == len(mine) > 0, counts
    assert counts["dropped_planned"] == sum(s.dropped for s in mine), counts
    assert counts["retreat_preemptions"] == len(by_retreat) > 0, counts
    assert counts["retreat_dropped"] == sum(s.dropped for s in by_retreat), counts
