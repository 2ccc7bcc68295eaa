"""NS Reach as the deployed robot sees it: a gymnasium env whose physics is on the far side of Zenoh.

``reset`` asks the robot's ``reset`` queryable; ``step(a)`` publishes an ``ActionChunk`` whose first
action is ``a`` and waits for the first ``state`` after the robot executed it, so each ``step`` is one
control period with exactly ``a`` applied (gymnasium semantics: TD3/DDPG run on it unchanged).

Chunks are a receding horizon: the tail after ``a`` is a plan (``planner(obs, a, n)``, by default zero
displacements = stay put) that the robot keeps playing if the learner is late, and the next step's chunk
(higher ``seq``) preempts it; the robot reports the dropped count. Each step's chunk is a ``Plan`` sent
through the same channel as the actor's plans (below): its segment and why it began come from the learner
node (``open_segment``), so a retreat shows as the first chunk of a new segment preempting the old
segment's plan, in robot-io's own status of that chunk, and the step is acknowledged as the actor's
ticks are: by the robot tick whose state names the chunk's first action as the one it played.
Observation: ee position/velocity (from ``state``) and target position/velocity (from vision's
``target``, or ``sim/target_truth`` when configured), the same 15 values as in-process ``NSReach-v0``
(the reach task's observation is shared).

The actor's plan channel (``deploy.actor_node``, ``learner.plans.PlanChannel``): ``send(plan)``
publishes one chunk with the plan's actions, its predicted end-effector path and its segment, at once
(the learner's latency delays the actor's policy snapshots, never its plans); ``advance()`` returns the
robot's next
control tick as an executed step, from the ``state`` stream, which names the tick and the chunk action
it played: every tick once, in order, a tick with nothing queued as a hold (plan -1, zero action);
ticks while the operator has the arm e-stopped or paused are not steps of the task and are passed over.
``dropped_planned`` counts planned actions a newer plan preempted, as the robot reports them.
"""

from __future__ import annotations

import logging
import threading
import time
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any, Literal

import gymnasium as gym
import numpy as np

from bus import messages as m
from bus.learner_session import REFUSALS, LearnerSession
from bus.transport import Bus
from common.errors import AdaptiveHError
from deploy.config import StackConfig
from deploy.plan_channel import PlanBook, played
from learner.plans import Executed, Plan
from learner.segments import Opening, opening
from robot_io.step_cap import cap_step_length
from tasks.reach import (
    TRACKING,
    ArmTracking,
    predict_reach,
    reach_distance,
    reach_observation,
    reach_observation_bounds,
    reach_reward,
    reach_success,
    reach_task_record,
)

log = logging.getLogger(__name__)
NO_PREDICTION = np.zeros((0, 0))  # a closed-loop chunk carries no predicted path
SUSPENDED = ("estop", "paused", "fault")  # robot modes in which a tick is not a step of the task
WHY_REFUSED = {
    "foreign": "another learner session has the arm",
    "forged": "our signature is not robot-io's: is the learner's operator token the stack's?",
}
MAX_REFUSED_IN_A_ROW = 64  # more than a forgery inside robot.max_chunk_seq_gap can cost: not a glitch
MAX_SIGNED_REFUSED = 3  # signed chunks that timed out refused while the arm runs: a wrong token


class EnvStopped(AdaptiveHError, RuntimeError):
    """The node is shutting down while ``step`` waited for a held robot."""


class TakenOver(AdaptiveHError, RuntimeError):
    """robot-io obeys another learner session now: this one's chunks are refused as foreign."""


Planner = Callable[[np.ndarray, np.ndarray, int], np.ndarray]


@dataclass(frozen=True)
class EnvSettings:
    """What the env needs to know about the robot and the task: :func:`env_settings` fills it from the
    stack config's ``robot:`` and ``learner:`` sections (no defaults copied here)."""

    workspace_lo: tuple[float, ...]
    workspace_hi: tuple[float, ...]
    max_step_m: float
    control_rate_hz: float
    max_episode_steps: int
    chunk_len: int
    target_topic: str  # a key of bus.messages.TOPICS
    target_lo: tuple[float, ...]
    target_hi: tuple[float, ...]
    target_speed_max: float
    step_timeout_s: float
    execution: Literal["closed_loop", "plan"]  # who steps the env: a learner's step(), or an actor's plans
    latency_ms: float  # closed loop: the learner's thinking time made real, a chunk goes out this late
    reset_timeout_s: float = 30.0
    target_timeout_s: float = 0.5
    robot_model: str = "panda"  # robot.model: the arm a checkpoint records (learner.provenance)
    tracking: ArmTracking = TRACKING  # robot.tracking: how the arm follows a step (the plan model's)


def env_settings(cfg: StackConfig) -> EnvSettings:
    """The reach env over Zenoh: the robot's workspace, step and rate, and the learner's task settings."""
    lc = cfg.learner
    return EnvSettings(
        workspace_lo=cfg.robot.workspace.lo,
        workspace_hi=cfg.robot.workspace.hi,
        max_step_m=cfg.robot.max_step_m,
        control_rate_hz=cfg.robot.control_rate_hz,
        max_episode_steps=lc.max_episode_steps,
        chunk_len=lc.chunk_len,
        target_topic=lc.target_topic,
        target_lo=lc.target_box[0],
        target_hi=lc.target_box[1],
        target_speed_max=lc.target_speed_max,
        step_timeout_s=lc.step_timeout_s,
        target_timeout_s=lc.target_timeout_s,
        execution="closed_loop" if lc.execution == "closed_loop" else "plan",  # actor: the actor's env plans
        latency_ms=lc.latency_ms if lc.execution == "closed_loop" else 0.0,  # actor: snapshots arrive late
        robot_model=cfg.robot.model,
        tracking=TRACKING if cfg.robot.tracking is None else ArmTracking(**cfg.robot.tracking.model_dump()),
    )


def _seen_at(target: m.Target | None) -> float:
    """When the target was observed: the camera frame's time, else the message's (ground truth)."""
    if target is None:
        return -np.inf
    return target.frame_stamp if target.frame_stamp > 0 else target.stamp


def target_at(target: m.Target, when: float, horizon_s: float) -> tuple[np.ndarray, float]:
    """(the target's position at time ``when``, its fix's age then): the fix moved on at its velocity.

    A state and a target are captured at different times (a camera frame is 50-250 ms older than the
    robot's state); the observation pairs the state with where the target is then, not where it was.
    The age used is at most ``horizon_s`` (the freshness limit: an older fix is not acted on at all)."""
    age = max(0.0, when - _seen_at(target))
    position = np.asarray(target.position, float) + np.asarray(target.velocity, float) * min(age, horizon_s)
    return position, age


def _usable(target: m.Target | None, when: float, limit_s: float) -> bool:
    """A fix not older than ``limit_s`` at time ``when`` (a state's stamp)."""
    return target is not None and when - _seen_at(target) <= limit_s


def _fixed_since(target: m.Target | None, stamp: float) -> bool:
    """A target fixed by a fresh detection (not a prediction) observed at or after ``stamp``."""
    return target is not None and target.status == m.Target.TRACKING and _seen_at(target) >= stamp


class ReachSpec(gym.Env):
    """The deployed reach task's spaces, state bounds and plan model, without a robot: what a learner
    that learns from an actor's stream (``learner.execution: actor``) needs to build its agent. It is
    never stepped; :class:`ZenohReachEnv` is the same task with the robot behind it."""

    metadata = {"render_modes": []}

    def __init__(self, settings: EnvSettings) -> None:
        self.settings = settings
        lo, hi = settings.workspace_lo, settings.workspace_hi
        low, high, self.obs_bounds = reach_observation_bounds(
            lo, hi, settings.target_lo, settings.target_hi, settings.target_speed_max
        )
        self.observation_space = gym.spaces.Box(low, high, dtype=np.float32)
        s = settings.max_step_m
        self.action_space = gym.spaces.Box(-s, s, shape=(3,), dtype=np.float32)
        self.period = 1.0 / settings.control_rate_hz
        self.workspace = (np.asarray(lo, float), np.asarray(hi, float))  # robot-io's box for the goal

    def task_record(self) -> tuple:
        """What a checkpoint of a policy learned here records (``learner.provenance``)."""
        return reach_task_record(self.settings.robot_model, "the stack (adaptiveh up)")

    def predict_next(self, obs: np.ndarray, action: np.ndarray) -> np.ndarray:
        """The plan model: the reach task's (``tasks.reach.predict_reach``) at the robot's control period."""
        s = self.settings
        return predict_reach(obs, action, self.period, s.max_step_m, s.tracking, self.workspace)

    def reset(self, *, seed: int | None = None, options: dict | None = None) -> tuple[np.ndarray, dict]:
        raise RuntimeError("ReachSpec has no robot: the actor beside the arm steps the task")

    def step(self, action: np.ndarray) -> tuple[np.ndarray, float, bool, bool, dict]:
        raise RuntimeError("ReachSpec has no robot: the actor beside the arm steps the task")


class ZenohReachEnv(ReachSpec):
    """The reach task over Zenoh. ``paused`` (set by the learner node) makes ``step`` wait."""

    def __init__(self, bus: Bus, settings: EnvSettings, planner: Planner | None = None) -> None:
        """A ``bus`` with the stack's key signs this learner's chunks (``bus.signing``)."""
        super().__init__(settings)
        self.bus = bus
        self.planner = planner
        self.segment = 0  # closed loop: the segment the next chunk belongs to (``open_segment``)
        self._opening = Opening.FIRST  # closed loop: why the next chunk's segment began, until it is sent
        self._cond = threading.Condition()
        self._state: m.RobotState | None = None
        self._state_count = 0
        self._target: m.Target | None = None
        self._target_lost = False
        self.target_waits = 0  # target outages waited out
        self.outage_ticks = 0  # an actor's: robot ticks passed over while the target was lost
        self.chunk_seq = -1  # the last chunk sent
        self.global_step = 0
        self._steps = 0
        self.stop = threading.Event()  # set by the node to abandon a step blocked on a held robot
        # The robot's ticks not yet read (an actor's: by ``advance``, with the target then known; closed
        # loop: since the last chunk went out, bounded while no step waits), and the plans sent.
        self.plan_mode = settings.execution == "plan"
        self._ticks: deque[tuple[m.RobotState, m.Target | None]] = deque(
            maxlen=None if self.plan_mode else 1024
        )
        self._buffered_tick = -1  # the newest tick buffered (a state between ticks repeats it)
        self._last_state: m.RobotState | None = None  # of the last tick ``advance`` returned
        self.suspended_ticks = 0
        self.book = PlanBook()
        # This learner's session: its chunks are numbered from 0 and obeyed once ``reset`` has taken over.
        self.session = LearnerSession(bus)
        self.refused: dict[str, int] = {}  # own chunks robot-io refused, by verdict
        self._plans_sent = 0  # closed loop: each step's chunk is plan number ``_plans_sent``
        self._taken_over_by = ""
        self._obeyed_since_tick: int | None = None  # the tick of our takeover (reset); None before it
        self._instance = ""  # the robot-io process whose states these are (RobotState.instance)
        self.robot_restarts = 0  # robot-io processes that replaced the one before (each ends an episode)
        self._restarted = False  # a new robot-io since the last step: the episode ends, a reset takes over
        self.target_topic = m.TOPICS[settings.target_topic]
        bus.subscribe(m.STATE, self._on_state)
        bus.subscribe(self.target_topic, self._on_target)
        bus.subscribe(m.CHUNK_STATUS, self._on_status)

    # -- Zenoh callbacks -----------------------------------------------------------------------------
    def _on_state(self, msg: m.RobotState) -> None:
        with self._cond:
            if msg.instance != self._instance:
                self._new_robot_io(msg.instance)
            self._state = msg
            self._state_count += 1
            since = self._obeyed_since_tick
            if since is not None and msg.tick > since and not self.session.mine(msg):
                self._taken_over_by = msg.session or "(none)"  # the arm obeys another session since ours
            if msg.tick > self._buffered_tick:
                self._buffered_tick = msg.tick
                self._ticks.append((msg, self._target))
            self._cond.notify_all()

    def _new_robot_io(self, instance: str) -> None:
        """A robot-io process that is not the one before (a restart): its ticks count from 0 and it obeys
        no session yet, so the tick bookkeeping starts over and the episode ends at the next step (the
        reset that follows takes the new process over). Caller holds the lock."""
        if self._instance:
            log.warning("robot-io restarted (%s after %s): ending the episode", instance, self._instance)
            self.robot_restarts += 1
            self._restarted = True
        self._instance = instance
        self._buffered_tick = -1
        self._obeyed_since_tick = None
        self._ticks.clear()

    def _consume_restart(self) -> bool:
        """Whether robot-io restarted since the last call (then this step ends the episode)."""
        with self._cond:
            restarted, self._restarted = self._restarted, False
        return restarted

    def _on_target(self, msg: m.Target) -> None:
        with self._cond:
            self._target_lost = not msg.valid
            if msg.valid:
                self._target = msg
            self._cond.notify_all()

    def _target_fresh(self) -> bool:
        """The newest target report is a valid fix observed within ``target_timeout_s``."""
        age = time.time() - _seen_at(self._target)
        return not self._target_lost and age <= self.settings.target_timeout_s

    def _await_target(self) -> None:
        """Block until the target is fresh again: a lost or stale target is never acted on (vision down,
        the target out of view). The wait is logged once per outage."""
        if self._wait(self._target_fresh, 0.0):
            return
        log.warning("target lost or stale on %s; waiting for a fresh fix", self.bus.key(self.target_topic))
        t0 = time.monotonic()
        while not self._wait(self._target_fresh, 1.0):
            pass
        self.target_waits += 1
        log.warning("target back after %.1f s", time.monotonic() - t0)

    def _on_status(self, msg: m.ChunkStatus) -> None:
        if not self.session.mine(msg):
            return  # another session's chunk (a stranger, or the learner before a restart)
        verdict = m.label(msg, "verdict")
        if verdict in REFUSALS:
            self._on_refused(msg, verdict)
            return
        self.book.on_status(msg)

    def _on_refused(self, msg: m.ChunkStatus, verdict: str) -> None:
        """robot-io refused our chunk: say so (once per kind, then every 100th), let a waiting step resend."""
        self.book.on_refused(msg)
        with self._cond:
            n = self.refused[verdict] = self.refused.get(verdict, 0) + 1
            self._cond.notify_all()
        if n == 1 or n % 100 == 0:
            log.warning(
                "robot-io refused our chunk %d as %s (%d so far): %s",
                msg.chunk_seq,
                verdict,
                n,
                WHY_REFUSED.get(verdict, "a forged or corrupted chunk number got in before ours; resending"),
            )

    # -- helpers -------------------------------------------------------------------------------------
    @property
    def robot_mode(self) -> str:
        return m.label(self._state, "mode") if self._state is not None else "unknown"

    @property
    def dropped_planned(self) -> int:
        """Planned actions that a newer plan preempted on the robot, total (the PlanChannel's count)."""
        return self.book.dropped_planned

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

    def _observe(
        self, state: m.RobotState | None = None, target: m.Target | None = None
    ) -> tuple[np.ndarray, float, dict[str, Any]]:
        """Observation, reward and info of ``state`` and ``target`` (default: the newest of each).

        The policy sees, and is rewarded by, the commanded TCP: what its action moves at once. A streamed
        arm reaches it a few periods later (franky-sim: 3-4), and a reward on the measured hand scored
        each action by the ones before it: learning drove the arm away from the target (docs/handoff.md).
        Distance and success are the measured hand's. On the mock the two are one (``ee_cmd = ee_pos``)."""
        with self._cond:
            state = self._state if state is None else state
            target = self._target if target is None else target
        assert state is not None and target is not None
        ee = np.asarray(state.ee_pos)
        position, age = target_at(target, state.stamp, self.settings.target_timeout_s)
        commanded = np.asarray(state.ee_cmd)
        obs = reach_observation(commanded, state.ee_vel, position, target.velocity)
        distance = reach_distance(ee, position)
        reward = reach_reward(reach_distance(commanded, position))
        info = {
            "distance": distance,
            "success": reach_success(distance),
            "global_step": self.global_step,
            "target_speed": float(np.linalg.norm(target.velocity)),
            "target_age_s": age,
            "dropped_total": self.book.dropped_planned,
            "tick": state.tick,  # the robot's control tick the observation is from
        }
        return obs, reward, info

    # -- gymnasium -----------------------------------------------------------------------------------
    def reset(self, *, seed: int | None = None, options: dict | None = None) -> tuple[np.ndarray, dict]:
        """Home pose via the ``reset`` queryable; a seed gives the (simulated) target a new motion."""
        gym.Env.reset(self, seed=seed)  # seeds np_random (ReachSpec.reset refuses: it has no robot)
        deadline = time.monotonic() + self.settings.reset_timeout_s
        while True:
            if self.stop.is_set():
                raise EnvStopped("stopped while resetting the robot")
            try:
                reply = self.session.reset(
                    seed if seed is not None else -1, timeout=min(10.0, self.settings.reset_timeout_s)
                )
                if reply.ok:
                    break
                err = reply.detail
            except (TimeoutError, m.MessageError) as exc:
                err = str(exc)
            if self.robot_mode in SUSPENDED:  # robot-io refuses to home an e-stopped, paused or faulted
                deadline = time.monotonic() + self.settings.reset_timeout_s  # arm: the operator decides
            if time.monotonic() > deadline:
                raise TimeoutError(f"robot reset failed: {err}")
            time.sleep(0.5)
        state = reply.state
        with self._cond:
            if state.instance != self._instance:
                self._new_robot_io(state.instance)
            self._restarted = False  # this reset took the robot-io that answered it over
            self._taken_over_by = ""  # the reset made this session the one the arm obeys
            self._obeyed_since_tick = state.tick
            if state.tick >= (self._state.tick if self._state is not None else -1):
                self._state = state
        # Only a target detected after the reset: a reset moves the (simulated) target, and the last
        # message from before it (or the tracker coasting on the old track) put 20-40 cm jumps inside
        # episodes (measured), which wrecked the critic.
        if not self._wait(lambda: _fixed_since(self._target, state.stamp), self.settings.reset_timeout_s):
            raise TimeoutError(f"no valid target on {self.bus.key(self.target_topic)} since the reset")
        with self._cond:
            # The episode starts at the newest tick (the arm held since the reset: nothing queued);
            # ``advance`` returns the ticks after it, each paired with a target from after the reset.
            self._ticks.clear()
            self._last_state = self._state
        self._steps = 0
        self._opening = Opening.FIRST
        obs, _, info = self._observe()
        return obs, info

    def open_segment(self, segment: int, segment_end: str) -> None:
        """Closed loop: the next chunk opens ``segment``, after the one before ended by ``segment_end``;
        the chunk says so, and robot-io's status of the chunk it preempts echoes it."""
        self.segment, self._opening = segment, opening(segment_end)

    def _chunk(self, obs: np.ndarray, action: np.ndarray) -> np.ndarray:
        n = self.settings.chunk_len - 1
        if n <= 0:
            return action[None, :]
        tail = np.zeros((n, 3)) if self.planner is None else np.asarray(self.planner(obs, action, n))
        return cap_step_length(np.vstack([action[None, :], tail.reshape(n, 3)]), self.settings.max_step_m)

    def step(self, action: np.ndarray) -> tuple[np.ndarray, float, bool, bool, dict]:
        action = np.clip(
            np.asarray(action, float).reshape(3), -self.settings.max_step_m, self.settings.max_step_m
        )
        self._await_target()
        obs_now, _, _ = self._observe()
        chunk = self._chunk(obs_now, action)
        if self.settings.latency_ms > 0:
            time.sleep(self.settings.latency_ms / 1000.0)  # thinking time; the last chunk's tail plays
        # Signed chunks (a stack token): only this learner can make a chunk robot-io accepts, and every one
        # has a fresh number, so a refusal naming ours is about a copy (a replay, an altered one): ignored
        # here, counted in ``refused``. Unsigned, a forged chunk can take our next number: resend at once.
        signed = self.bus.signing_key is not None
        refused_in_a_row = 0
        restarted = False
        while True:
            if self.stop.is_set():
                raise EnvStopped("stopped while waiting for the robot")
            if self._consume_restart():
                restarted = True  # the chunk went to a process that is gone: the episode ends here
                break
            self._check_taken_over()
            if refused_in_a_row > (MAX_SIGNED_REFUSED if signed else MAX_REFUSED_IN_A_ROW):
                raise RuntimeError(f"robot-io refused {refused_in_a_row} chunks in a row: {self.refused}")
            plan = Plan(
                self._plans_sent, chunk, chunk, NO_PREDICTION, segment=self.segment, opened_by=self._opening
            )
            self._plans_sent += 1
            with self._cond:
                self._ticks.clear()  # only a tick after the chunk went out can have played it
                tick0 = self._state.tick if self._state is not None else -1
            seq = self._publish_plan(plan)
            outcome = self._await_played(plan.plan_id, seq, signed)
            if outcome == "played":
                break
            if outcome == "refused":
                refused_in_a_row += 1
                continue  # stale or a jump (a forged number got in first): resend with the next one
            if signed and self.robot_mode == "running" and self.book.refused(seq):
                refused_in_a_row += 1  # not played in time, and refused: e.g. a token that is not robot-io's
            # Not played: the arm is held (the watchdog after a stall of ours, a lost peer), e-stopped or
            # paused, the chunk was cut before it played, or another session took over (checked before
            # the resend). A watchdog hold lifts only with a fresh chunk, so a held arm gets one per
            # step timeout (refused harmlessly while another hold lasts); an e-stop, a pause or a fault
            # waits for the operator.
            while not self._wait(lambda: self.robot_mode not in SUSPENDED or self.stop.is_set(), 0.5):
                pass
            # At most one resend per tick: a "held" verdict comes before the state that shows the hold.
            self._wait(lambda t=tick0: self._state is not None and self._state.tick > t, 2 * self.period)
        self._opening = Opening.CONTINUE  # played: the segment's later chunks continue it
        self._steps += 1
        self.global_step += 1
        obs, reward, info = self._observe()
        truncated = self._steps >= self.settings.max_episode_steps or restarted
        return obs, reward, False, truncated, info

    def _await_played(self, plan_id: int, seq: int, signed: bool) -> str:
        """How the step's chunk ``seq`` fared within the step timeout: "played" when a tick played its
        first action (the tick's own report, read by ``played`` as ``advance`` reads it; the ticks it
        passes are the last chunk's tail), "refused" when robot-io refused it unsigned (signed, a refusal
        naming it is about a copy: see ``step``), "" for neither (held, suspended, taken over)."""
        deadline = time.monotonic() + self.settings.step_timeout_s
        refused = lambda: not signed and self.book.refused(seq)  # noqa: E731
        news = lambda: bool(self._ticks) or refused() or bool(self._taken_over_by)  # noqa: E731
        while self._wait(news, max(deadline - time.monotonic(), 0.0)):
            with self._cond:
                ticks = list(self._ticks)
                self._ticks.clear()
            if any(played(state, self.book, self.session.id)[0] == plan_id for state, _ in ticks):
                return "played"
            if self._taken_over_by:
                return ""
            if refused():
                return "refused"
        return ""

    def _check_taken_over(self) -> None:
        """Raise ``TakenOver`` when robot-io obeys another session: a learner never fights another one
        for the arm behind the operator's back (its supervisor decides whether to start it again)."""
        with self._cond:
            other = self._taken_over_by
        if other:
            raise TakenOver(
                f"robot-io obeys learner session {other[:16]!r}, not ours ({self.session.id}); stopping"
            )

    # -- plan channel (learner.plans.PlanChannel) ----------------------------------------------------
    def send(self, plan: Plan) -> None:
        """Publish ``plan`` as one chunk; never blocks."""
        self._publish_plan(plan)

    def _publish_plan(self, plan: Plan) -> int:
        actions = cap_step_length(np.reshape(plan.actions, (-1, 3)), self.settings.max_step_m)
        predicted = np.asarray(plan.predicted, float)[1 : len(actions) + 1, 0:3]
        msg = m.ActionChunk(
            actions=actions.ravel().tolist(),
            segment=plan.segment,
            predicted_ee=predicted.ravel().tolist(),
            opened_by=m.enum(m.ActionChunk, "opened_by", plan.opened_by),
        )
        self.chunk_seq = self.book.send(lambda: self.session.send(msg), plan, actions)
        return self.chunk_seq

    def _hold_for_target(self) -> None:
        """The target lost or stale: a plan made for a target we cannot see must not play on. A
        one-action plan that stays put preempts it (robot-io's watchdog then holds the arm), the actor
        waits for a fresh fix, and the ticks of the outage are passed over: nothing is learned from them
        (the next tick closes the segment)."""
        obs, _, _ = self._observe()
        stay = np.zeros((1, 3))
        newest = self.book.newest()
        segment = newest.plan.segment if newest is not None else 0
        here = np.stack([obs, obs])
        self._publish_plan(Plan(-1, stay, stay, here, segment=segment, opened_by=Opening.TARGET_LOST))
        self._await_target()
        with self._cond:
            self.outage_ticks += len(self._ticks)
            self._ticks.clear()

    def _next_tick(self) -> tuple[m.RobotState, m.Target | None]:
        """The oldest tick not yet returned, waiting for it; ticks while suspended are passed over."""
        while True:
            if not self._wait(lambda: bool(self._ticks), self.settings.step_timeout_s):
                log.warning("no robot state for %.1f s; waiting for robot-io", self.settings.step_timeout_s)
                continue
            with self._cond:
                state, target = self._ticks.popleft()
            if m.label(state, "mode") in SUSPENDED:
                self.suspended_ticks += 1
                continue
            return state, target

    def backlog(self) -> int:
        """Ticks that played and are not yet returned by ``advance`` (more than none: this side lags)."""
        with self._cond:
            return len(self._ticks)

    def advance(self) -> Executed:
        """The robot's next control tick as an executed step (see the module docstring)."""
        self._check_taken_over()
        while True:
            if not self._wait(self._target_fresh, 0.0):
                self._hold_for_target()
            state, target = self._next_tick()
            if _usable(target, state.stamp, self.settings.target_timeout_s):
                break
            self.outage_ticks += 1  # paired with a fix that went stale between the check and the tick
        restarted = self._consume_restart()  # this tick is the new robot-io's: the episode ends with it
        with self._cond:
            self._last_state = state
        plan_id, index, action = played(state, self.book, self.session.id)
        self._steps += 1
        self.global_step += 1
        obs, reward, info = self._observe(state, target)
        info.update(tick=state.tick, played_chunk=state.played_chunk, mode=m.label(state, "mode"))
        truncated = self._steps >= self.settings.max_episode_steps or restarted
        return Executed(plan_id, index, action, obs, reward, False, truncated, info, state.tick)
