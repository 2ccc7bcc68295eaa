"""Helpers for the tests that start the whole stack (imported by name: tests/ is not a package)."""

from __future__ import annotations

import json
import os
import subprocess
import sys
import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any

import pytest
import yaml
from loopback import free_endpoint, unique_name

from deploy.config import compose_stack_yaml
from deploy.part_env import TOKEN_ENV
from deploy.stack import PART_COMMANDS, running_parts

PARTS = tuple(PART_COMMANDS.values())  # what ``adaptiveh up`` runs on configs/sim.yaml
parts_of = running_parts  # pid of each running part of a config, by its command


def write_stack_config(
    directory: Path, prefix: str, vision_rate_hz: float | None = None, **learner: Any
) -> tuple[Path, dict]:
    """``configs/sim.yaml`` made private to one test: its own robot name and Zenoh hub port, the monitor on
    a free port, recording and checkpoints under ``directory``; ``learner`` overrides that section."""
    cfg = compose_stack_yaml("configs/sim.yaml")
    cfg["name"] = unique_name(prefix)
    cfg["zenoh"]["hub"] = free_endpoint()
    if vision_rate_hz is not None:
        cfg["vision"]["rate_hz"] = vision_rate_hz
    cfg["learner"].update({"checkpoint_dir": str(directory / "learner"), **learner})
    cfg["monitor"]["port"] = 0
    cfg["monitor"]["foxglove_port"] = 0  # the live Foxglove view on a free port too
    cfg["recording"]["dir"] = str(directory / "rec")
    path = directory / "c.yaml"
    path.write_text(yaml.safe_dump(cfg))
    return path, cfg


def write_fleet_config(directory: Path, prefix: str, arms: int = 2, **learner: Any) -> tuple[Path, dict]:
    """``configs/fleet.yaml`` made private to one test (as ``write_stack_config``): ``arms`` arms named
    arm0, arm1, ... with seeds 0, 1, ...; no monitor (the monitor's own tests cover its fleet view)."""
    cfg = compose_stack_yaml("configs/fleet.yaml")
    cfg["name"] = unique_name(prefix)
    cfg["zenoh"]["hub"] = free_endpoint()
    cfg["learner"].update({"checkpoint_dir": str(directory / "learner"), **learner})
    cfg["monitor"] = None
    cfg["recording"]["dir"] = str(directory / "rec")
    cfg["fleet"] = {"arms": [{"name": f"arm{i}", "seed": i} for i in range(arms)]}
    path = directory / "c.yaml"
    path.write_text(yaml.safe_dump(cfg))
    return path, cfg


def run_up(path: Path, *args: str, timeout: float = 400) -> dict:
    """``adaptiveh up`` on ``path`` to its end (extra ``args`` on its command line); its summary."""
    out = path.parent / "summary.json"
    proc = subprocess.run(
        [sys.executable, "-m", "deploy.cli", "up", str(path), "--summary", str(out), *args],
        capture_output=True,
        text=True,
        timeout=timeout,
    )
    assert proc.returncode == 0, proc.stdout[-3000:] + proc.stderr[-3000:]
    return json.loads(out.read_text())


def learn_one_episode(config: Path, checkpoint_dir: Path) -> dict:
    """Run ``adaptiveh learn`` for the config's 60 steps (one episode) and return its result.json."""
    learn = subprocess.run(
        [sys.executable, "-m", "deploy.cli", "learn", "--config", str(config), "--log-level", "WARNING"],
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert learn.returncode == 0, learn.stderr[-2000:]
    res = json.loads((checkpoint_dir / "result.json").read_text())
    assert res["global_step"] == 60 and len(res["episodes"]) == 1
    return res


@contextmanager
def running_part(
    part: str,
    cfg: dict,
    directory: Path,
    ready: Callable[[], Any],
    token: str = "",
    args: tuple[str, ...] = (),
) -> Iterator[subprocess.Popen]:
    """``adaptiveh <part>`` on ``cfg`` (written to ``directory``) as a subprocess until the block ends;
    ``token`` is the operator token it gets through its environment (as under ``adaptiveh up``); ``args``
    are the command's own options.

    ``ready()`` waits for the part to be up (a probe's ``wait``, raising AssertionError on time-out); if
    it never is, the test fails with the part's own output. The part is terminated (then killed) after.
    """
    path = directory / f"{part}.yaml"
    path.write_text(yaml.safe_dump(cfg))
    proc = subprocess.Popen(
        [sys.executable, "-m", "deploy.cli", part, "--config", str(path), "--log-level", "WARNING", *args],
        stdout=subprocess.PIPE,
        stderr=subprocess.STDOUT,
        text=True,
        env={**os.environ, **({TOKEN_ENV: token} if token else {})},
    )
    try:
        try:
            ready()
        except (AssertionError, TimeoutError):
            proc.kill()
            pytest.fail(f"{part} did not come up:\n{proc.communicate()[0]}")
        yield proc
    finally:
        proc.terminate()
        try:
            proc.wait(timeout=10)
        except subprocess.TimeoutExpired:
            proc.kill()


def assert_within_limits(states: list, robot: dict, tol_m: float = 0.01) -> None:
    """No state of ``states`` (RobotState, in arrival order) shows the arm outside its workspace box or
    joint limits, and no control tick that played an action moved it more than ``robot.max_step_m``
    (``tol_m``: PyBullet's tracking slack). Consecutive ticks are compared only within one robot-io
    process (its ``seq`` restarts with it), and a reset's jump home is not a played step."""
    import numpy as np

    from robot_io.config import RobotConfig
    from robot_io.description import RobotDescription
    from robot_io.kinematics import Kinematics

    lo, hi = np.array(robot["workspace"]["lo"]), np.array(robot["workspace"]["hi"])
    ee = np.array([s.ee_pos for s in states])
    assert np.all(ee >= lo - tol_m) and np.all(ee <= hi + tol_m), "a state outside the workspace box"
    limits = RobotDescription(robot.get("model", "panda")).limits
    q = np.array([s.q for s in states])
    assert np.all(q >= limits.lower - 1e-3) and np.all(q <= limits.upper + 1e-3), "outside the joint limits"
    # A reset homes the arm between two ticks, and the tick after it may already play the new episode's
    # first chunk: a tick that ends near home may be that jump, not a played step.
    cfg = RobotConfig.model_validate(robot)  # the home pose a reset goes to, defaults included
    home = Kinematics(RobotDescription(cfg.model)).ee_position(np.asarray(cfg.home_q, float))
    near_home = robot["max_step_m"] + tol_m
    moves = [
        float(np.linalg.norm(np.subtract(s.ee_pos, prev.ee_pos)))
        for prev, s in zip(states, states[1:], strict=False)
        if s.tick == prev.tick + 1
        and s.seq > prev.seq
        and s.played_chunk >= 0
        and np.linalg.norm(np.subtract(s.ee_pos, home)) > near_home
    ]
    assert moves and max(moves) <= robot["max_step_m"] + tol_m, f"a tick moved {max(moves or [0]):.3f} m"


def start_up(path: Path, timeout: float = 60.0) -> tuple[subprocess.Popen, str]:
    """``adaptiveh up <path>`` (stdout piped, stderr dropped) and its operator token, once every part of
    ``PARTS`` runs: a peer joining after that finds the supervisor holding the loopback hub."""
    up = subprocess.Popen(
        [sys.executable, "-m", "deploy.cli", "up", str(path)],
        stdout=subprocess.PIPE,
        stderr=subprocess.DEVNULL,
        text=True,
    )
    token = up.stdout.readline().strip().removeprefix("operator token: ")
    wait_for_parts(path, up, timeout)
    return up, token


def wait_for_parts(path: Path, up: subprocess.Popen, timeout: float = 60.0) -> dict[str, int]:
    """The pids of ``adaptiveh up``'s parts once all of ``PARTS`` run; the test fails (and ``up`` is
    killed) if they do not within ``timeout`` s or ``up`` ends."""
    deadline = time.monotonic() + timeout
    while set(parts_of(path)) != set(PARTS):
        if time.monotonic() > deadline or up.poll() is not None:
            up.kill()
            pytest.fail(f"adaptiveh up: parts up {sorted(parts_of(path))}, exit {up.poll()}")
        time.sleep(0.2)
    return parts_of(path)
