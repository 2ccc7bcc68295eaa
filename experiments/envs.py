"""The one env factory of every in-process run: ``adaptiveh train`` and the paper and plans benches.

A seed is a world: only the first seeded ``reset`` keeps its seed. AdaptiveH reseeds every episode
(``reset(seed=k)``), SB3 only the first; on NS Reach a seeded reset also redraws the target's motion, so
passing every seed through would hand the algorithms different schedules, and ``adaptiveh train`` a
different world from the bench's at the same seed.
"""

from __future__ import annotations

from typing import Any

import gymnasium as gym

import tasks  # noqa: F401  (registers every environment, NS Reach included)


class SeedOnce(gym.Wrapper):
    """Passes a ``reset`` seed through until one has gone through (``seeded``); later seeds are dropped."""

    def __init__(self, env: gym.Env, seeded: bool = False) -> None:
        super().__init__(env)
        self.seeded = seeded

    def reset(self, *, seed: int | None = None, options: dict | None = None) -> Any:
        if self.seeded:
            seed = None
        self.seeded = self.seeded or seed is not None
        return self.env.reset(seed=seed, options=options)


def make_env(
    env_id: str, kwargs: dict[str, Any], reseed_episodes: bool = False, seeded: bool = False
) -> gym.Env:
    """``env_id`` built from ``kwargs`` in a :class:`SeedOnce`.

    ``seeded``: its world is already drawn (a resumed run, whose checkpoint restores the env's state).
    ``reseed_episodes``: every seeded reset draws a new world instead, as the stack's actor asks of the
    arm each episode (``deploy.actor_node``): the world of the stack bench's in-process reference.
    """
    env = gym.make(env_id, **kwargs)
    return env if reseed_episodes else SeedOnce(env, seeded)
