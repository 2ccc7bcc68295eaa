"""The learner's session against forgeries (issue #13's wedge): robot-io (PyBullet, its own process, with
the stack's operator token) on a loopback hub, the real closed-loop Zenoh env as the learner, and a
stranger on the bus that copies the learner's session id and publishes unsigned, altered, replayed and
foreign chunks while the learner steps.

Before sessions, one chunk with a higher number froze the arm and let the learner step at five times the
control rate on it, silently. Now: every chunk the arm plays is one the learner signed, the learner keeps
stepping at no more than one step per control tick, and robot-io reports the refusals."""

from __future__ import annotations

import threading
import time

import numpy as np
from bus_probe import send_chunk

from bus import messages as m
from bus.signing import authentic, mac_key
from bus.transport import Bus, open_session
from deploy.zenoh_env import ZenohReachEnv, env_settings

FORGED_STEP = [0.0, 0.05, 0.0]  # a 5 cm sideways step: it would show in the arm's path


def test_forged_chunks_neither_wedge_nor_speed_up_nor_steer(robot_hub):
    stack, probe = robot_hub
    events = probe.collect(m.EVENTS_SAFETY, arrival=False)
    states = probe.collect(m.STATE, arrival=False)
    chunks = probe.collect(m.CMD_CHUNK, arrival=False)
    key = mac_key(probe.token)
    env = ZenohReachEnv(Bus(open_session(stack.zenoh), stack.name, key), env_settings(stack))
    stranger = Bus(open_session(stack.zenoh), stack.name)
    stop, forged = threading.Event(), [0]
    rng = np.random.default_rng(0)

    def forge() -> None:
        while not stop.wait(0.1):
            seq, me = env.link.chunk_seq, env.link.session.id
            send_chunk(stranger, seq + 1, [FORGED_STEP], me)  # unsigned, the learner's next number
            send_chunk(stranger, seq + 10**6, [FORGED_STEP], me)  # an altered number
            send_chunk(stranger, seq + 1, [FORGED_STEP], "f" * 16)  # another session
            with probe.lock:
                genuine = [c for c in chunks if c.session == me][-3:]
            for c in genuine:  # exact replays (stale) and copies with one byte flipped (forged)
                data = bytearray(c.SerializeToString())
                stranger.session.put(stranger.key(m.CMD_CHUNK), bytes(data))
                data[rng.integers(len(data))] ^= 1 << int(rng.integers(8))
                stranger.session.put(stranger.key(m.CMD_CHUNK), bytes(data))
            forged[0] += 3 + 2 * len(genuine)

    try:
        env.reset(seed=4)
        thread = threading.Thread(target=forge, daemon=True)
        thread.start()
        n, t0, ticks = 60, time.monotonic(), []
        for _ in range(n):
            ticks.append(env.step(np.array([0.0, 0.0, 0.004]))[4]["tick"])  # the observation's tick
        elapsed = time.monotonic() - t0
    finally:
        stop.set()
        thread.join()
        env.bus.close()
        stranger.close()
    assert forged[0] >= 50
    assert elapsed < 30, "the learner was wedged"
    # One step per control tick at most: never faster than the arm (the wedge ran at 5x the rate).
    assert all(b > a for a, b in zip(ticks, ticks[1:], strict=False)), str(ticks)
    with probe.lock:
        signed = {(c.seq, c.stamp) for c in chunks if c.session == env.link.session.id and authentic(c, key)}
        played = [(s.played_chunk, s.played_stamp) for s in states if s.session == env.link.session.id]
        kinds = [m.label(e, "kind") for e in events]
    played = [p for p in played if p[0] >= 0]
    assert len(played) >= n // 2 and set(played) <= signed, "the arm played a chunk the learner did not sign"
    assert "foreign_command" in kinds


def test_a_forged_target_never_reaches_the_learner(robot_hub):
    """A stranger publishing targets (where the arm should reach) on the learner's target key: the env,
    with the stack's key, keeps robot-io's signed ones only."""
    stack, probe = robot_hub
    env = ZenohReachEnv(Bus(open_session(stack.zenoh), stack.name, mac_key(probe.token)), env_settings(stack))
    stranger = Bus(open_session(stack.zenoh), stack.name)
    fake = m.Target(position=[0.5, 0.4, 0.6], velocity=[0, 0, 0], covariance=[0.0] * 9, valid=True)
    fake.status, fake.frame_stamp = m.Target.TRACKING, time.time()
    pub = stranger.publisher(m.TOPICS[stack.learner.target_topic])
    stop = threading.Event()

    def forge() -> None:
        while not stop.wait(0.02):
            fake.frame_stamp = time.time()
            pub.put(fake)

    thread = threading.Thread(target=forge, daemon=True)
    thread.start()
    try:
        env.reset(seed=3)
        seen = []
        for _ in range(20):
            env.step(np.zeros(3))
            seen.append(list(env.link.target.position))
    finally:
        stop.set()
        thread.join()
        stranger.close()
        env.bus.close()
    assert seen and all(not np.allclose(p, fake.position) for p in seen)
    assert env.bus.bad_messages.get(stack.learner.target_topic, 0) > 10  # dropped as unsigned, counted
