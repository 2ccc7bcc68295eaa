"""NS Reach as the deployed robot sees it: a gymnasium env whose physics is on the far side of Zenoh.

``reset`` asks the robot's ``reset`` queryable; ``step(a)`` publishes an ``ActionChunk`` whose first
action is ``a`` and waits for the first ``state`` after the robot executed it, so each ``step`` is one
control period with exactly ``a`` applied (gymnasium semantics: TD3/DDPG run on it unchanged).

Chunks are a receding horizon: the tail after ``a`` is a plan (``planner(obs, a, n)``, by default zero
displacements = stay put) that the robot keeps playing if the learner is late, and the next step's chunk
(higher ``chunk_seq``) preempts it; the robot reports the dropped count. The learner node marks chunks
with their segment index, so a retreat shows as the first chunk of a new segment preempting the old
segment's plan. Observation: ee position/velocity (from ``state``) and target position/velocity (from
vision's ``target``, or ``sim/target_truth`` when configured) — 12 values like ``sim.reach.NSReachEnv``.
"""

from __future__ import annotations

import threading
import time
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import gymnasium as gym
import numpy as np

from deploy import messages as m
from deploy.transport import Bus
from sim.reach import SUCCESS_M, reach_observation, reach_observation_bounds


class EnvStopped(RuntimeError):
    """The node is shutting down while ``step`` waited for a held robot."""


Planner = Callable[[np.ndarray, np.ndarray, int], np.ndarray]


@dataclass(frozen=True)
class EnvSettings:
    """What the env needs to know about the robot (from the ``robot:`` and ``learner:`` sections)."""

    workspace_lo: tuple[float, float, float] = (0.2, -0.45, 0.05)
    workspace_hi: tuple[float, float, float] = (0.8, 0.45, 0.7)
    max_step_m: float = 0.05
    control_rate_hz: float = 20.0
    max_episode_steps: int = 200
    chunk_len: int = 10
    target_topic: str = m.TARGET
    target_lo: tuple[float, float, float] = (0.35, -0.3, 0.12)
    target_hi: tuple[float, float, float] = (0.65, 0.3, 0.45)
    target_speed_max: float = 0.06
    step_timeout_s: float = 2.0
    reset_timeout_s: float = 30.0


def extrapolate(obs: np.ndarray, action: np.ndarray, dt: float) -> np.ndarray:
    """The observation one period after ``action``: the ee moves by it, the target keeps its velocity."""
    nxt = np.array(obs, dtype=float)
    nxt[0:3] = obs[0:3] + action
    nxt[3:6] = action / dt
    nxt[6:9] = obs[6:9] + obs[9:12] * dt
    nxt[12:15] = nxt[6:9] - nxt[0:3]
    return nxt


def _seen_at(target: m.Target | None) -> float:
    """When the target was observed: the camera frame's time, else the message's (ground truth)."""
    if target is None:
        return -np.inf
    return target.frame_stamp if target.frame_stamp > 0 else target.stamp


def _fixed_since(target: m.Target | None, stamp: float) -> bool:
    """A target fixed by a fresh detection (not a prediction) observed at or after ``stamp``."""
    return target is not None and target.status == "tracking" and _seen_at(target) >= stamp


class ZenohReachEnv(gym.Env):
    """The reach task over Zenoh. ``paused`` (set by the learner node) makes ``step`` wait."""

    metadata = {"render_modes": []}

    def __init__(self, bus: Bus, settings: EnvSettings, planner: Planner | None = None) -> None:
        self.bus = bus
        self.settings = settings
        self.planner = planner
        self.segment = 0
        lo, hi = settings.workspace_lo, settings.workspace_hi
        low, high, self.obs_bounds = reach_observation_bounds(
            lo, hi, settings.target_lo, settings.target_hi, settings.target_speed_max
        )
        self.observation_space = gym.spaces.Box(low, high, dtype=np.float32)
        s = settings.max_step_m
        self.action_space = gym.spaces.Box(-s, s, shape=(3,), dtype=np.float32)
        self._cond = threading.Condition()
        self._state: m.RobotState | None = None
        self._state_count = 0
        self._target: m.Target | None = None
        self.chunk_seq = int(time.time() * 1000) % 1_000_000_000  # newer than a previous run's chunks
        self.global_step = 0
        self._steps = 0
        self.dropped_total = 0
        self.preemptions = 0
        self.chunk_first: dict[int, int] = {}  # chunk_seq -> segment, for the node's accounting
        self._pub_chunk = bus.publisher(m.CMD_CHUNK)
        bus.subscribe(m.STATE, m.RobotState, self._on_state)
        bus.subscribe(settings.target_topic, m.Target, self._on_target)
        bus.subscribe(m.CHUNK_STATUS, m.ChunkStatus, self._on_status)
        self.on_status: Callable[[m.ChunkStatus], None] | None = None
        self.stop = threading.Event()  # set by the node to abandon a step blocked on a held robot

    # -- Zenoh callbacks -----------------------------------------------------------------------------
    def _on_state(self, msg: m.RobotState) -> None:
        with self._cond:
            self._state = msg
            self._state_count += 1
            self._cond.notify_all()

    def _on_target(self, msg: m.Target) -> None:
        if msg.valid:
            with self._cond:
                self._target = msg

    def _on_status(self, msg: m.ChunkStatus) -> None:
        if msg.preempted_by >= 0 and msg.dropped:
            self.dropped_total += msg.dropped
            self.preemptions += 1
        if self.on_status is not None:
            self.on_status(msg)

    # -- helpers -------------------------------------------------------------------------------------
    @property
    def robot_mode(self) -> str:
        return self._state.mode if self._state is not None else "unknown"

    def _wait(self, pred: Callable[[], bool], timeout: float) -> bool:
        """Wait for ``pred`` up to ``timeout``; ``EnvStopped`` as soon as the node is stopping."""
        deadline = time.monotonic() + timeout
        with self._cond:
            while True:
                if self.stop.is_set():
                    raise EnvStopped("stopped while waiting for the robot")
                left = deadline - time.monotonic()
                # Short slices: a stop request sets an Event, which does not wake this condition.
                if self._cond.wait_for(pred, min(max(left, 0.0), 0.25)):
                    return True
                if left <= 0:
                    return False

    def _observe(self) -> tuple[np.ndarray, float, dict[str, Any]]:
        with self._cond:
            state, target = self._state, self._target
        assert state is not None and target is not None
        ee = np.asarray(state.ee_pos)
        obs = reach_observation(ee, state.ee_vel, target.position, target.velocity)
        distance = float(np.linalg.norm(ee - np.asarray(target.position)))
        info = {
            "distance": distance,
            "success": distance < SUCCESS_M,
            "global_step": self.global_step,
            "target_speed": float(np.linalg.norm(target.velocity)),
            "target_age_s": max(0.0, time.time() - target.stamp),
            "dropped_total": self.dropped_total,
        }
        return obs, distance, info

    # -- gymnasium -----------------------------------------------------------------------------------
    def reset(self, *, seed: int | None = None, options: dict | None = None) -> tuple[np.ndarray, dict]:
        """Home pose via the ``reset`` queryable; a seed gives the (simulated) target a new motion."""
        super().reset(seed=seed)
        deadline = time.monotonic() + self.settings.reset_timeout_s
        while True:
            if self.stop.is_set():
                raise EnvStopped("stopped while resetting the robot")
            try:
                reply = self.bus.query(
                    m.RESET,
                    m.ResetRequest(seed=seed if seed is not None else -1),
                    m.ResetReply,
                    timeout=min(10.0, self.settings.reset_timeout_s),
                )
                if reply.ok:
                    break
                err = reply.detail
            except (TimeoutError, m.MessageError) as exc:
                err = str(exc)
            if time.monotonic() > deadline:
                raise TimeoutError(f"robot reset failed: {err}")
            time.sleep(0.5)
        state = m.decode(reply.state, m.RobotState)
        with self._cond:
            self._state = state
        # Only a target detected after the reset: a reset moves the (simulated) target, and the last
        # message from before it (or the tracker coasting on the old track) put 20-40 cm jumps inside
        # episodes (measured), which wrecked the critic.
        if not self._wait(lambda: _fixed_since(self._target, state.stamp), self.settings.reset_timeout_s):
            raise TimeoutError(
                f"no valid target on {self.bus.key(self.settings.target_topic)} since the reset"
            )
        self._steps = 0
        obs, _, info = self._observe()
        return obs, info

    def _chunk(self, obs: np.ndarray, action: np.ndarray) -> np.ndarray:
        n = self.settings.chunk_len - 1
        if n <= 0:
            return action[None, :]
        tail = np.zeros((n, 3)) if self.planner is None else np.asarray(self.planner(obs, action, n))
        return np.vstack([action[None, :], tail.reshape(n, 3)])

    def step(self, action: np.ndarray) -> tuple[np.ndarray, float, bool, bool, dict]:
        action = np.clip(
            np.asarray(action, float).reshape(3), -self.settings.max_step_m, self.settings.max_step_m
        )
        obs_now, _, _ = self._observe()
        chunk = self._chunk(obs_now, action)
        while True:
            if self.stop.is_set():
                raise EnvStopped("stopped while waiting for the robot")
            self.chunk_seq += 1
            seq = self.chunk_seq
            self.chunk_first[seq] = self.segment
            if len(self.chunk_first) > 1000:
                self.chunk_first.pop(next(iter(self.chunk_first)))
            self._pub_chunk(
                m.ActionChunk(seq=seq, chunk_seq=seq, actions=chunk.ravel().tolist(), segment=self.segment)
            )
            n = len(chunk)

            def executed(seq: int = seq, n: int = n) -> bool:
                s = self._state
                return s is not None and (s.chunk_seq > seq or (s.chunk_seq == seq and s.queue_len < n))

            if self._wait(executed, self.settings.step_timeout_s):
                break
            # Not executed: the arm is held (e-stop, pause, lost peer). Wait until it runs, then resend.
            while not self._wait(lambda: self.robot_mode == "running" or self.stop.is_set(), 0.5):
                pass
            if self.stop.is_set():
                raise EnvStopped("stopped while waiting for the robot")
        self._steps += 1
        self.global_step += 1
        obs, distance, info = self._observe()
        truncated = self._steps >= self.settings.max_episode_steps
        return obs, -distance, False, truncated, info
