"""``adaptiveh up CONFIG --policy-from PATH``: the stack starts from a policy trained in-process.

The actor plays nothing before the learner's first snapshot (the handed-off policy), so the first plan's
first action is drawn from the loaded policy's mean at the state it was planned from; the summary names
the checkpoint. A checkpoint of another task is refused before any part starts.
"""

from __future__ import annotations

import json
import subprocess
import sys

import numpy as np
import pytest
from stack_helpers import run_up, write_stack_config

from bus import messages as m
from deploy.run_report import summary_table
from learner.adaptiveh import AdaptiveH
from learner.config import AdaptiveHConfig
from monitor import recording
from tasks.reach_env import NSReachEnv


@pytest.fixture(scope="module")
def reach_checkpoint(tmp_path_factory):
    """AdaptiveH after 400 steps of in-process NS Reach (with reach.yaml's kernel), and its checkpoint."""
    env = NSReachEnv(motion="slow", max_episode_steps=50)
    bandwidth = [5.0] * 12 + [0.3] * 3
    agent = AdaptiveH(env, AdaptiveHConfig(gamma=0.5, bandwidth=bandwidth, policy_budget=100), seed=1)
    agent.learn(400)
    path = tmp_path_factory.mktemp("source") / "checkpoint.pkl"
    agent.save(path)
    env.close()
    return path, agent


def first_planned_action(records: list) -> m.Transition:
    """The actor's first tick that played a planned action (noise drawn): the first plan's first action."""
    for topic, _, _, data in records:
        if topic.endswith("/" + m.TRANSITIONS.name):
            t = m.Transition.FromString(data)
            if np.any(np.asarray(t.noise) != 0):
                return t
    raise AssertionError("no planned action was played")


@pytest.mark.timeout(300)
def test_the_first_plan_comes_from_the_handed_off_policy(tmp_path, reach_checkpoint):
    source_path, source = reach_checkpoint
    path, _ = write_stack_config(tmp_path, "handoff", vision_rate_hz=10.0, steps=100)
    summary = run_up(path, "--policy-from", str(source_path), timeout=240)
    assert summary["started_from"]["path"] == str(source_path)
    assert summary["started_from"]["steps"] == 400 and summary["started_from"]["arm"] == "panda"
    assert f"policy started from            | {source_path}" in summary_table(summary)
    first = first_planned_action(recording.read(summary["recording"]))
    planned_mean = np.asarray(first.raw_action) - np.asarray(first.noise)
    loaded_mean = source.policy.mean(source.normalize(np.asarray(first.obs)))
    print("first planned action's mean", planned_mean, "the loaded policy's at its state", loaded_mean)
    assert np.linalg.norm(loaded_mean) > 0.005  # a trained policy moves (an empty one's mean is 0)
    np.testing.assert_allclose(planned_mean, loaded_mean, atol=1e-3)  # 1 mm: the plan began on time
    result = json.loads((tmp_path / "learner" / "result.json").read_text())
    assert result["global_step"] == 100 and result["started_from"]["path"] == str(source_path)


def test_a_checkpoint_of_another_task_is_refused_before_anything_starts(tmp_path):
    import gymnasium as gym

    import sim  # noqa: F401  (registers the NS envs)
    from learner.registry import make_agent

    env = gym.make("NSCartPoleContinuous-v0")
    agent = make_agent("adaptiveh", env, 0, {})
    agent.learn(20)
    agent.save(tmp_path / "cartpole.pkl")
    path, _ = write_stack_config(tmp_path, "refuse", steps=50)
    proc = subprocess.run(
        [
            sys.executable,
            "-m",
            "deploy.cli",
            "up",
            str(path),
            "--policy-from",
            str(tmp_path / "cartpole.pkl"),
        ],
        capture_output=True,
        text=True,
        timeout=60,
    )
    assert proc.returncode == 2, proc.stdout[-2000:] + proc.stderr[-2000:]
    assert "policy handoff refused: task differs" in proc.stderr + proc.stdout
    assert not (tmp_path / "learner").exists()  # no part ran
