"""The paper's experiments ("Results Analysis"): which runs make AdaptiveH vs TD3, DDPG, SAC, PPO and
fixed-H RKHS.

One plan of runs: environment x algorithm x seed, equal env steps per environment, the same seeded
non-stationary schedule for every algorithm at a given seed. ``runner`` executes it (resumable, one
process per run), ``report`` and ``figures`` read whatever runs are finished.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from pydantic import Field

from common.config import Section
from learner.registry import ALGOS

# The bench's methods, in the paper's order: the learner registry's (``learner.registry.ALGOS``); an
# algorithm the registry gains is appended.
PAPER_ORDER = ("adaptiveh", "td3", "ddpg", "sac", "ppo", "rkhs")
PAPER_ALGOS: tuple[str, ...] = tuple(dict.fromkeys((*PAPER_ORDER, *ALGOS)))
SB3_ALGOS = ("td3", "ddpg", "sac", "ppo")  # the stable-baselines3 baselines: zoo hyperparameters
ALGO_LABELS = {
    "adaptiveh": "AdaptiveH",
    "td3": "TD3",
    "ddpg": "DDPG",
    "sac": "SAC",
    "ppo": "PPO",
    "rkhs": "RKHS fixed-H",
}
CONFIG_DIR = Path(__file__).resolve().parent.parent / "configs"


class EnvSpec(Section):
    """One environment setting of the paper; ``threshold`` is the stated return for steps-to-threshold."""

    key: str = Field(
        description="the setting's name in the plan (e.g. cartpole_slow): run names and result files use it"
    )
    env_id: str = Field(description="the Gymnasium environment id")
    preset: str = Field(description="the environment's non-stationarity preset (e.g. slow)")
    label: str = Field(description="the setting's name on figures and in tables")
    steps: int = Field(ge=1, description="environment steps per run")
    quick_steps: int = Field(
        ge=1, description="environment steps per run of the quick plan (a smoke test of the bench)"
    )
    threshold: float = Field(
        description="the return that counts as reaching the task, for steps-to-threshold"
    )
    config_file: str  # configs/<file>: its ``agent`` section tunes AdaptiveH and the RKHS baseline


# Budgets: CartPole and Pendulum 20k steps (the zoo's Pendulum budget), Reach 10k (PyBullet + IK per
# step). Thresholds: CartPole 195 (CartPole-v0's "solved" level), Pendulum -400 (upright most of the
# episode; random play scores about -1200), Reach -5 over its 50-step episodes (configs/reach.yaml): a
# mean distance of 10 cm; random play scores -8 to -28, a proportional controller -1 to -5.
ENVS: dict[str, EnvSpec] = {
    e.key: e
    for e in (
        EnvSpec(
            key="cartpole_slow",
            env_id="NSCartPoleContinuous-v0",
            preset="slow",
            label="NS CartPole (slow)",
            steps=20_000,
            quick_steps=4_000,
            threshold=195.0,
            config_file="cartpole.yaml",
        ),
        EnvSpec(
            key="pendulum_slow",
            env_id="NSPendulum-v0",
            preset="slow",
            label="NS Pendulum (slow)",
            steps=20_000,
            quick_steps=4_000,
            threshold=-400.0,
            config_file="pendulum.yaml",
        ),
        EnvSpec(
            key="reach_slow",
            env_id="NSReach-v0",
            preset="slow",
            label="NS Reach (slow)",
            steps=10_000,
            quick_steps=2_000,
            threshold=-5.0,
            config_file="reach.yaml",
        ),
        EnvSpec(
            key="cartpole_fast",
            env_id="NSCartPoleContinuous-v0",
            preset="fast",
            label="NS CartPole (fast)",
            steps=20_000,
            quick_steps=4_000,
            threshold=195.0,
            config_file="cartpole.yaml",
        ),
    )
}
DRIFT_KEYS = {
    "NSCartPoleContinuous-v0": "gravity",
    "NSPendulum-v0": "noise_bound",
    "NSReach-v0": "target_speed",
}
MAIN_ENVS = ("cartpole_slow", "pendulum_slow", "reach_slow")  # paper Fig. main results (d)-(f)
SPEED_ENVS = ("cartpole_slow", "cartpole_fast")  # paper Figs. H and fast comparison
FULL_SEEDS = 5
QUICK_SEEDS = 2


@dataclass(frozen=True)
class RunSpec:
    """One run of the plan; its name is its file name, so a changed budget is a different run."""

    env: str
    algo: str
    seed: int
    steps: int
    config: dict[str, Any] = field(default_factory=dict, hash=False, compare=False)
    env_kwargs: dict[str, Any] = field(default_factory=dict, hash=False, compare=False)

    @property
    def name(self) -> str:
        return f"{self.env}__{self.algo}__s{self.seed}__{self.steps}"

    @property
    def env_spec(self) -> EnvSpec:
        """The setting this run plays (other benches' specs may name settings outside ``ENVS``)."""
        return ENVS[self.env]


@dataclass
class Plan:
    runs: list[RunSpec]
    envs: list[str]
    algos: list[str]
    seeds: list[int]
    steps: dict[str, int]
    quick: bool

    def finished(self, runs: dict[str, dict[str, Any]], env: str, algo: str) -> list[dict[str, Any]]:
        """The finished runs (loaded run files) of one (env, algo) group, in plan order."""
        return [runs[r.name] for r in self.runs if r.env == env and r.algo == algo and r.name in runs]


def _config_file(env: EnvSpec) -> dict[str, Any]:
    path = CONFIG_DIR / env.config_file
    if not path.is_file():
        return {}
    import yaml

    return dict(yaml.safe_load(path.read_text()) or {})


def agent_config(env: EnvSpec, algo: str) -> dict[str, Any]:
    """Hyperparameters per algorithm: RKHS learners from ``configs/<env>.yaml`` (the learner's tuned
    values, the fixed-H baseline uses the same ones), TD3/DDPG/SAC/PPO the zoo's Pendulum-v1 values on
    every env (``learner.baselines``: the defaults of its config classes)."""
    if algo in SB3_ALGOS:
        return {}
    return dict(_config_file(env).get("agent") or {})


def env_kwargs(env: EnvSpec, seed: int) -> dict[str, Any]:
    """The env's constructor arguments: ``configs/<env>.yaml``'s ``env_kwargs`` (e.g. Reach's episode
    length), with this setting's preset and the run's seed; the same for every algorithm."""
    preset_key = "motion" if env.env_id == "NSReach-v0" else "preset"
    return {**(_config_file(env).get("env_kwargs") or {}), preset_key: env.preset, "seed": seed}


def build_plan(
    quick: bool = False,
    seeds: int | None = None,
    steps: int | None = None,
    envs: list[str] | None = None,
    algos: list[str] | None = None,
    overrides: dict[str, dict[str, Any]] | None = None,
) -> Plan:
    """The runs of the full (or ``quick``) experiment, ordered so that a partial run is already useful."""
    env_keys = list(envs or ENVS)
    algo_keys = list(algos or PAPER_ALGOS)
    for key in env_keys:
        if key not in ENVS:
            raise ValueError(f"unknown env {key!r}; choose from {sorted(ENVS)}")
    for algo in algo_keys:
        if algo not in PAPER_ALGOS:
            raise ValueError(f"unknown algo {algo!r}; choose from {PAPER_ALGOS}")
    n_seeds = seeds if seeds is not None else (QUICK_SEEDS if quick else FULL_SEEDS)
    if n_seeds < 1:
        raise ValueError(f"seeds must be >= 1, got {n_seeds}")
    if steps is not None and steps < 1:
        raise ValueError(f"steps must be >= 1, got {steps}")
    budget = {k: steps or (ENVS[k].quick_steps if quick else ENVS[k].steps) for k in env_keys}
    runs = []
    for seed in range(n_seeds):
        for key in env_keys:
            for algo in algo_keys:
                cfg = {**agent_config(ENVS[key], algo), **(overrides or {}).get(algo, {})}
                runs.append(RunSpec(key, algo, seed, budget[key], cfg, env_kwargs(ENVS[key], seed)))
    # Cheap runs first (the RKHS learners on CartPole/Pendulum: ~1 min each, 10-20x faster than TD3/DDPG),
    # then everything else seed-major (Reach costs PyBullet + IK per step for every algorithm): a partial
    # experiment then already holds every seed for the H claim and complete seeds of the rest. The order
    # never changes a result: every run is its own process with its own seed.
    runs.sort(key=lambda r: (not _cheap(r), r.seed))
    return Plan(runs, env_keys, algo_keys, list(range(n_seeds)), budget, quick)


def _cheap(run: RunSpec) -> bool:
    return run.algo in ("adaptiveh", "rkhs") and ENVS[run.env].env_id != "NSReach-v0"
