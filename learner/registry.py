"""``make_agent``: one constructor for every algorithm the CLI and benchmarks run."""

from __future__ import annotations

from typing import TYPE_CHECKING, Any, Literal, get_args

from learner.protocol import Agent

if TYPE_CHECKING:  # configs import the Algo names; only building an agent needs gymnasium
    import gymnasium as gym

# The algorithms, in the paper's order (its tables and figures list them so); configs declare
# ``algo: Algo`` and everything else iterates ``ALGOS``.
Algo = Literal["adaptiveh", "td3", "ddpg", "rkhs", "sac", "ppo"]
ALGOS: tuple[str, ...] = get_args(Algo)


def make_agent(algo: str, env: gym.Env, seed: int = 0, config: dict[str, Any] | None = None) -> Agent:
    """Build ``algo`` on ``env``; ``config`` holds the algorithm's hyperparameters (validated)."""
    if algo in ("adaptiveh", "rkhs"):
        from learner.adaptiveh import AdaptiveH, RKHSFixedH
        from learner.config import AdaptiveHConfig

        cls = AdaptiveH if algo == "adaptiveh" else RKHSFixedH
        return cls(env, AdaptiveHConfig(**(config or {})), seed)
    if algo in ("td3", "ddpg", "sac", "ppo"):
        from learner.baselines import SB3Agent
        from learner.config import AGENT_CONFIGS

        return SB3Agent(algo, env, AGENT_CONFIGS[algo](**(config or {})), seed)
    raise ValueError(f"unknown algo {algo!r}; choose one of {ALGOS}")
