"""A stop request stops the arm whatever else is wrong with it (issue #31): robot-io (PyBullet, its own
process, with the stack's operator token) on a loopback hub, the test's signed learner session driving
the arm, and a stranger without the token putting e-stops with missing or garbage fields, unknown fields,
a bad stamp, no session and no (or a wrong) signature. Each stops the arm within two control periods."""

from __future__ import annotations

import time

import numpy as np
import pytest
from bus_probe import BusProbe

from bus import messages as m
from bus.learner_session import LearnerSession
from bus.signing import mac_key
from bus.transport import Bus, open_session

UNKNOWN_FIELD = b"\xf8\x07\x01"  # field 127, varint 1: well-formed protobuf, not in the schema


def _estop(**fields) -> bytes:
    msg = m.Control(command=m.Control.ESTOP)
    for name, value in fields.items():
        if name == "jog":
            msg.jog.extend(value)
        else:
            setattr(msg, name, value)
    return msg.SerializeToString()


MALFORMED = {
    "no jog values": _estop(),
    "seven jog values with NaN": _estop(jog=[float("nan"), 1e308, -1.0, 0.0, 2.0, 3.0, 4.0]),
    "a garbage mac and a negative stamp": _estop(jog=[0.0, 0.0, 0.0], mac=b"\x01" * 7, stamp=-5.0),
    "an unknown field": _estop(jog=[0.0, 0.0, 0.0]) + UNKNOWN_FIELD,
}


@pytest.fixture(scope="module")
def driven(robot_hub):
    """The test's learner (signed, its session obeyed) and a stranger's bus without the token."""
    stack, probe = robot_hub
    learner = Bus(open_session(stack.zenoh), stack.name, mac_key(probe.token))
    session = LearnerSession(learner)
    release = learner.publisher(m.CONTROL)
    stranger = Bus(open_session(stack.zenoh), stack.name)
    assert session.reset(seed=5, timeout=20).ok
    yield probe, session, release, stranger, stack.robot.period
    stranger.close()
    learner.close()


def _moving(probe: BusProbe, session: LearnerSession) -> None:
    session.send(
        m.ActionChunk(actions=np.tile([0.0, -0.03, 0.0], (40, 1)).ravel(), opened_by=m.ActionChunk.FIRST)
    )
    probe.wait(lambda: max(abs(v) for v in probe.states[-1].dq) > 0.2, 5, "the arm moving")


@pytest.mark.parametrize("case", list(MALFORMED))
def test_a_malformed_unsigned_estop_stops_the_arm_within_two_periods(driven, case):
    probe, session, release, stranger, period = driven
    try:
        _moving(probe, session)
        stranger.session.put(stranger.key(m.CONTROL), MALFORMED[case])
        t_sent = time.monotonic()
        probe.wait(lambda: probe.states[-1].mode == m.RobotState.ESTOP, 2 * period + 0.5, "the e-stop")
        time.sleep(max(0.0, t_sent + 2 * period - time.monotonic()))
        # A newer tick, not a longer list: ``probe.states`` keeps the newest 50 only (full after 2.5 s).
        last = probe.states[-1].tick
        probe.wait(lambda: probe.states[-1].tick > last, 2, "a state after two periods")
        settled = probe.states[-1]
        assert settled.mode == m.RobotState.ESTOP
        assert max(abs(v) for v in settled.dq) < 0.01, f"{case}: joints still at {max(np.abs(settled.dq))}"
    finally:
        release.put(m.Control(command=m.Control.RELEASE, jog=[0.0, 0.0, 0.0]))  # signed: obeyed
        probe.wait(lambda: probe.states[-1].mode != m.RobotState.ESTOP, 3, "the release")


def test_bytes_that_are_no_estop_do_not_stop_the_arm(driven):
    """The lenient e-stop path reads a stop request, not any garbage: a truncated pause is refused."""
    probe, session, _, stranger, period = driven
    _moving(probe, session)
    pause = m.Control(command=m.Control.PAUSE).SerializeToString()
    stranger.session.put(stranger.key(m.CONTROL), pause + b"\xff")
    time.sleep(5 * period)
    assert probe.states[-1].mode == m.RobotState.RUNNING
