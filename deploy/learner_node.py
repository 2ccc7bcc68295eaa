"""The learner process: any registry agent (AdaptiveH, RKHS, TD3, DDPG) on the Zenoh reach env, or, with
``learner.execution: actor``, an RKHS learner that learns from the actor's stream of executed ticks
(``deploy.transition_stream.Inbox``: in order, and nothing lost while the learner restarts) and
publishes a policy snapshot at each segment end (``deploy.actor_node``).

Publishes ``events/retreat`` for every closed segment (RKHS learners) and ``telemetry/learner`` for every
finished episode; obeys ``control`` pause/resume (with the operator token when one is set); declares
``alive/learner`` so the robot holds while the learner is gone, and its session
(``bus.learner_session``: robot-io obeys only the session that took over with the latest reset);
checkpoints to ``checkpoint_dir/checkpoint.pkl`` every ``checkpoint_every`` steps and at the end, and
resumes from it on restart. In closed loop, AdaptiveH's chunk tail can be its own plan: the policy mean
rolled forward on the task's model (``learner.plan: policy``); a retreat's first chunk preempts the rest
of the one before, and the planned actions that drops (the non-zero ones apart: real motion abandoned)
are counted as ``retreat_dropped`` / ``retreat_dropped_moving``.
"""

from __future__ import annotations

import json
import logging
import queue
import threading
import time
from pathlib import Path
from typing import Any

import numpy as np

from bus import messages as m
from bus.node import Node
from bus.signing import ForgedMessage, Fresh, authentic
from common.heap import release_free_heap
from deploy.config import StackConfig
from deploy.plan_channel import DelayedSender
from deploy.policy_wire import snapshot_message
from deploy.robot_link import LinkStopped, TakenOver
from deploy.run_report import started_from
from deploy.transition_stream import Inbox
from deploy.zenoh_env import ReachSpec, ZenohReachEnv, env_settings
from learner.protocol import Agent, RunLog
from learner.registry import make_agent
from learner.run_archive import RunArchive
from learner.run_summary import summarize
from learner.segments import Execution

log = logging.getLogger(__name__)
TELEMETRY_EVERY = 20  # steps between progress telemetry (1 s at 20 Hz), besides one per episode


REPUBLISH_S = 1.0  # how often the held policy is published again while no tick comes


def learn_transition(agent: Agent, t: m.Transition) -> Any:
    """Feed one of the actor's ticks to an RKHS agent (``AdaptiveH.learn_transition``)."""
    info = {"success": t.success, "distance": t.distance, "target_age_s": t.target_age}
    return agent.learn_transition(
        np.asarray(t.obs, float),
        np.asarray(t.raw_action, float),
        t.reward,
        np.asarray(t.next_obs, float),
        t.terminated,
        t.truncated,
        info,
        np.asarray(t.predicted, float) if len(t.predicted) else None,
        m.label(t, "end"),
        t.statistic if t.HasField("statistic") else None,
        np.asarray(t.noise, float) if len(t.noise) else None,
        stream=t.stream,
        arm=t.arm,
    )


class LearnerNode(Node):
    """``run()`` learns (on the caller's thread) until ``steps`` are done or ``request_stop()``."""

    alive_as = "learner"

    def __init__(self, settings: StackConfig, control_token: str = "") -> None:
        self.settings = settings
        self.cfg = settings.learner
        self._fresh_control = Fresh()
        super().__init__(settings.bus_key, settings.zenoh, token=control_token, fleet=settings.name)
        # learn from an actor's stream; never drive the robot
        self.stream = self.cfg.execution == Execution.ACTOR
        self.env = (
            ReachSpec(env_settings(settings))
            if self.stream
            else ZenohReachEnv(self.bus, env_settings(settings))
        )
        agent_cfg = self.cfg.agent_config()
        self.agent: Agent = make_agent(self.cfg.algo, self.env, self.cfg.seed, agent_cfg)
        if self.cfg.plan == "policy" and not self.stream and hasattr(self.agent, "step_env"):
            self.env.planner = self._plan
        self.ckpt = Path(self.cfg.checkpoint_dir) / "checkpoint.pkl"
        self.resumed_from = 0
        if self.ckpt.exists():
            self.agent.load(self.ckpt)
            self.resumed_from = self.agent.log.global_step
            log.info("resumed from %s at step %d", self.ckpt, self.resumed_from)
        elif self.cfg.policy_from is not None:
            came = self.agent.start_from(self.cfg.policy_from)
            log.info(
                "handoff: started from %s (%s, %d steps)", came["path"], came["trained_on"], came["steps"]
            )
        self.handed_off = getattr(self.agent, "started_from", None) is not None
        self._pub_retreat = self.bus.publisher(m.EVENTS_RETREAT)
        self._pub_tel = self.bus.publisher(m.TELEMETRY_LEARNER)
        self._paused = threading.Event()
        self._episodes_seen = self.agent.log.episode_count
        self._segments_seen = self.agent.log.segment_count
        self.archive = RunArchive(self.ckpt.parent, self.agent.log)
        self._arm_changes: queue.SimpleQueue[tuple[str, bool]] = queue.SimpleQueue()  # (arm, alive)
        if self.stream:
            self.feed = Inbox(self.bus, getattr(self.agent, "stream_marks", {}))
            self.bus.watch_arms("actor", lambda arm, alive: self._arm_changes.put((arm, alive)))
            self._pub_policy = self.bus.publisher(m.POLICY)
            delay = self.cfg.latency_ms / 1000.0
            self._snapshot_sender = DelayedSender(self._pub_policy, delay, self._stop) if delay > 0 else None
        self.bus.subscribe(m.FLEET_CONTROL, self._on_control, verify=False)  # judged in _on_control
        self.declare_alive()

    # -- plan and accounting -------------------------------------------------------------------------
    def _plan(self, obs: np.ndarray, action: np.ndarray, n: int) -> np.ndarray:
        """The policy mean on observations the task's model predicts from ``obs`` after ``action``."""
        out, o, a = [], np.asarray(obs, float), np.asarray(action, float)
        for _ in range(n):
            o = self.env.predict_next(o, a)
            a = np.asarray(self.agent.predict(o, deterministic=True), float).reshape(3)
            out.append(a)
        return np.asarray(out)

    def _on_control(self, msg: m.Control) -> None:
        command = m.label(msg, "command")
        if command not in ("pause", "resume"):
            return
        key = self.bus.signing_key
        if key is not None and not (authentic(msg, key) and self._fresh_control(msg.stamp)):
            why = f"control {command} ignored: not signed with the stack's key, or a replay"
            self.bus.report_bad(m.CONTROL.name, ForgedMessage(why, msg))
            return
        if command == "pause":
            self._paused.set()
        else:
            self._paused.clear()
        self._telemetry()

    def _telemetry(self) -> None:
        eps = self.agent.log.episodes
        last = eps[-1] if eps else None
        self._pub_tel(
            m.LearnerTelemetry(
                global_step=self.agent.log.global_step,
                episode=self.agent.log.episode_count,
                episode_return=float(last.ret) if last else 0.0,
                success=bool(last.success) if last and last.success is not None else False,
                paused=self._paused.is_set(),
                algo=self.cfg.algo,
                started_from=started_from(getattr(self.agent, "started_from", None)),
            )
        )

    def _after_step(self) -> None:
        new_episode = self._report_closed()
        lg = self.agent.log
        if new_episode:
            self._telemetry()
        elif lg.global_step % TELEMETRY_EVERY == 0:
            self._telemetry()  # the operator sees the step count move between episodes
        if lg.global_step % self.cfg.checkpoint_every == 0:
            self.save()

    def _report_closed(self) -> bool:
        """Publish the segments closed since the last call and archive them with the episodes; whether an
        episode ended."""
        lg = self.agent.log
        for rec in lg.segments_since(self._segments_seen):
            self._pub_retreat(
                m.RetreatEvent(
                    segment=rec.index,
                    H=rec.H,
                    reason=m.enum(m.RetreatEvent, "reason", rec.reason),
                    statistic=[x if np.isfinite(x) else 0.0 for x in rec.statistic],
                    threshold=float(rec.threshold),
                    global_step=rec.global_step,
                    arm=rec.arm,
                )
            )
            if not self.stream:
                self.env.open_segment(rec.index + 1, rec.reason)
        new_episode = lg.episode_count > self._episodes_seen
        if lg.segment_count > self._segments_seen or new_episode:
            self._segments_seen, self._episodes_seen = lg.segment_count, lg.episode_count
            self.archive.add(lg)  # on file; memory keeps the newest
        return new_episode

    def _learn_stream(self, progress: Any) -> None:
        """Learn from the actor's ticks; at each segment's end checkpoint (so a killed learner loses at
        most the segment it was in) and publish the new policy. While no tick comes (an actor starting,
        or waiting for a handed-off policy before it plays anything), the policy held is published again
        every second: a subscriber has no history, so an actor that joins later would never get it."""
        quiet_since = time.monotonic()
        while self.agent.log.global_step < self.cfg.steps and self._gate():
            self._arms_come_and_go()
            self.feed.ack()
            t = self.feed.get(timeout=0.25)
            if t is None:
                if self._holds_policy() and time.monotonic() - quiet_since >= REPUBLISH_S:
                    self._publish_snapshot()
                    quiet_since = time.monotonic()
                continue
            quiet_since = time.monotonic()
            closed = learn_transition(self.agent, t)
            self.feed.learned_one(t)
            if closed is not None:
                self.save()
                self._publish_snapshot()
            self._after_step()
            if progress is not None:
                progress(self)

    def _arms_come_and_go(self) -> None:
        """An arm's actor that comes gets the policy at once (a subscriber has no history), so its first
        plan is the newest policy's; one that goes has its open segment closed, and the others go on
        untouched."""
        while True:
            try:
                arm, alive = self._arm_changes.get_nowait()
            except queue.Empty:
                return
            if alive:  # the policy as it is, even an empty one: the actor waits for it before it plans
                log.info("arm %r: its actor is up", arm)
                self._publish_snapshot()
            else:
                closed = self.agent.close_arm(arm)
                log.warning("arm %r: its actor is gone (%d open segment closed)", arm, len(closed))
                self._report_closed()

    def _holds_policy(self) -> bool:
        """A policy worth publishing unasked: handed off, or learned (this run or before a restart)."""
        return self.handed_off or self.agent.log.global_step > 0

    def _publish_snapshot(self) -> None:
        msg = snapshot_message(self.agent.snapshot())
        if self._snapshot_sender is None:
            self._pub_policy(msg)
        else:
            self._snapshot_sender.submit(msg)

    def _gate(self) -> bool:
        """Block while paused; False when stopping."""
        while self._paused.is_set() and not self.stopping:
            time.sleep(0.05)
        return not self.stopping

    # -- run -----------------------------------------------------------------------------------------
    def save(self) -> None:
        """Checkpoint (with how far each actor's stream is learned: the actors may then forget it), then
        hand the writer's freed buffers back to the OS (``common.heap``)."""
        if self.stream:
            self.agent.stream_marks = dict(self.feed.learned)
        self.agent.save(self.ckpt)
        if self.stream:
            self.feed.checkpointed(self.agent.stream_marks)
        release_free_heap()

    def run(self, progress: Any = None) -> dict[str, Any]:
        """Learn the remaining steps; ``progress(node)`` is called after every step."""
        t0 = time.perf_counter()
        start = self.agent.log.global_step
        try:
            if self.stream:
                self._learn_stream(progress)
            elif hasattr(self.agent, "step_env"):
                while self.agent.log.global_step < self.cfg.steps and self._gate():
                    self.agent.step_env()
                    self._after_step()
                    if progress is not None:
                        progress(self)
            else:

                def callback(step: int, lg: RunLog) -> bool:
                    self._after_step()
                    if progress is not None:
                        progress(self)
                    return self._gate()

                self.agent.learn(max(self.cfg.steps - start, 0), callback=callback)
        except LinkStopped:
            log.info("stopped while the robot was held")
        except TakenOver as exc:
            log.error("%s", exc)  # the checkpoint is kept; the supervisor decides whether to start again
            raise
        finally:
            self.save()
        wall = time.perf_counter() - t0
        return self.result(wall, self.agent.log.global_step - start)

    def result(self, wall: float, steps: int) -> dict[str, Any]:
        full = self.archive.full(self.agent.log)
        out = {
            "algo": self.cfg.algo,
            "config": self.cfg.model_dump(),
            "summary": summarize(full),
            "resumed_from": self.resumed_from,
            "started_from": getattr(self.agent, "started_from", None),
            "steps_this_session": steps,
            "wall_clock_s": wall,
            "execution": self.cfg.execution,
            "latency_ms": self.cfg.latency_ms,
            **(self._stream_counts() if self.stream else self._robot_counts()),
            **full.to_dict(),
        }
        path = self.ckpt.parent / "result.json"
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_text(json.dumps(out, indent=1, default=float))
        return out

    def _robot_counts(self) -> dict[str, Any]:
        link = self.env.link
        return {
            "session": link.session.id,
            "refused_chunks": dict(link.refused),
            **link.counts(),
            "chunk_preemptions": link.book.preemptions,  # the names older results and benches read
            "dropped_actions": link.book.dropped_planned,
        }

    def _stream_counts(self) -> dict[str, Any]:
        """The stream as this learner saw it; the actor's own counts (plans, drops) are in its actor.json."""
        feed = self.feed
        return {
            "transitions_received": feed.received,
            "transitions_learned": dict(feed.learned),  # per actor stream, in order, without a gap
            "transitions_duplicate": feed.duplicates,  # sent again (or cached) after it was taken
            "transitions_out_of_order": feed.out_of_order,  # after a gap: taken when sent again
            "transitions_lost": feed.lost,  # dropped by an actor before this learner had them
        }

    def wake(self) -> None:
        if not self.stream:
            self.env.link.stop.set()  # a step or reset blocked on a held robot returns at once
