"""NS CartPole (continuous): the classic cart-pole whose gravity drifts on the global step clock.

Dynamics, constants and termination are gymnasium's CartPole-v1 (Euler integrator): gravity 9.8,
cart 1.0 kg, pole 0.1 kg, half-length 0.5 m, τ 0.02 s, fail at 12° or |x| > 2.4, +1 per step, 500-step
cap. The action in [-1, 1] scales a force of ``force_mag`` = 10 N (CartPole-v1's bang-bang force), so
a = ±1 reproduces the discrete env exactly. Gravity is visible in ``info["gravity"]`` only.
"""

from __future__ import annotations

import gymnasium as gym
import numpy as np

from sim.schedules import DriftConfig, DriftSchedule

G0 = 9.8
GRAVITY_PRESETS = {
    "stationary": DriftConfig(base=G0, low=G0, high=G0),
    # slow: one gravity cycle per 20k steps (~40 full episodes) between 0.6 g and 1.4 g.
    "slow": DriftConfig(
        base=G0, low=0.5 * G0, high=1.5 * G0, amplitude=0.4 * G0, period=20_000, walk_std=0.002
    ),
    # fast: a cycle per 2k steps, a noisier walk and a jump every 1k steps.
    "fast": DriftConfig(
        base=G0,
        low=0.5 * G0,
        high=1.5 * G0,
        amplitude=0.4 * G0,
        period=2_000,
        walk_std=0.01,
        jump_every=1_000,
        jump_size=0.1 * G0,
    ),
}


class NSCartPoleContinuous(gym.Env):
    metadata = {"render_modes": []}

    gravity_default = G0
    masscart = 1.0
    masspole = 0.1
    length = 0.5  # half the pole's length
    tau = 0.02
    theta_threshold = 12 * 2 * np.pi / 360
    x_threshold = 2.4
    max_steps = 500

    def __init__(
        self, preset: str = "slow", seed: int = 0, force_mag: float = 10.0, drift: DriftConfig | None = None
    ):
        if preset not in GRAVITY_PRESETS and drift is None:
            raise ValueError(f"unknown preset {preset!r}; choose one of {sorted(GRAVITY_PRESETS)}")
        if force_mag <= 0:
            raise ValueError(f"force_mag must be > 0, got {force_mag}")
        self.preset = preset
        self.force_mag = force_mag
        self.gravity_schedule = DriftSchedule(drift or GRAVITY_PRESETS[preset], seed)
        high = np.array([self.x_threshold * 2, np.inf, self.theta_threshold * 2, np.inf], dtype=np.float32)
        self.observation_space = gym.spaces.Box(-high, high, dtype=np.float32)
        self.action_space = gym.spaces.Box(-1.0, 1.0, (1,), dtype=np.float32)
        self.obs_bounds = (np.array([-2.4, -3.0, -0.21, -3.5]), np.array([2.4, 3.0, 0.21, 3.5]))
        self.state: np.ndarray | None = None
        self.steps = 0

    @property
    def gravity(self) -> float:
        return self.gravity_schedule.value

    def reset(self, *, seed: int | None = None, options: dict | None = None):
        super().reset(seed=seed)
        self.state = self.np_random.uniform(low=-0.05, high=0.05, size=(4,))
        self.steps = 0
        return self.state.astype(np.float32), {"gravity": self.gravity}

    def step(self, action):
        if self.state is None:
            raise RuntimeError("call reset() before step()")
        a = float(np.clip(np.asarray(action, dtype=float).reshape(-1)[0], -1.0, 1.0))
        self.state = self.dynamics(self.state, a * self.force_mag, self.gravity)
        self.gravity_schedule.advance()
        self.steps += 1
        x, _, theta, _ = self.state
        terminated = bool(abs(x) > self.x_threshold or abs(theta) > self.theta_threshold)
        truncated = self.steps >= self.max_steps and not terminated
        return self.state.astype(np.float32), 1.0, terminated, truncated, {"gravity": self.gravity}

    def predict_next(self, obs: np.ndarray, action: np.ndarray) -> np.ndarray:
        """The plan model: the nominal dynamics (default gravity), never the drift."""
        a = float(np.clip(np.asarray(action, float).reshape(-1)[0], -1.0, 1.0))
        return self.dynamics(np.asarray(obs, float), a * self.force_mag, self.gravity_default)

    def dynamics(self, state: np.ndarray, force: float, gravity: float) -> np.ndarray:
        x, x_dot, theta, theta_dot = state
        total_mass = self.masspole + self.masscart
        polemass_length = self.masspole * self.length
        cos, sin = np.cos(theta), np.sin(theta)
        temp = (force + polemass_length * theta_dot**2 * sin) / total_mass
        thetaacc = (gravity * sin - cos * temp) / (
            self.length * (4.0 / 3.0 - self.masspole * cos**2 / total_mass)
        )
        xacc = temp - polemass_length * thetaacc * cos / total_mass
        return np.array(
            [
                x + self.tau * x_dot,
                x_dot + self.tau * xacc,
                theta + self.tau * theta_dot,
                theta_dot + self.tau * thetaacc,
            ]
        )

    def get_state(self) -> dict:
        return {
            "state": None if self.state is None else self.state.copy(),
            "steps": self.steps,
            "schedule": self.gravity_schedule.get_state(),
            "np_random": self.np_random.bit_generator.state,
        }

    def set_state(self, state: dict) -> None:
        self.state, self.steps = state["state"], state["steps"]
        self.gravity_schedule.set_state(state["schedule"])
        self.np_random.bit_generator.state = state["np_random"]
