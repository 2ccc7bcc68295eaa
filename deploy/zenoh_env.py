"""NS Reach as the deployed robot sees it: a gymnasium env whose physics is on the far side of Zenoh.

``reset`` asks the robot's ``reset`` queryable; ``step(a)`` publishes an ``ActionChunk`` whose first
action is ``a`` and waits for the first ``state`` after the robot executed it, so each ``step`` is one
control period with exactly ``a`` applied (gymnasium semantics: TD3/DDPG run on it unchanged).

Chunks are a receding horizon: the tail after ``a`` is a plan (``planner(obs, a, n)``, by default zero
displacements = stay put) that the robot keeps playing if the learner is late, and the next step's chunk
(higher ``seq``) preempts it; the robot reports the dropped count. The learner node marks chunks
with their segment index, so a retreat shows as the first chunk of a new segment preempting the old
segment's plan. Observation: ee position/velocity (from ``state``) and target position/velocity (from
vision's ``target``, or ``sim/target_truth`` when configured), the same 15 values as in-process
``NSReach-v0`` (the reach task's observation is shared).
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
from tasks.reach import (
    reach_distance,
    reach_observation,
    reach_observation_bounds,
    reach_reward,
    reach_success,
)


class EnvStopped(RuntimeError):
    """The node is shutting down while ``step`` waited for a held robot."""


Planner = Callable[[np.ndarray, np.ndarray, int], np.ndarray]


@dataclass(frozen=True)
class EnvSettings:
    """What the env needs to know about the robot and the task: ``deploy.learner_node.env_settings``
    fills it from the stack config's ``robot:`` and ``learner:`` sections (no defaults copied here)."""

    workspace_lo: tuple[float, ...]
    workspace_hi: tuple[float, ...]
    max_step_m: float
    control_rate_hz: float
    max_episode_steps: int
    chunk_len: int
    target_topic: str  # a key of deploy.messages.TOPICS
    target_lo: tuple[float, ...]
    target_hi: tuple[float, ...]
    target_speed_max: float
    step_timeout_s: float
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
    return target is not None and target.status == m.Target.TRACKING and _seen_at(target) >= stamp


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
        self.chunk_seq = 0  # the last chunk sent
        self.global_step = 0
        self._steps = 0
        self.dropped_total = 0
        self.preemptions = 0
        # Chunk numbers start from the wall clock so a restarted learner's chunks are newer than the last
        # run's (robot-io refuses older ones).
        first = int(time.time() * 1000) % 1_000_000_000
        self._pub_chunk = bus.publisher(m.CMD_CHUNK, first_seq=first)
        self.target_topic = m.TOPICS[settings.target_topic]
        bus.subscribe(m.STATE, self._on_state)
        bus.subscribe(self.target_topic, self._on_target)
        bus.subscribe(m.CHUNK_STATUS, self._on_status)
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
        return m.label(self._state, "mode") if self._state is not None else "unknown"

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
        distance = reach_distance(ee, target.position)
        info = {
            "distance": distance,
            "success": reach_success(distance),
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
        state = reply.state
        with self._cond:
            self._state = state
        # Only a target detected after the reset: a reset moves the (simulated) target, and the last
        # message from before it (or the tracker coasting on the old track) put 20-40 cm jumps inside
        # episodes (measured), which wrecked the critic.
        if not self._wait(lambda: _fixed_since(self._target, state.stamp), self.settings.reset_timeout_s):
            raise TimeoutError(
                f"no valid target on {self.bus.key(self.target_topic)} since the reset"
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
            seq = self._pub_chunk(m.ActionChunk(actions=chunk.ravel().tolist(), segment=self.segment))
            self.chunk_seq = seq
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
        return obs, reach_reward(distance), False, truncated, info
