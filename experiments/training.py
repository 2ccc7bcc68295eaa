"""One in-process training run: ``adaptiveh train`` and the stack bench build on ``TrainSpec``/``train``.

A run writes ``result.json`` (episodes, segments, the run summary, timing), ``curve.png`` and a
checkpoint (``checkpoint.pkl``) every ``checkpoint_every`` steps and at the end, so an interrupted run
resumes where it stopped and nothing learned is lost.
"""

from __future__ import annotations

import json
import time
from pathlib import Path
from typing import Any

import gymnasium as gym
import numpy as np
from pydantic import Field, field_validator
from tqdm import tqdm

import tasks  # noqa: F401  (registers every environment, NS Reach included)
from common.config import ConfigError, Section, load_yaml, parse
from experiments import envs
from learner.protocol import Agent, RunLog
from learner.registry import Algo, make_agent
from learner.run_summary import summarize


class TrainSpec(Section):
    """One training run; every field can come from YAML (``--config``) or the command line."""

    env: str = Field(
        "NSCartPoleContinuous-v0",
        description="the Gymnasium environment id (a registered one, e.g. NSCartPoleContinuous-v0,"
        " NSPendulum-v0, NSReach-v0)",
    )
    env_kwargs: dict[str, Any] = Field(
        default_factory=dict,
        description="keyword arguments of the environment (e.g. preset: slow); the environment's seed is"
        " seed's unless given here",
    )
    algo: Algo = Field(
        "adaptiveh",
        description="the learning algorithm: adaptiveh, rkhs (fixed horizon), or a stable-baselines3"
        " baseline (td3, ddpg, sac, ppo)",
    )
    steps: int = Field(
        default=20_000,
        ge=1,
        description="total environment steps of the run (a resumed run counts those already done)",
    )
    seed: int = Field(0, description="seeds the environment and the agent: one seed, one run")
    agent: dict[str, Any] = Field(
        default_factory=dict, description="the algorithm's hyperparameters, checked against algo"
    )
    checkpoint_every: int = Field(
        default=5_000,
        ge=1,
        description="save a checkpoint every this many environment steps (and at the end)",
    )
    # Every episode's seeded reset draws a new world (the stack's actor reseeds the arm's each episode);
    # by default only the first reset's seed counts, as in the benches (experiments.envs).
    reseed_episodes: bool = False

    @field_validator("env")
    @classmethod
    def _registered(cls, env: str) -> str:
        if env not in gym.registry:
            raise ValueError(f"unknown environment {env!r}")
        return env


def load_spec(path: str | Path | None, overrides: dict[str, Any]) -> TrainSpec:
    data = load_yaml(path) if path else {}
    data.update({k: v for k, v in overrides.items() if v is not None})
    return parse(TrainSpec, data, str(path or "train"))


def make_env(spec: TrainSpec, resumed: bool = False) -> gym.Env:
    """``spec``'s env from the benches' factory, so a seed is the same world (``resumed``: drawn already)."""
    kwargs = {"seed": spec.seed, **spec.env_kwargs}
    try:
        return envs.make_env(spec.env, kwargs, spec.reseed_episodes, seeded=resumed)
    except TypeError as exc:
        raise ConfigError(f"env_kwargs: {exc}") from None


def build_agent(spec: TrainSpec, env: gym.Env) -> Agent:
    try:
        return make_agent(spec.algo, env, spec.seed, spec.agent)
    except (TypeError, ValueError) as exc:
        raise ConfigError(f"agent: {exc}") from None


def plot_run(log: RunLog, title: str, path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    has_segments = bool(log.segments)
    fig, axes = plt.subplots(1, 3 if has_segments else 1, figsize=(14.5 if has_segments else 6, 4))
    axes = np.atleast_1d(axes)
    steps = [e.global_step for e in log.episodes]
    rets = np.array([e.ret for e in log.episodes])
    axes[0].plot(steps, rets, ".", alpha=0.35, label="episode return")
    if len(rets) >= 5:
        k = max(5, len(rets) // 20)
        smooth = np.convolve(rets, np.ones(k) / k, mode="valid")
        axes[0].plot(steps[k - 1 :], smooth, "-", lw=2, label=f"moving mean ({k} episodes)")
    axes[0].set(xlabel="environment step", ylabel="return", title=title)
    axes[0].legend()
    if has_segments:
        seg_steps = [s.global_step for s in log.segments]
        colors = {"retreat": "tab:red", "h_max": "tab:blue", "episode_end": "tab:gray"}
        for reason, color in colors.items():
            pts = [(s.global_step, s.H) for s in log.segments if s.reason == reason]
            if pts:
                axes[1].plot(*zip(*pts, strict=True), ".", ms=3, color=color, alpha=0.5, label=reason)
        axes[1].set(xlabel="environment step", ylabel="segment length H", title="adaptive window H")
        axes[1].legend()
        axes[2].hist([s.H for s in log.segments], bins=30, color="tab:purple")
        axes[2].set(xlabel="H", ylabel="segments", title=f"H distribution ({len(seg_steps)} segments)")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def train(spec: TrainSpec, out: str | Path, resume: bool = True, progress: bool = True) -> dict[str, Any]:
    """Run (or resume) ``spec``; returns the result dict also written to ``out/result.json``."""
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    ckpt = out / "checkpoint.pkl"
    resumed = resume and ckpt.exists()
    env = make_env(spec, resumed)
    agent = build_agent(spec, env)
    if resumed:
        agent.load(ckpt)
    start_step = agent.log.global_step
    remaining = max(spec.steps - start_step, 0)
    bar = tqdm(
        total=spec.steps,
        initial=start_step,
        disable=not progress,
        unit="step",
        desc=f"{spec.algo} {spec.env}",
        mininterval=0.5,
    )
    t0 = time.perf_counter()

    def on_step(step: int, log: RunLog) -> None:
        bar.update(1)
        if step % spec.checkpoint_every == 0:
            agent.save(ckpt)
        if log.episodes and step % 200 == 0:
            postfix = {"ep": len(log.episodes), "ret": f"{log.episodes[-1].ret:.1f}"}
            if log.segments:
                postfix["H"] = log.segments[-1].H
            bar.set_postfix(postfix)

    try:
        agent.learn(remaining, callback=on_step)
    finally:
        agent.save(ckpt)
        bar.close()
    wall = time.perf_counter() - t0
    result = {
        "spec": spec.model_dump(),
        "agent_config": agent.config.model_dump(mode="json"),  # type: ignore[attr-defined]
        "summary": summarize(agent.log),
        "wall_clock_s": wall,
        "steps_this_session": agent.log.global_step - start_step,
        "steps_per_s": (agent.log.global_step - start_step) / wall if wall > 0 else None,
        "nonfinite_skipped": getattr(agent, "nonfinite_skipped", 0),
        **agent.log.to_dict(),
    }
    (out / "result.json").write_text(json.dumps(result, indent=1))
    plot_run(agent.log, f"{spec.algo} on {spec.env} (seed {spec.seed})", out / "curve.png")
    env.close()
    return result
