"""``adaptiveh train --config configs/<task>.yaml`` and the paper bench build one world for a seed (issue
#35): the same observations over the first episodes, each opened with a seeded reset as AdaptiveH opens
them. Reseeding every episode (the stack's world) is another world, so the comparison can tell."""

from __future__ import annotations

from pathlib import Path

import gymnasium as gym
import numpy as np
import pytest

from experiments.envs import make_env
from experiments.plan import build_plan
from experiments.training import load_spec
from experiments.training import make_env as train_env

CONFIGS = Path(__file__).resolve().parents[2] / "configs"
SEED = 3


def _observations(env: gym.Env, episodes: int = 3, steps: int = 15) -> np.ndarray:
    """``episodes`` episodes opened with ``reset(seed=SEED + k)``, ``steps`` fixed random actions each."""
    rng = np.random.default_rng(0)
    space = env.action_space
    out = []
    for k in range(episodes):
        obs, _ = env.reset(seed=SEED + k)
        out.append(obs)
        for _ in range(steps):
            obs, _, terminated, truncated, _ = env.step(
                rng.uniform(space.low, space.high).astype(space.dtype)
            )
            out.append(obs)
            if terminated or truncated:
                break
    env.close()
    return np.array(out)


@pytest.mark.parametrize(
    "config, setting",
    [("reach.yaml", "reach_slow"), ("cartpole.yaml", "cartpole_slow"), ("pendulum.yaml", "pendulum_slow")],
)
def test_train_and_the_bench_build_the_same_world_for_a_seed(config: str, setting: str) -> None:
    spec = load_spec(CONFIGS / config, {"seed": SEED})
    run = next(
        r for r in build_plan(seeds=SEED + 1, envs=[setting], algos=["adaptiveh"]).runs if r.seed == SEED
    )
    assert spec.env == run.env_spec.env_id
    trained = _observations(train_env(spec))
    benched = _observations(make_env(run.env_spec.env_id, run.env_kwargs))
    np.testing.assert_array_equal(trained, benched)
    reseeded = _observations(train_env(spec.model_copy(update={"reseed_episodes": True})))
    assert not np.array_equal(reseeded, benched)  # a seeded reset per episode would have been another world
