"""Plan execution through the stack: robot-io (PyBullet, its own process) plays plans that the Zenoh env
sends as the learner's ``PlanChannel``; the test is the learner.

What the issue asks of the robot: a new plan preempts the rest of the old one, the robot reports the
dropped planned actions (non-zero motion, not the zeros of closed loop), and the arm's next commanded
displacement comes from the new plan. The env reports every tick once and in order.
"""

from __future__ import annotations

import time

import numpy as np
import pytest

from bus import messages as m
from bus.signing import mac_key
from bus.transport import Bus, open_session
from deploy.config import StackConfig, compose_stack_yaml
from deploy.learner_node import LearnerNode, env_settings
from deploy.zenoh_env import ZenohReachEnv
from learner.plans import Executed, Plan

RATE = 20.0


def open_env(stack: StackConfig, token: str, **learner) -> ZenohReachEnv:
    cfg = stack.model_copy(
        update={"learner": stack.learner.model_copy(update={"execution": "plan", **learner})}
    )
    return ZenohReachEnv(Bus(open_session(stack.zenoh), stack.name, mac_key(token)), env_settings(cfg))


def straight(plan_id: int, obs: np.ndarray, step: list[float], n: int, env: ZenohReachEnv) -> Plan:
    """``n`` equal steps, with the path the env's model predicts for them."""
    actions = np.tile(step, (n, 1))
    predicted = [np.asarray(obs, float)]
    for a in actions:
        predicted.append(env.predict_next(predicted[-1], a))
    return Plan(plan_id, actions, actions.copy(), np.asarray(predicted))


def advance_until(env: ZenohReachEnv, pred, limit: int = 60) -> list[Executed]:
    steps = []
    for _ in range(limit):
        steps.append(env.advance())
        if pred(steps[-1]):
            return steps
    raise AssertionError(f"not within {limit} ticks: {[(s.plan_id, s.index) for s in steps]}")


def test_a_new_plan_drops_planned_motion_and_moves_the_arm_at_once(robot_hub):
    stack, probe = robot_hub
    env = open_env(stack, probe.token)
    try:
        obs, _ = env.reset(seed=1)
        sideways = straight(0, obs, [0.0, 0.012, 0.0], 30, env)
        env.send(sideways)
        steps = advance_until(env, lambda s: s.plan_id == 0 and s.index == 5)
        down = straight(1, steps[-1].obs, [0.0, 0.0, -0.012], 10, env)
        env.send(down)
        steps += advance_until(env, lambda s: s.plan_id == 1)
        first = steps[-1]
        # The robot played the new plan's first action on the tick after the old plan's last one.
        assert first.index == 0 and steps[-2].plan_id == 0
        np.testing.assert_allclose(first.action, down.actions[0])
        moved = first.obs[0:3] - steps[-2].obs[0:3]
        assert moved[2] < -0.006 and abs(moved[1]) < 0.004, moved  # m: down, no longer sideways
        # Every tick once, in order; the holds before the first plan arrived are plan -1.
        ticks = [s.info["tick"] for s in steps]
        assert ticks == list(range(ticks[0], ticks[0] + len(ticks)))
        assert all(s.plan_id == -1 and not s.action.any() for s in steps if s.plan_id < 0)
        # The robot's account of the preempted plan: non-zero planned actions dropped, for the new plan.
        seqs = {
            sent.plan.plan_id: sent.seq
            for sent in (env.book.get(env.chunk_seq - 1), env.book.get(env.chunk_seq))
        }
        status = probe.wait(
            lambda: [
                s
                for s in probe.status
                if s.session == env.session.id and s.chunk_seq == seqs[0] and s.preempted_by == seqs[1]
            ],
            3,
            "status",
        )[0]
        executed = sum(s.plan_id == 0 for s in steps)
        assert status.dropped == 30 - status.executed and status.dropped >= 30 - executed - 2
        drop = probe.wait(lambda: list(env.book.drops), 3, "the env's account")[0]
        assert (drop.plan_id, drop.by_plan_id, drop.dropped) == (0, 1, status.dropped)
        assert drop.moving == drop.dropped and drop.path_m == pytest.approx(0.012 * drop.dropped)
        assert env.dropped_planned == status.dropped
    finally:
        env.bus.close()


def test_with_latency_the_old_plan_keeps_playing_until_the_new_one_lands(robot_hub):
    stack, probe = robot_hub
    env = open_env(stack, probe.token, latency_ms=250.0)
    try:
        obs, _ = env.reset(seed=2)
        env.send(straight(0, obs, [0.0, -0.01, 0.0], 40, env))
        advance_until(env, lambda s: s.plan_id == 0 and s.index == 3)
        t0 = time.monotonic()
        env.send(straight(1, obs, [0.0, 0.0, 0.01], 5, env))
        assert time.monotonic() - t0 < 0.05  # s: the learner does not wait out the latency
        np.testing.assert_allclose(env.queued(2), [[0.0, -0.01, 0.0]] * 2)  # the new plan has not landed
        after = advance_until(env, lambda s: s.plan_id == 1)
        old = [s for s in after if s.plan_id == 0]
        assert 3 <= len(old) <= 8 and after[-1].index == 0  # 250 ms = 5 ticks of the old plan, then the new
    finally:
        env.bus.close()


def test_closed_loop_chunks_say_which_segment_and_why_it_began(robot_hub):
    """Closed loop: the chunk that opens a segment after a retreat says so, and robot-io's status of the
    chunk it cut echoes it. Each step's chunk is a plan through the plan channel: the drop reaches the
    learner as plan mode's do (``on_plan_dropped``), one account, not a second one of its own."""
    stack, probe = robot_hub
    chunks = probe.collect(m.CMD_CHUNK, arrival=False)
    env = open_env(stack, probe.token, execution="closed_loop", chunk_len=5)
    drops: list = []
    env.on_plan_dropped = drops.append
    try:
        env.reset(seed=3)
        me = env.session.id
        env.step(np.array([0.0, 0.01, 0.0]))
        env.open_segment(4, "retreat")
        env.step(np.array([0.0, -0.01, 0.0]))
        env.step(np.zeros(3))

        def cut() -> list[m.ChunkStatus]:
            return [s for s in probe.status if s.session == me and s.preempted_by >= 0 and s.dropped]

        probe.wait(lambda: len(cut()) >= 2, 5, "the status of the cut chunks")
        with probe.lock:
            mine = [(c.seq, c.segment, m.label(c, "opened_by")) for c in chunks if c.session == me]
            first, second = cut()[:2]
    finally:
        env.bus.close()
    assert [c[1:] for c in mine] == [(0, "first"), (4, "retreat"), (4, "continue")]
    assert (first.chunk_seq, first.segment, m.label(first, "opened_by")) == (mine[0][0], 0, "first")
    assert (first.preempted_by, m.label(first, "preempted_by_opening")) == (mine[1][0], "retreat")
    assert (second.segment, m.label(second, "preempted_by_opening")) == (4, "continue")
    assert [(d.plan_id, d.by_plan_id, d.by_opening) for d in drops[:2]] == [
        (0, 1, "retreat"),
        (1, 2, "continue"),
    ]
    assert drops[0].dropped == first.dropped and drops[0].moving == 0  # the tail stays put: no motion lost


def test_the_learner_in_plan_mode_retreats_and_its_new_plan_plays_next(robot_hub, tmp_path):
    """The real learner (AdaptiveH, ``learner.execution: plan``): every retreat's plan preempts non-zero
    planned motion on the robot, and the robot's very next tick plays the new plan's first action.
    Last in the module: the learner's liveliness token going away holds the robot."""
    stack, probe = robot_hub
    chunks = probe.collect(m.CMD_CHUNK, arrival=False)
    retreats = probe.collect(m.EVENTS_RETREAT, arrival=False)
    ticks = probe.collect(m.STATE, arrival=False)
    learner = stack.learner.model_copy(
        update={
            "execution": "plan",
            "steps": 300,
            "max_episode_steps": 50,
            "checkpoint_dir": str(tmp_path),
            # the product's agent (its plan retreat's kernel): the defaults' 24 cm-wide kernel may let a
            # 300-step run pass without a retreat
            "agent": compose_stack_yaml("configs/sim.yaml")["learner"]["agent"],
        }
    )
    node = LearnerNode(stack.model_copy(update={"learner": learner}), control_token=probe.token)
    try:
        res = node.run()
    finally:
        node.stop()
    assert res["execution"] == "plan" and res["global_step"] == 300
    seen = {k: res.get(k) for k in ("target_waits", "outage_ticks", "refused", "segments")}
    assert res["retreat_preemptions"] >= 1, seen
    assert res["retreat_dropped_moving"] == res["retreat_dropped"] > 0  # planned motion, not zeros
    me = res["session"]  # chunk numbers restart with each session (the earlier tests' envs had theirs)
    with probe.lock:
        by_tick = {s.tick: s for s in ticks if s.session == me}
        seqs = {c.seq: c for c in chunks if c.session == me}
        # A retreat's plan says so, and opens the segment after the one the retreat closed.
        opened = [c for c in seqs.values() if m.label(c, "opened_by") == "retreat"]
        retreated = {e.segment for e in retreats if m.label(e, "reason") == "retreat"}
        preempted = {
            s.preempted_by: s
            for s in probe.status
            if s.session == me and s.preempted_by in seqs and s.dropped
        }
    assert opened and {c.segment - 1 for c in opened} <= retreated
    checked = 0
    for new in opened:
        assert len(new.predicted_ee) == len(new.actions)  # the plan's path travels with it
        played = [t for t, s in by_tick.items() if s.played_chunk == new.seq]
        if not played:
            continue  # cut before its first tick: by the run's end or by an episode's reset
        first = min(played)
        assert by_tick[first].played_index == 0
        dropped = preempted.get(new.seq)
        if dropped is None:
            continue  # the old plan had run out before this one landed: nothing to preempt
        old = seqs[dropped.chunk_seq]
        # Robot-io's own status of the cut plan names its segment and the retreat that cut it.
        assert (dropped.segment, m.label(dropped, "preempted_by_opening")) == (old.segment, "retreat")
        rest = np.reshape(old.actions, (-1, 3))[dropped.executed :]
        assert len(rest) == dropped.dropped and np.linalg.norm(rest, axis=1).min() > 0
        before = by_tick[first - 1]  # the tick before played the old plan: no hold in between
        assert (before.played_chunk, before.played_index) == (old.seq, dropped.executed - 1)
        checked += 1
    assert checked >= 1  # at least one retreat cut a plan short on the robot
