"""The multi-machine setup on loopback: two ``adaptiveh router`` processes on different ports, robot-io
and the learner connected to different routers as clients, complete a short learning run through them;
and a router killed and restarted mid-run does not end it."""

import subprocess
import sys
import time

import numpy as np
import yaml
from bus_probe import BusProbe
from loopback import free_endpoint, unique_name
from stack_helpers import learn_one_episode

from bus import messages as m
from bus.transport import Bus, open_session, wait_listening
from deploy.config import compose_stack_yaml, load_stack_config


def test_two_routers_carry_a_run(tmp_path):
    e1, e2 = free_endpoint(), free_endpoint()
    r1 = subprocess.Popen([sys.executable, "-m", "deploy.cli", "router", "--listen", e1])
    wait_listening(e1)
    r2 = subprocess.Popen([sys.executable, "-m", "deploy.cli", "router", "--listen", e2, "--connect", e1])
    wait_listening(e2)  # a client exits when it cannot connect, so both must be up before the parts start
    cfg = compose_stack_yaml("configs/sim.yaml")
    cfg["name"] = unique_name("rt")
    cfg.pop("vision")
    cfg["learner"].update(
        steps=60, target_topic="sim/target_truth", checkpoint_dir=str(tmp_path / "l"), execution="closed_loop"
    )  # a learner on another machine driving the arm through the routers
    robot_cfg, learner_cfg = tmp_path / "robot.yaml", tmp_path / "learner.yaml"
    robot_cfg.write_text(yaml.safe_dump({**cfg, "zenoh": {"mode": "client", "connect": [e1]}}))
    learner_cfg.write_text(yaml.safe_dump({**cfg, "zenoh": {"mode": "client", "connect": [e2]}}))
    robot = subprocess.Popen([sys.executable, "-m", "deploy.cli", "robot-io", "--config", str(robot_cfg)])
    try:
        res = learn_one_episode(learner_cfg, tmp_path / "l")
        assert res["chunk_preemptions"] > 0  # the robot's chunk reports came back through both routers
    finally:
        for p in (robot, r2, r1):
            p.terminate()
            p.wait(timeout=15)


def test_a_restarted_router_the_arm_holds_and_the_run_resumes(tmp_path):
    """The multi-machine setup's router is SIGKILLed mid-run and started again on its endpoint: the parts
    (Zenoh clients) reconnect by themselves, the arm did not move while they were cut off, and learning
    resumes with the same processes."""
    endpoint = free_endpoint()
    router = lambda: subprocess.Popen(  # noqa: E731
        [sys.executable, "-m", "deploy.cli", "router", "--listen", endpoint], stdout=subprocess.DEVNULL
    )
    first = router()
    wait_listening(endpoint)  # the parts must find it at start (a client exits when it cannot connect)
    cfg = compose_stack_yaml("configs/sim.yaml")
    cfg["name"] = unique_name("rr")
    cfg.pop("vision")
    cfg["zenoh"] = {"mode": "client", "connect": [endpoint]}
    cfg["learner"].update(
        steps=100000,
        target_topic="sim/target_truth",
        checkpoint_dir=str(tmp_path / "l"),
        execution="closed_loop",
    )
    path = tmp_path / "c.yaml"
    path.write_text(yaml.safe_dump(cfg))
    parts = [
        subprocess.Popen([sys.executable, "-m", "deploy.cli", part, "--config", str(path)])
        for part in ("robot-io", "learn")
    ]
    second = None
    try:
        stack = load_stack_config(path)
        probe = BusProbe(Bus(open_session(stack.zenoh), stack.name))
        states, telemetry = probe.collect(m.STATE), probe.collect(m.TELEMETRY_LEARNER)
        probe.wait(lambda: any(t.global_step >= 60 for _, t in telemetry), 120, "the learner stepping")
        with probe.lock:
            before = states[-1][1]
        first.kill()
        first.wait(timeout=10)
        time.sleep(3.0)  # cut off: robot-io loses the learner (liveliness) and its commands
        t_back = time.time()
        second = router()
        probe.wait(lambda: any(at > t_back for at, _ in states), 60, "robot states through the new router")
        with probe.lock:
            after = next(s for at, s in states if at > t_back)
        # At most the tick in progress at the cut played (a chunk's tail is zeros: plan hold).
        moved = float(np.linalg.norm(np.subtract(after.ee_pos, before.ee_pos)))
        assert moved <= 2 * cfg["robot"]["max_step_m"] + 0.01, moved
        step = max(t.global_step for _, t in telemetry)
        probe.wait(lambda: any(t.global_step >= step + 40 for _, t in telemetry), 90, "learning resumed")
        assert all(p.poll() is None for p in parts), "a part ended when the router went"
        probe.bus.close()
    finally:
        for p in (*parts, second, first):
            if p is not None and p.poll() is None:
                p.terminate()
                try:
                    p.wait(timeout=15)
                except subprocess.TimeoutExpired:
                    p.kill()
