"""NS Pendulum (swing-up): the classic pendulum whose observation noise bound drifts.

Dynamics and reward are gymnasium's Pendulum-v1 (g 10, m 1, l 1, dt 0.05, max speed 8, max torque 2,
200 steps). The observation ``[cos θ, sin θ, θ̇]`` gets uniform noise in ``[-b, b]``; ``b`` follows a
drift schedule on the global clock (``info["noise_bound"]``). ``obs_delay`` > 0 returns the observation
from that many steps ago (the real-world latency of the paper's motivation).
"""

from __future__ import annotations

from collections import deque

import gymnasium as gym
import numpy as np

from sim.schedules import DriftConfig, DriftSchedule

NOISE_PRESETS = {
    "stationary": DriftConfig(base=0.0, low=0.0, high=0.0),
    "slow": DriftConfig(base=0.05, low=0.0, high=0.15, amplitude=0.05, period=20_000, walk_std=0.0005),
    "fast": DriftConfig(
        base=0.1,
        low=0.0,
        high=0.3,
        amplitude=0.1,
        period=2_000,
        walk_std=0.002,
        jump_every=1_000,
        jump_size=0.05,
    ),
}


def angle_normalize(x: float) -> float:
    return ((x + np.pi) % (2 * np.pi)) - np.pi


class NSPendulum(gym.Env):
    metadata = {"render_modes": []}

    g, m, length, dt = 10.0, 1.0, 1.0, 0.05
    max_speed, max_torque = 8.0, 2.0
    max_steps = 200

    def __init__(
        self, preset: str = "slow", seed: int = 0, obs_delay: int = 0, drift: DriftConfig | None = None
    ):
        if preset not in NOISE_PRESETS and drift is None:
            raise ValueError(f"unknown preset {preset!r}; choose one of {sorted(NOISE_PRESETS)}")
        if obs_delay < 0:
            raise ValueError(f"obs_delay must be >= 0, got {obs_delay}")
        self.preset = preset
        self.noise_schedule = DriftSchedule(drift or NOISE_PRESETS[preset], seed)
        self.obs_delay = obs_delay
        b = self.noise_schedule.config.high
        high = np.array([1.0 + b, 1.0 + b, self.max_speed + b], dtype=np.float32)
        self.observation_space = gym.spaces.Box(-high, high, dtype=np.float32)
        self.action_space = gym.spaces.Box(-self.max_torque, self.max_torque, (1,), dtype=np.float32)
        self.obs_bounds = (np.array([-1.0, -1.0, -8.0]), np.array([1.0, 1.0, 8.0]))
        self.state: np.ndarray | None = None
        self.steps = 0
        self._history: deque[np.ndarray] = deque(maxlen=obs_delay + 1)

    @classmethod
    def transition(
        cls, th: np.ndarray | float, thdot: np.ndarray | float, u: np.ndarray | float
    ) -> tuple[np.ndarray | float, np.ndarray | float, np.ndarray | float]:
        """(θ', θ̇', reward) of the true dynamics, on floats or arrays of states (``u`` inside the torque
        box): one source for the env, its plan model and the benches' batched rollouts."""
        cost = angle_normalize(th) ** 2 + 0.1 * thdot**2 + 0.001 * u**2
        accel = 3 * cls.g / (2 * cls.length) * np.sin(th) + 3.0 / (cls.m * cls.length**2) * u
        thdot = np.clip(thdot + accel * cls.dt, -cls.max_speed, cls.max_speed)
        return th + thdot * cls.dt, thdot, -cost

    @staticmethod
    def observation(th: np.ndarray | float, thdot: np.ndarray | float) -> np.ndarray:
        """The noise-free observation ``[cos θ, sin θ, θ̇]`` of a state (one row per state for arrays)."""
        return np.stack([np.cos(th), np.sin(th), thdot], -1)

    def _observe(self) -> np.ndarray:
        th, thdot = self.state
        clean = self.observation(th, thdot)
        b = self.noise_schedule.value
        noisy = clean + (self.np_random.uniform(-b, b, 3) if b > 0 else 0.0)
        self._history.append(noisy)
        return self._history[0].astype(np.float32)

    def _info(self) -> dict:
        return {"noise_bound": self.noise_schedule.value}

    def reset(self, *, seed: int | None = None, options: dict | None = None):
        super().reset(seed=seed)
        self.state = self.np_random.uniform(low=[-np.pi, -1.0], high=[np.pi, 1.0])
        self.steps = 0
        self._history.clear()
        return self._observe(), self._info()

    def predict_next(self, obs: np.ndarray, action: np.ndarray) -> np.ndarray:
        """The plan model: the nominal dynamics on the observed angle, no noise, no delay."""
        c, s, thdot = np.asarray(obs, float)
        th = np.arctan2(s, c)
        u = float(np.clip(np.asarray(action, dtype=float).reshape(-1)[0], -self.max_torque, self.max_torque))
        th, thdot, _ = self.transition(th, thdot, u)
        return self.observation(th, thdot)

    def step(self, action):
        if self.state is None:
            raise RuntimeError("call reset() before step()")
        u = float(np.clip(np.asarray(action, dtype=float).reshape(-1)[0], -self.max_torque, self.max_torque))
        th, thdot, reward = self.transition(*self.state, u)
        self.state = np.array([th, thdot])
        self.noise_schedule.advance()
        self.steps += 1
        truncated = self.steps >= self.max_steps
        return self._observe(), float(reward), False, truncated, self._info()

    def get_state(self) -> dict:
        return {
            "state": None if self.state is None else self.state.copy(),
            "steps": self.steps,
            "history": list(self._history),
            "schedule": self.noise_schedule.get_state(),
            "np_random": self.np_random.bit_generator.state,
        }

    def set_state(self, state: dict) -> None:
        self.state, self.steps = state["state"], state["steps"]
        self._history.clear()
        self._history.extend(state["history"])
        self.noise_schedule.set_state(state["schedule"])
        self.np_random.bit_generator.state = state["np_random"]
