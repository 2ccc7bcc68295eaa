"""``adaptiveh up --check``: validates a config and names missing drivers without starting anything."""

import importlib.util
import subprocess
import sys
from pathlib import Path

import pytest
import yaml

from deploy.config import compose_stack_yaml
from robot_io.backends.realtime_host import realtime_kernel


def _check(path: str, *extra: str) -> subprocess.CompletedProcess:
    return subprocess.run(
        [sys.executable, "-m", "deploy.cli", "up", path, "--check", *extra],
        capture_output=True,
        text=True,
        timeout=120,
    )


def test_franka_check_names_model_driver_and_missing_drivers():
    out = _check("configs/franka_realsense.yaml")
    assert "robot model panda (panda.urdf" in out.stdout
    if importlib.util.find_spec("franky") is None:
        assert "MISSING driver franky" in out.stdout
    else:
        assert "driver franky-control" in out.stdout and "robot server version" in out.stdout
    assert ("MISSING driver pyrealsense2" in out.stdout) == (importlib.util.find_spec("pyrealsense2") is None)
    assert "nothing was started and nothing moved" in out.stdout
    assert "not contacted (add --probe-arm" in out.stdout  # a plain check never reaches out to the arm
    # The host, as franka_realsense.yaml (realtime: enforce) needs it: a kernel without PREEMPT_RT fails it
    assert "host SCHED_FIFO 99 for the 1 kHz loop" in out.stdout
    assert "host memory locking (franka.lock_memory)" in out.stdout
    if not realtime_kernel():
        assert "MISSING host real-time kernel" in out.stdout and out.returncode == 1


@pytest.mark.skipif(importlib.util.find_spec("franky_sim") is None, reason="franky-sim is not installed")
def test_franka_check_reads_the_arms_version_when_it_answers():
    from franka_simulators import FrankySimServer

    with FrankySimServer("127.0.0.1"):
        out = _check("configs/franka_sim.yaml", "--probe-arm")  # franky-sim on loopback
    assert out.returncode == 0, out.stdout
    assert "robot server version 10 (FR3), matches the installed franky" in out.stdout
    assert "model check: flange FK within" in out.stdout


def test_sim_check_passes_and_bad_config_is_named(tmp_path):
    assert _check("configs/sim.yaml").returncode == 0
    bad = tmp_path / "bad.yaml"
    bad.write_text(f"base: {Path('configs/sim.yaml').resolve()}\nlearner: {{algo: ppo}}\n")  # an overlay
    out = _check(str(bad))
    assert out.returncode == 1 and "learner" in out.stdout and "ppo" in out.stdout


def test_sim_camera_on_a_real_arm_is_refused(tmp_path):
    """The sim camera renders the simulated world robot-io publishes; on a real Franka there is none."""
    cfg = compose_stack_yaml("configs/franka_realsense.yaml")
    cfg["vision"]["camera"] = "sim"
    bad = tmp_path / "bad.yaml"
    bad.write_text(yaml.safe_dump(cfg))
    out = _check(str(bad))
    assert out.returncode == 1 and "this robot has none: use realsense" in out.stdout


@pytest.fixture(scope="module")
def reach_checkpoint(tmp_path_factory) -> Path:
    """A run folder holding AdaptiveH's checkpoint after 60 steps of in-process NS Reach."""
    from learner.adaptiveh import AdaptiveH
    from learner.config import AdaptiveHConfig
    from tasks.reach_env import NSReachEnv

    env = NSReachEnv(motion="slow", max_episode_steps=30)
    agent = AdaptiveH(env, AdaptiveHConfig(policy_budget=20, critic_budget=20), seed=0)
    agent.learn(60)
    run = tmp_path_factory.mktemp("reach")
    agent.save(run / "checkpoint.pkl")
    env.close()
    return run


def _fresh(config: str, tmp_path: Path, **learner) -> Path:
    """``config`` with its learner's checkpoint folder in ``tmp_path`` (nothing there to resume)."""
    path = tmp_path / "overlay.yaml"
    overlay = {
        "base": str(Path(config).resolve()),
        "learner": {"checkpoint_dir": str(tmp_path / "l"), **learner},
    }
    path.write_text(yaml.safe_dump(overlay))
    return path


def test_the_check_says_whether_the_learner_accepts_the_policy(reach_checkpoint, tmp_path):
    """``--check --policy-from``: the policy the learner would start from is checked as it will check it;
    the real arm's config accepts the simulator's policy (its scales are the simulator's)."""
    out = _check(
        str(_fresh("configs/franka_realsense.yaml", tmp_path)), "--policy-from", str(reach_checkpoint)
    )
    assert (
        f"policy {reach_checkpoint}: accepted (NSReach-v0 (in-process, PyBullet mock), 60 steps" in out.stdout
    )
    tight = _fresh("configs/franka_realsense.yaml", tmp_path, state_workspace=None, action_step_m=None)
    out = _check(str(tight), "--policy-from", str(reach_checkpoint))  # the arm's own scales
    assert "MISSING a policy the learner accepts" in out.stdout and "observation_low differs" in out.stdout
    out = _check(str(_fresh("configs/sim.yaml", tmp_path)), "--policy-from", str(tmp_path / "none"))
    assert out.returncode == 1 and "no checkpoint at" in out.stdout
