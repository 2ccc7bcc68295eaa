"""The learner process: any registry agent (AdaptiveH, RKHS, TD3, DDPG) on the Zenoh reach env.

Publishes ``events/retreat`` for every closed segment (RKHS learners) and ``telemetry/learner`` for
every finished episode; obeys ``control`` pause/resume (with the operator token when one is set);
declares ``alive/learner`` so the robot holds while the learner is gone; checkpoints to
``checkpoint_dir/checkpoint.pkl`` every ``checkpoint_every`` steps and at the end, and resumes from it
on restart. AdaptiveH's chunk tail is its own plan: the policy mean rolled forward on extrapolated
observations (see ``deploy.zenoh_env``).
"""

from __future__ import annotations

import json
import logging
import threading
import time
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from deploy import messages as m
from deploy.config import build, load_yaml, robot_name
from deploy.training import summarize
from deploy.transport import Bus, ZenohConfig, open_session
from deploy.zenoh_env import EnvSettings, EnvStopped, ZenohReachEnv, extrapolate
from learner.protocol import Agent, RunLog
from learner.registry import ALGOS, make_agent

log = logging.getLogger(__name__)
TELEMETRY_EVERY = 20  # steps between progress telemetry (1 s at 20 Hz), besides one per episode


@dataclass(frozen=True)
class LearnerConfig:
    """The ``learner:`` section."""

    algo: str = "adaptiveh"
    steps: int = 4000
    seed: int = 0
    agent: dict[str, Any] = field(default_factory=dict)
    chunk_len: int = 10
    # The chunk's tail after this step's action, played if the learner is late for a tick: ``hold``
    # (zero displacements) or ``policy`` (AdaptiveH's mean rolled forward). Measured: with ``policy`` a
    # late learner's transitions mix in planned actions and NS Reach did not learn over Zenoh in 2400
    # steps; with ``hold`` a late tick only costs time.
    plan: str = "hold"
    max_episode_steps: int = 200
    target_topic: str = m.TARGET
    # Where the target moves and how fast: the learner scales its state with these, so they must match
    # the real target's range (NSReach-v0 scales with its motion preset's box and speed). Measured: with
    # the workspace as the box and 0.2 m/s, in-process NS Reach seed 0 stopped learning (0 % vs 90 %).
    target_box: tuple[tuple[float, float, float], tuple[float, float, float]] = (
        (0.35, -0.3, 0.12),
        (0.65, 0.3, 0.45),
    )
    target_speed_max: float = 0.06
    step_timeout_s: float = 2.0
    checkpoint_dir: str = "runs/stack/learner"
    checkpoint_every: int = 500

    def __post_init__(self) -> None:
        if self.algo not in ALGOS:
            raise ValueError(f"algo: unknown {self.algo!r}; choose one of {list(ALGOS)}")
        for name in ("steps", "chunk_len", "max_episode_steps", "checkpoint_every"):
            if not isinstance(getattr(self, name), int) or getattr(self, name) < 1:
                raise ValueError(f"{name}: must be an integer >= 1, got {getattr(self, name)!r}")
        if self.plan not in ("hold", "policy"):
            raise ValueError(f"plan: must be hold or policy, got {self.plan!r}")
        if not isinstance(self.agent, dict):
            raise ValueError("agent: must be a mapping of hyperparameters")
        lo, hi = (np.asarray(b, float) for b in self.target_box)
        if lo.shape != (3,) or hi.shape != (3,) or np.any(lo >= hi):
            raise ValueError(
                f"target_box: must be [[x, y, z] lo, [x, y, z] hi] with lo < hi, got {self.target_box}"
            )
        if not self.target_speed_max > 0:
            raise ValueError(f"target_speed_max: must be > 0, got {self.target_speed_max}")


@dataclass(frozen=True)
class LearnerSettings:
    name: str
    zenoh: ZenohConfig
    learner: LearnerConfig
    env: EnvSettings


def load_settings(path: str | Path, overrides: dict[str, Any] | None = None) -> LearnerSettings:
    """Read ``name``, ``zenoh``, ``learner`` and the robot's workspace/rate/step from a top-level config."""
    data = load_yaml(path)
    name = robot_name(data, path)
    section = {**(data.get("learner") or {}), **{k: v for k, v in (overrides or {}).items() if v is not None}}
    lc = build(LearnerConfig, section, f"{path}: learner")
    robot = data.get("robot") or {}
    ws = robot.get("workspace") or {}
    env = EnvSettings(
        workspace_lo=tuple(ws.get("lo", EnvSettings.workspace_lo)),
        workspace_hi=tuple(ws.get("hi", EnvSettings.workspace_hi)),
        max_step_m=float(robot.get("max_step_m", EnvSettings.max_step_m)),
        control_rate_hz=float(robot.get("control_rate_hz", EnvSettings.control_rate_hz)),
        max_episode_steps=lc.max_episode_steps,
        chunk_len=lc.chunk_len,
        target_topic=lc.target_topic,
        target_lo=tuple(lc.target_box[0]),
        target_hi=tuple(lc.target_box[1]),
        target_speed_max=lc.target_speed_max,
        step_timeout_s=lc.step_timeout_s,
    )
    return LearnerSettings(name, build(ZenohConfig, data.get("zenoh"), "zenoh"), lc, env)


class LearnerNode:
    """``run()`` learns until ``steps`` are done or ``request_stop()``; returns the summary."""

    def __init__(self, settings: LearnerSettings, control_token: str = "") -> None:
        self.settings = settings
        self.cfg = settings.learner
        self.control_token = control_token
        self.bus = Bus(open_session(settings.zenoh), settings.name)
        self.env = ZenohReachEnv(self.bus, settings.env)
        self.agent: Agent = make_agent(self.cfg.algo, self.env, self.cfg.seed, self.cfg.agent)
        if self.cfg.plan == "policy" and hasattr(self.agent, "step_env"):
            self.env.planner = self._plan
        self.ckpt = Path(self.cfg.checkpoint_dir) / "checkpoint.pkl"
        self.resumed_from = 0
        if self.ckpt.exists():
            self.agent.load(self.ckpt)
            self.resumed_from = self.agent.log.global_step
            log.info("resumed from %s at step %d", self.ckpt, self.resumed_from)
        self._pub_retreat = self.bus.publisher(m.EVENTS_RETREAT)
        self._pub_tel = self.bus.publisher(m.TELEMETRY_LEARNER)
        self._paused = threading.Event()
        self._stop = threading.Event()
        self._seq = 0
        self._episodes_seen = len(self.agent.log.episodes)
        self._segments_seen = len(self.agent.log.segments)
        self.retreat_preemptions = 0  # a retreat's first chunk preempting the previous segment's plan
        self.retreat_dropped = 0
        self._retreat_chunks: set[int] = set()
        self.env.on_status = self._on_status
        self.bus.subscribe(m.CONTROL, m.Control, self._on_control)
        self.bus.declare_alive("learner")

    # -- plan and accounting -------------------------------------------------------------------------
    def _plan(self, obs: np.ndarray, action: np.ndarray, n: int) -> np.ndarray:
        """The policy mean on observations extrapolated from ``obs`` after ``action``."""
        dt = 1.0 / self.settings.env.control_rate_hz
        out, o, a = [], np.asarray(obs, float), np.asarray(action, float)
        for _ in range(n):
            o = extrapolate(o, a, dt)
            a = np.asarray(self.agent.predict(o, deterministic=True), float).reshape(3)
            out.append(a)
        return np.asarray(out)

    def _on_status(self, msg: m.ChunkStatus) -> None:
        if msg.preempted_by in self._retreat_chunks and msg.dropped:
            self.retreat_preemptions += 1
            self.retreat_dropped += msg.dropped

    def _on_control(self, msg: m.Control) -> None:
        if msg.command not in ("pause", "resume"):
            return
        if self.control_token and msg.token != self.control_token:
            log.warning("control %s with a wrong token ignored", msg.command)
            return
        if msg.command == "pause":
            self._paused.set()
        else:
            self._paused.clear()
        self._telemetry()

    def _next(self) -> int:
        self._seq += 1
        return self._seq

    def _telemetry(self) -> None:
        eps = self.agent.log.episodes
        last = eps[-1] if eps else None
        self._pub_tel(
            m.LearnerTelemetry(
                seq=self._next(),
                global_step=self.agent.log.global_step,
                episode=len(eps),
                episode_return=float(last.ret) if last else 0.0,
                success=bool(last.success) if last and last.success is not None else False,
                paused=self._paused.is_set(),
                algo=self.cfg.algo,
            )
        )

    def _after_step(self) -> None:
        lg = self.agent.log
        for rec in lg.segments[self._segments_seen :]:
            self._pub_retreat(
                m.RetreatEvent(
                    seq=self._next(),
                    segment=rec.index,
                    H=rec.H,
                    reason=rec.reason,
                    statistic=[x if np.isfinite(x) else 0.0 for x in rec.statistic],
                    threshold=float(rec.threshold),
                    global_step=rec.global_step,
                )
            )
            self.env.segment = rec.index + 1
            if rec.reason == "retreat":
                self._retreat_chunks.add(self.env.chunk_seq + 1)  # the next chunk opens the new segment
        self._segments_seen = len(lg.segments)
        if len(lg.episodes) > self._episodes_seen:
            self._episodes_seen = len(lg.episodes)
            self._telemetry()
        elif lg.global_step % TELEMETRY_EVERY == 0:
            self._telemetry()  # the operator sees the step count move between episodes
        if lg.global_step % self.cfg.checkpoint_every == 0:
            self.save()

    def _gate(self) -> bool:
        """Block while paused; False when stopping."""
        while self._paused.is_set() and not self._stop.is_set():
            time.sleep(0.05)
        return not self._stop.is_set()

    # -- run -----------------------------------------------------------------------------------------
    def save(self) -> None:
        self.agent.save(self.ckpt)

    def run(self, progress: Any = None) -> dict[str, Any]:
        """Learn the remaining steps; ``progress(node)`` is called after every step."""
        t0 = time.perf_counter()
        start = self.agent.log.global_step
        try:
            if hasattr(self.agent, "step_env"):
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
        except EnvStopped:
            log.info("stopped while the robot was held")
        finally:
            self.save()
        wall = time.perf_counter() - t0
        return self.result(wall, self.agent.log.global_step - start)

    def result(self, wall: float, steps: int) -> dict[str, Any]:
        out = {
            "algo": self.cfg.algo,
            "config": asdict(self.cfg),
            "summary": summarize(self.agent.log),
            "resumed_from": self.resumed_from,
            "steps_this_session": steps,
            "wall_clock_s": wall,
            "chunk_preemptions": self.env.preemptions,
            "dropped_actions": self.env.dropped_total,
            "retreat_preemptions": self.retreat_preemptions,
            "retreat_dropped": self.retreat_dropped,
            **self.agent.log.to_dict(),
        }
        path = self.ckpt.parent / "result.json"
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_text(json.dumps(out, indent=1, default=float))
        return out

    def request_stop(self) -> None:
        self._stop.set()
        self.env.stop.set()

    def close(self) -> None:
        self.bus.close()
