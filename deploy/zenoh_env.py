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
What the robot reports, the takeover and the book of plans sent are the env's ``link``
(``deploy.robot_link.RobotLink``); the env is the task on top of it.
"""

from __future__ import annotations

import logging
import time
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import gymnasium as gym
import numpy as np

from bus import messages as m
from bus.transport import Bus
from deploy.config import StackConfig
from deploy.plan_channel import played
from deploy.robot_link import SUSPENDED, LinkStopped, RobotLink, seen_at, usable
from learner.plans import Executed, Plan
from learner.segments import Execution, Opening, opening
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
MAX_REFUSED_IN_A_ROW = 64  # more than a forgery inside robot.max_chunk_seq_gap can cost: not a glitch
MAX_SIGNED_REFUSED = 3  # signed chunks that timed out refused while the arm runs: a wrong token


Planner = Callable[[np.ndarray, np.ndarray, int], np.ndarray]


@dataclass(frozen=True)
class EnvSettings:
    """What the env needs to know about the robot and the task: :func:`env_settings` fills it from the
    stack config's ``robot:`` and ``learner:`` sections (no defaults copied here)."""

    workspace_lo: tuple[float, ...]
    workspace_hi: tuple[float, ...]
    max_step_m: float  # robot-io's: what is sent is capped at it
    state_lo: tuple[float, ...]  # the policy's scales (learner.state_workspace, learner.action_step_m)
    state_hi: tuple[float, ...]
    action_step_m: float
    control_rate_hz: float
    max_episode_steps: int
    chunk_len: int
    target_topic: str  # a key of bus.messages.TOPICS
    target_lo: tuple[float, ...]
    target_hi: tuple[float, ...]
    target_speed_max: float
    step_timeout_s: float
    reads_every_tick: bool  # an actor reads every tick (``advance``); a learner's ``step`` the newest
    latency_ms: float  # closed loop: the learner's thinking time made real, a chunk goes out this late
    reset_timeout_s: float = 30.0
    target_timeout_s: float = 0.5
    robot_model: str = "panda"  # robot.model: the arm a checkpoint records (learner.provenance)
    tracking: ArmTracking = TRACKING  # robot.tracking: how the arm follows a step (the plan model's)


def env_settings(cfg: StackConfig) -> EnvSettings:
    """The reach env over Zenoh: the robot's workspace, step and rate, and the learner's task settings."""
    lc = cfg.learner
    scaled_box = lc.state_workspace or (cfg.robot.workspace.lo, cfg.robot.workspace.hi)
    return EnvSettings(
        workspace_lo=cfg.robot.workspace.lo,
        workspace_hi=cfg.robot.workspace.hi,
        max_step_m=cfg.robot.max_step_m,
        state_lo=scaled_box[0],
        state_hi=scaled_box[1],
        action_step_m=lc.action_step_m or cfg.robot.max_step_m,
        control_rate_hz=cfg.robot.control_rate_hz,
        max_episode_steps=lc.max_episode_steps,
        chunk_len=lc.chunk_len,
        target_topic=lc.target_topic,
        target_lo=lc.target_box[0],
        target_hi=lc.target_box[1],
        target_speed_max=lc.target_speed_max,
        step_timeout_s=lc.step_timeout_s,
        target_timeout_s=lc.target_timeout_s,
        reads_every_tick=lc.execution == Execution.ACTOR,
        # actor: the snapshots arrive late, not the chunks
        latency_ms=lc.latency_ms if lc.execution == Execution.CLOSED_LOOP else 0.0,
        robot_model=cfg.robot.model,
        tracking=TRACKING if cfg.robot.tracking is None else ArmTracking(**cfg.robot.tracking.model_dump()),
    )


def target_at(target: m.Target, when: float, horizon_s: float) -> tuple[np.ndarray, float]:
    """(the target's position at time ``when``, its fix's age then): the fix moved on at its velocity.

    A state and a target are captured at different times (a camera frame is 50-250 ms older than the
    robot's state); the observation pairs the state with where the target is then, not where it was.
    The age used is at most ``horizon_s`` (the freshness limit: an older fix is not acted on at all)."""
    age = max(0.0, when - seen_at(target))
    position = np.asarray(target.position, float) + np.asarray(target.velocity, float) * min(age, horizon_s)
    return position, age


class ReachSpec(gym.Env):
    """The deployed reach task's spaces, state bounds and plan model, without a robot: what a learner
    that learns from an actor's stream (``learner.execution: actor``) needs to build its agent. It is
    never stepped; :class:`ZenohReachEnv` is the same task with the robot behind it."""

    metadata = {"render_modes": []}

    def __init__(self, settings: EnvSettings) -> None:
        self.settings = settings
        low, high, self.obs_bounds = reach_observation_bounds(
            settings.state_lo,
            settings.state_hi,
            settings.target_lo,
            settings.target_hi,
            settings.target_speed_max,
        )
        self.observation_space = gym.spaces.Box(low, high, dtype=np.float32)
        s = settings.action_step_m
        self.action_space = gym.spaces.Box(-s, s, shape=(3,), dtype=np.float32)
        self.period = 1.0 / settings.control_rate_hz
        # robot-io's box for the goal
        self.workspace = (np.asarray(settings.workspace_lo, float), np.asarray(settings.workspace_hi, float))

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
    """The reach task over Zenoh, on a :class:`deploy.robot_link.RobotLink` to the robot."""

    def __init__(self, bus: Bus, settings: EnvSettings, planner: Planner | None = None) -> None:
        """A ``bus`` with the stack's key signs this learner's chunks (``bus.signing``)."""
        super().__init__(settings)
        self.bus = bus
        self.planner = planner
        # The robot's ticks not yet read: every one for an actor (``advance``, with the target then
        # known); closed loop, those since the last chunk went out, bounded while no step waits.
        keep = None if settings.reads_every_tick else 1024
        target_topic = m.TOPICS[settings.target_topic]
        self.link = RobotLink(bus, target_topic, settings.target_timeout_s, settings.max_step_m, keep)
        self.segment = 0  # closed loop: the segment the next chunk belongs to (``open_segment``)
        self._opening = Opening.FIRST  # closed loop: why the next chunk's segment began, until it is sent
        self._plans_sent = 0  # closed loop: each step's chunk is plan number ``_plans_sent``
        self.global_step = 0
        self._steps = 0

    @property
    def dropped_planned(self) -> int:
        """Planned actions that a newer plan preempted on the robot, total (the PlanChannel's count)."""
        return self.link.book.dropped_planned

    def _observe(
        self, state: m.RobotState | None = None, target: m.Target | None = None
    ) -> tuple[np.ndarray, float, dict[str, Any]]:
        """Observation, reward and info of ``state`` and ``target`` (default: the newest of each).

        The policy sees, and is rewarded by, the commanded TCP: what its action moves at once. A streamed
        arm reaches it a few periods later (franky-sim: 3-4), and a reward on the measured hand scored
        each action by the ones before it: learning drove the arm away from the target (docs/handoff.md).
        Distance and success are the measured hand's. On the mock the two are one (``ee_cmd = ee_pos``)."""
        with self.link.cond:
            state = self.link.state if state is None else state
            target = self.link.target if target is None else target
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
            "dropped_total": self.link.book.dropped_planned,
            "tick": state.tick,  # the robot's control tick the observation is from
        }
        return obs, reward, info

    # -- gymnasium -----------------------------------------------------------------------------------
    def reset(self, *, seed: int | None = None, options: dict | None = None) -> tuple[np.ndarray, dict]:
        """Home pose via the ``reset`` queryable; a seed gives the (simulated) target a new motion."""
        gym.Env.reset(self, seed=seed)  # seeds np_random (ReachSpec.reset refuses: it has no robot)
        self.link.reset(seed, self.settings.reset_timeout_s)
        self._steps = 0
        self._opening = Opening.FIRST
        obs, _, info = self._observe()
        return obs, info

    def open_segment(self, segment: int, segment_end: str) -> None:
        """Closed loop: the next chunk opens ``segment``, after the one before ended by ``segment_end``;
        the chunk says so, and robot-io's status of the chunk it preempts echoes it."""
        self.segment, self._opening = segment, opening(segment_end)

    def _chunk(self, obs: np.ndarray, action: np.ndarray) -> np.ndarray:
        """This step's action and its tail, each step capped in length as robot-io requires (the action is
        clipped per axis: a diagonal one is up to √3 times too long)."""
        n = max(self.settings.chunk_len - 1, 0)
        tail = np.zeros((n, 3)) if self.planner is None or not n else np.asarray(self.planner(obs, action, n))
        return cap_step_length(np.vstack([action[None, :], tail.reshape(n, 3)]), self.settings.max_step_m)

    def step(self, action: np.ndarray) -> tuple[np.ndarray, float, bool, bool, dict]:
        link = self.link
        action = np.clip(
            np.asarray(action, float).reshape(3), -self.settings.max_step_m, self.settings.max_step_m
        )
        link.await_target()
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
            if link.stop.is_set():
                raise LinkStopped("stopped while waiting for the robot")
            if link.consume_restart():
                restarted = True  # the chunk went to a process that is gone: the episode ends here
                break
            link.check_taken_over()
            if refused_in_a_row > (MAX_SIGNED_REFUSED if signed else MAX_REFUSED_IN_A_ROW):
                raise RuntimeError(f"robot-io refused {refused_in_a_row} chunks in a row: {link.refused}")
            plan = Plan(
                self._plans_sent, chunk, chunk, NO_PREDICTION, segment=self.segment, opened_by=self._opening
            )
            self._plans_sent += 1
            with link.cond:
                link.ticks.clear()  # only a tick after the chunk went out can have played it
                tick0 = link.state.tick if link.state is not None else -1
            seq = link.publish(plan)
            outcome = self._await_played(plan.plan_id, seq, signed)
            if outcome == "played":
                break
            if outcome == "refused":
                refused_in_a_row += 1
                continue  # stale or a jump (a forged number got in first): resend with the next one
            if signed and link.robot_mode == "running" and link.book.refused(seq):
                refused_in_a_row += 1  # not played in time, and refused: e.g. a token that is not robot-io's
            # Not played: the arm is held (the watchdog after a stall of ours, a lost peer), e-stopped or
            # paused, the chunk was cut before it played, or another session took over (checked before
            # the resend). A watchdog hold lifts only with a fresh chunk, so a held arm gets one per
            # step timeout (refused harmlessly while another hold lasts); an e-stop, a pause or a fault
            # waits for the operator.
            while not link.wait(lambda: link.robot_mode not in SUSPENDED or link.stop.is_set(), 0.5):
                pass
            # At most one resend per tick: a "held" verdict comes before the state that shows the hold.
            link.wait(lambda t=tick0: link.state is not None and link.state.tick > t, 2 * self.period)
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
        link = self.link
        deadline = time.monotonic() + self.settings.step_timeout_s
        refused = lambda: not signed and link.book.refused(seq)  # noqa: E731
        news = lambda: bool(link.ticks) or refused() or link.taken_over  # noqa: E731
        while link.wait(news, max(deadline - time.monotonic(), 0.0)):
            ticks = link.drain_ticks()
            if any(played(state, link.book, link.session.id)[0] == plan_id for state, _ in ticks):
                return "played"
            if link.taken_over:
                return ""
            if refused():
                return "refused"
        return ""

    # -- plan channel (learner.plans.PlanChannel) ----------------------------------------------------
    def send(self, plan: Plan) -> None:
        """Publish ``plan`` as one chunk; never blocks."""
        self.link.publish(plan)

    def _hold_for_target(self) -> None:
        """The target lost or stale: a plan made for a target we cannot see must not play on. A
        one-action plan that stays put preempts it (robot-io's watchdog then holds the arm), the actor
        waits for a fresh fix, and the ticks of the outage are passed over: nothing is learned from them
        (the next tick closes the segment)."""
        obs, _, _ = self._observe()
        stay = np.zeros((1, 3))
        newest = self.link.book.newest()
        segment = newest.plan.segment if newest is not None else 0
        here = np.stack([obs, obs])
        self.link.publish(Plan(-1, stay, stay, here, segment=segment, opened_by=Opening.TARGET_LOST))
        self.link.await_target()
        self.link.outage_ticks += len(self.link.drain_ticks())

    def backlog(self) -> int:
        """Ticks that played and are not yet returned by ``advance`` (more than none: this side lags)."""
        return self.link.backlog()

    def advance(self) -> Executed:
        """The robot's next control tick as an executed step (see the module docstring)."""
        link = self.link
        link.check_taken_over()
        while True:
            if not link.wait(link.target_fresh, 0.0):
                self._hold_for_target()
            state, target = link.next_tick(self.settings.step_timeout_s)
            if usable(target, state.stamp, self.settings.target_timeout_s):
                break
            link.outage_ticks += 1  # paired with a fix that went stale between the check and the tick
        restarted = link.consume_restart()  # this tick is the new robot-io's: the episode ends with it
        plan_id, index, action = played(state, link.book, link.session.id)
        self._steps += 1
        self.global_step += 1
        obs, reward, info = self._observe(state, target)
        info.update(tick=state.tick, played_chunk=state.played_chunk, mode=m.label(state, "mode"))
        truncated = self._steps >= self.settings.max_episode_steps or restarted
        return Executed(plan_id, index, action, obs, reward, False, truncated, info, state.tick)
