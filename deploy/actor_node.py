"""The actor process (``adaptiveh act``): AdaptiveH's plans made and judged beside the arm.

It runs where robot-io runs and holds the newest policy snapshot the learner published
(``policy/snapshot``: signed, well-formed and newer than the one it has, else refused with a
``bad_message`` safety event while the old one keeps running). Each segment it plans from the state the
arm is in (``learner.actor.Actor``), plays the plan through robot-io (``deploy.zenoh_env``, plan
execution), evaluates the retreat test at every tick and re-plans at once when it fails, at the plan's
end or at the episode's end: the segment loop ``learner.acting.SegmentLoop``, as in-process plan
execution runs it. Every tick goes to the learner on ``stream/transition`` with how its
segment stands; the learner learns and publishes snapshots when it is ready, so learner latency
delays improvement, not control, and a stopped or restarting learner stops nothing here.
"""

from __future__ import annotations

import json
import logging
import threading
import time
from typing import Any

import numpy as np

from bus import messages as m
from bus.node import Node
from common.throttle import EVENT_EVERY_S, Throttle
from deploy.config import StackConfig
from deploy.policy_wire import snapshot_from_message
from deploy.robot_link import LinkStopped
from deploy.run_report import actor_counts_path
from deploy.transition_stream import Outbox
from deploy.zenoh_env import ZenohReachEnv, env_settings
from learner.acting import SegmentLoop, Tick
from learner.actor import Actor
from learner.config import AdaptiveHConfig, rkhs_config
from learner.segments import SegmentEnd
from learner.snapshot import PolicySnapshot, SnapshotError

log = logging.getLogger(__name__)
JOIN_WAIT_S = 2.0  # an arm joining a running learner waits this long at most for its policy


class ActorNode(Node):
    """Acts on its own thread from start to stop; ``counts`` and ``actor.json`` say what it did."""

    alive_as = "actor"

    def __init__(self, settings: StackConfig, control_token: str = "") -> None:
        super().__init__(settings.bus_key, settings.zenoh, token=control_token, fleet=settings.name)
        lc = settings.learner
        # The actor plays each plan at once: the learner's latency delays snapshots, not plans.
        self.env = ZenohReachEnv(self.bus, env_settings(settings))
        self.actor = Actor(self.env, rkhs_config(lc.algo, AdaptiveHConfig(**lc.agent_config())), lc.seed)
        self.arm = settings.arm or ""  # of a fleet: its transitions and counts say so
        self.out = actor_counts_path(lc.checkpoint_dir, self.arm)
        self.handoff = lc.policy_from  # then the first plan waits for the learner's first snapshot
        self.error = ""  # why acting ended, when it did not end by a stop
        self._lock = threading.Lock()
        self._offered: PolicySnapshot | None = None  # the newest accepted snapshot, taken at the next segment
        self._episode_seed = lc.seed
        # The segment loop; a plan is made from the newest tick only: ticks that played while this process
        # was held up (a stall, a loaded machine) are streamed first, never planned from.
        self.loop = SegmentLoop(
            self.actor,
            self.env,
            self.actor.judge,
            ready=lambda: not self.env.backlog(),
            before_plan=self._take_offered,
        )
        self.counts = {"steps": 0, "episodes": 0, "snapshots": 0, "refused": 0}
        self._refusals = Throttle("refused snapshots", EVENT_EVERY_S)
        self.outbox = Outbox(self.bus.publisher(m.TRANSITIONS), lc.unsaved_limit)
        self._losses = Throttle("transitions dropped before the learner saved them", EVENT_EVERY_S)
        self.bus.subscribe(m.TRANSITION_ACKS, self.outbox.on_ack)
        self._pub_safety = self.bus.publisher(m.EVENTS_SAFETY)
        self.bus.subscribe(m.POLICY, self._on_snapshot, on_bad=self._on_bad_snapshot)
        self.declare_alive()

    # -- snapshots -----------------------------------------------------------------------------------
    def _on_snapshot(self, msg: m.PolicySnapshot) -> None:
        try:
            snap = snapshot_from_message(msg)
            self.actor.check(snap)
            with self._lock:
                newest = max(self.actor.version, self._offered.version if self._offered else -1)
                if snap.version == newest:
                    return  # the learner publishes its policy again while no tick reaches it
                if snap.version < newest:
                    raise SnapshotError(f"version {snap.version} is not newer than {newest}")
                self._offered = snap
        except SnapshotError as exc:
            self._refuse(str(exc), log_it=True)

    def _on_bad_snapshot(self, topic: str, exc: Exception, data: bytes) -> None:
        self._refuse(str(exc))  # undecodable, unsigned, forged or replayed: the bus has logged it

    def _refuse(self, why: str, log_it: bool = False) -> None:
        """One safety event a second at most (with the count held back): a flood must not flood."""
        self.counts["refused"] += 1
        if log_it:
            self.bus.report_bad(m.POLICY.name, m.MessageError(why, "out_of_range"))  # rate-limited
        detail = f"policy snapshot refused, the policy of version {self.actor.version} keeps running: {why}"
        self._report_refusal(self._refusals.report(detail))

    def _report_held_back(self) -> None:
        """Reports the throttles held back, once their window ends (a burst with nothing after)."""
        for detail in self._refusals.overdue():
            self._report_refusal(detail)
        for detail in self._losses.overdue():
            log.warning("%s", detail)

    def _report_refusal(self, detail: str | None) -> None:
        if detail is not None:
            self._pub_safety(m.SafetyEvent(kind=m.SafetyEvent.BAD_MESSAGE, detail=detail, held=False))

    def _take_offered(self) -> None:
        with self._lock:
            snap, self._offered = self._offered, None
        if snap is not None:
            self.actor.load(snap)
            self.counts["snapshots"] += 1

    # -- acting --------------------------------------------------------------------------------------
    def workers(self) -> dict[str, Any]:
        return {"act": self._act}

    def wake(self) -> None:
        self.env.link.stop.set()  # a reset or tick wait returns at once

    def _act(self) -> None:
        try:
            self._await_policy()
            while not self.stopping:
                self._episode()
        except LinkStopped:
            pass
        except Exception as exc:  # a takeover, a robot that never resets: the supervisor restarts us
            self.error = f"{type(exc).__name__}: {exc}"
            log.exception("acting stopped")
            self.request_stop()
        finally:
            self._write_counts()

    def _await_policy(self) -> None:
        """The first plan comes from the learner's policy when there is one to have: with
        ``learner.policy_from`` nothing moves (no reset, no plan) until the learner's first snapshot is
        here; else, with a learner up (an arm that joins a running fleet), the first plan waits for the
        snapshot the learner sends a joining actor, at most ``JOIN_WAIT_S``."""
        start = told = time.monotonic()
        if self.handoff is None and not self._learner_up():
            return
        while not self.stopping and not self._holds_snapshot():
            now = time.monotonic()
            if self.handoff is None and now - start >= JOIN_WAIT_S:
                log.warning("no policy snapshot %.0f s after joining: an empty policy acts", now - start)
                return
            if now - told >= 5.0:
                log.warning(
                    "no plan yet: waited %.0f s for the handed-off policy of %s", now - start, self.handoff
                )
                told = now
            time.sleep(0.02)

    def _learner_up(self) -> bool:
        try:
            return self.bus.alive_now("learner", timeout=1.0, fleet=True)
        except ConnectionError:
            return False

    def _holds_snapshot(self) -> bool:
        with self._lock:
            return self._offered is not None or self.actor.version >= 0

    def _episode(self) -> None:
        self.loop.reset(seed=self._episode_seed)
        self._episode_seed += 1
        episode = self.counts["episodes"]
        while not self.stopping:
            tick = self.loop.tick()
            self._publish(episode, tick)
            self.outbox.resend()
            self._report_held_back()
            self.counts["steps"] += 1
            if tick.episode_over:
                self.counts["episodes"] += 1
                return

    def _publish(self, episode: int, tick: Tick) -> None:
        step, played = tick.step, tick.played
        raw, source = played.raw(step), played.source
        noise = source.noise[step.index] if source is not None else np.zeros_like(raw)  # a hold: no draw
        predicted = played.predicted(step)
        msg = m.Transition(
            episode=episode,
            segment=tick.segment,
            obs=np.asarray(tick.obs, float).tolist(),
            raw_action=np.asarray(raw, float).tolist(),
            noise=np.asarray(noise, float).tolist(),
            reward=step.reward,
            next_obs=np.asarray(step.obs, float).tolist(),
            terminated=step.terminated,
            truncated=step.truncated,
            success=bool(step.info.get("success", False)),
            distance=float(step.info.get("distance", 0.0)),
            predicted=[] if predicted is None else np.asarray(predicted, float).tolist(),
            end=m.enum(m.Transition, "end", tick.end),
            policy_version=max(self.actor.version, 0),
            target_age=float(step.info.get("target_age_s", 0.0)),
            arm=self.arm,
        )
        if tick.statistic is not None:
            msg.statistic = tick.statistic
        if self.outbox.send(msg):
            why = f"the learner has not saved the last {self.outbox.limit} transitions: the oldest is lost"
            detail = self._losses.report(f"{why} ({self.outbox.lost} so far)")
            if detail is not None:
                log.warning("%s", detail)

    def _write_counts(self) -> dict[str, Any]:
        env = self.env
        out = {
            **self.counts,
            "segments": self.loop.segments,
            "retreats": self.loop.ends[SegmentEnd.RETREAT],
            **self.loop.starts,
            "policy_version": self.actor.version,
            "session": env.link.session.id,  # robot-io's chunk statuses name it
            **env.link.counts(),
            "plan_model_updates": self.actor.model.updates,  # ticks the plan model learned from
            "stream": self.outbox.stream,
            "transitions_unsaved": self.outbox.unsaved(),  # kept: the learner has not checkpointed them
            "transitions_resent": self.outbox.resent,
            "transitions_lost": self.outbox.lost,
            "error": self.error,
            "arm": self.arm,
        }
        self.out.parent.mkdir(parents=True, exist_ok=True)
        self.out.write_text(json.dumps(out, indent=1))
        return out
