"""Two ``adaptiveh router`` processes on different loopback ports; robot-io and the learner connect to
different routers as clients and a short learning run completes through them."""

import subprocess
import sys
import time

import yaml
from loopback import free_endpoint, unique_name
from stack_helpers import learn_one_episode


def test_two_routers_carry_a_run(tmp_path):
    e1, e2 = free_endpoint(), free_endpoint()
    r1 = subprocess.Popen([sys.executable, "-m", "deploy.cli", "router", "--listen", e1])
    time.sleep(1.0)
    r2 = subprocess.Popen([sys.executable, "-m", "deploy.cli", "router", "--listen", e2, "--connect", e1])
    cfg = yaml.safe_load(open("configs/sim.yaml"))
    cfg["name"] = unique_name("rt")
    cfg.pop("vision")
    cfg["learner"].update(steps=60, target_topic="sim/target_truth", checkpoint_dir=str(tmp_path / "l"))
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
