"""The plan channel through the stack: robot-io (PyBullet, its own process) plays plans that the Zenoh env
sends as the actor's ``PlanChannel``; the test is the actor (tests/deploy/test_actor_node.py: the real
one).

What the issue asks of the robot: a new plan preempts the rest of the old one, the robot reports the
dropped planned actions (non-zero motion, not the zeros of closed loop), and the arm's next commanded
displacement comes from the new plan. The env reports every tick once and in order.
"""

from __future__ import annotations

import numpy as np
import pytest

from bus import messages as m
from bus.signing import mac_key
from bus.transport import Bus, open_session
from deploy.config import StackConfig
from deploy.zenoh_env import ZenohReachEnv, env_settings
from learner.plans import Executed, Plan

RATE = 20.0


def open_env(stack: StackConfig, token: str, **learner) -> ZenohReachEnv:
    cfg = stack.model_copy(
        update={"learner": stack.learner.model_copy(update={"execution": "actor", **learner})}
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
            for sent in (env.link.book.get(env.link.chunk_seq - 1), env.link.book.get(env.link.chunk_seq))
        }
        status = probe.wait(
            lambda: [
                s
                for s in probe.status
                if s.session == env.link.session.id and s.chunk_seq == seqs[0] and s.preempted_by == seqs[1]
            ],
            3,
            "status",
        )[0]
        executed = sum(s.plan_id == 0 for s in steps)
        assert status.dropped == 30 - status.executed and status.dropped >= 30 - executed - 2
        drop = probe.wait(lambda: list(env.link.book.drops), 3, "the env's account")[0]
        assert (drop.plan_id, drop.by_plan_id, drop.dropped) == (0, 1, status.dropped)
        assert drop.moving == drop.dropped and drop.path_m == pytest.approx(0.012 * drop.dropped)
        assert env.dropped_planned == status.dropped
    finally:
        env.bus.close()


def test_closed_loop_chunks_say_which_segment_and_why_it_began(robot_hub):
    """Closed loop: the chunk that opens a segment after a retreat says so, and robot-io's status of the
    chunk it cut echoes it. Each step's chunk is a plan through the plan channel: the drop is in the one
    account of drops (``PlanBook``) the actor's plans are in, not a second one of its own."""
    stack, probe = robot_hub
    chunks = probe.collect(m.CMD_CHUNK, arrival=False)
    env = open_env(stack, probe.token, execution="closed_loop", chunk_len=5)
    try:
        env.reset(seed=3)
        me = env.link.session.id
        env.step(np.array([0.0, 0.01, 0.0]))
        env.open_segment(4, "retreat")
        env.step(np.array([0.0, -0.01, 0.0]))
        env.step(np.zeros(3))

        def cut() -> list[m.ChunkStatus]:
            return [s for s in probe.status if s.session == me and s.preempted_by >= 0 and s.dropped]

        book = env.link.book
        probe.wait(lambda: len(cut()) >= 2 and len(book.drops) >= 2, 5, "the status of the cut chunks")
        drops = list(env.link.book.drops)
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
    assert (
        env.link.book.counts()["retreat_preemptions"] == 1
        and env.link.book.counts()["retreat_dropped"] == first.dropped
    )
