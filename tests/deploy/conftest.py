"""Deploy tests' shared parts: robot-io on a loopback hub, with the test as the learner."""

from __future__ import annotations

import secrets

import pytest
from bus_probe import BusProbe
from loopback import free_endpoint, unique_name
from stack_helpers import running_part

from bus import messages as m
from bus.transport import Bus, open_session, wait_listening
from deploy.config import StackConfig

RATE = 20.0


@pytest.fixture(scope="module")
def robot_hub(tmp_path_factory):
    """robot-io owning a loopback hub (so the test's sessions and a learner node reach each other through
    it), with an operator token as under ``adaptiveh up``: it obeys only chunks signed with it; yields
    (stack config for the learner's side, probe on the bus; ``probe.token`` is the token)."""
    hub = free_endpoint()
    cfg = {
        "name": unique_name("hub"),
        "zenoh": {"hub": hub},
        "robot": {"backend": "pybullet", "control_rate_hz": RATE, "target_motion": "slow"},
    }
    stack = StackConfig.model_validate({**cfg, "learner": {"target_topic": "sim/target_truth"}})
    joined: list[BusProbe] = []

    def up() -> None:
        wait_listening(hub)  # join only once robot-io holds the hub, or this session would take it
        probe = BusProbe(Bus(open_session(stack.zenoh), cfg["name"]))
        probe.states = probe.collect(m.STATE, arrival=False, maxlen=50)
        probe.status = probe.collect(m.CHUNK_STATUS, arrival=False)
        probe.bus.declare_alive("learner")  # robot-io watches the learner's token
        probe.token = token
        joined.append(probe)
        probe.wait(lambda: len(probe.states) > 3, 60, "robot states")

    token = secrets.token_urlsafe(12)
    with running_part("robot-io", cfg, tmp_path_factory.mktemp("hub"), up, token=token):
        yield stack, joined[0]
        joined[0].bus.close()
