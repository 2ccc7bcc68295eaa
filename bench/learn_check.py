"""Does the default AdaptiveH learn stationary continuous CartPole, and does it stay learned?

Owed from the learner issue (#2). Per seed: train the default config (``configs/cartpole.yaml``'s agent,
preset ``stationary``) for up to ``--steps`` (100k), and every ``--every`` steps evaluate the mean action
(no exploration) for 10 episodes on a separate env. ``reached``: the 10-episode mean hit 400 at some
evaluation (``steps_to_400`` the first one); ``final``: the evaluation at the end. The bar: reached AND
still >= 400 at the end for at least 4 of 5 seeds. Writes ``results/learn_check.json`` and prints it.

    python bench/learn_check.py                      # 5 seeds x 100k steps (~10-20 min on one core)
    python bench/learn_check.py --seeds 1 --steps 20000 --every 5000 --out /tmp/lc.json
"""

from __future__ import annotations

import argparse
import json
import time
from multiprocessing import Pool
from pathlib import Path

import gymnasium as gym
import numpy as np
import yaml

import sim  # noqa: F401  (registers the NS environments)
from learner.registry import make_agent

ROOT = Path(__file__).resolve().parents[1]
BAR = 400.0


def evaluate(agent, seed: int, episodes: int = 10) -> float:
    """Mean return of the mean action over ``episodes`` fresh episodes (its own env and seeds)."""
    env = gym.make("NSCartPoleContinuous-v0", preset="stationary")
    returns = []
    for k in range(episodes):
        obs, _ = env.reset(seed=10_000 * (seed + 1) + k)
        done, total = False, 0.0
        while not done:
            obs, r, terminated, truncated, _ = env.step(agent.predict(obs, deterministic=True))
            total += r
            done = terminated or truncated
        returns.append(total)
    return float(np.mean(returns))


def check_seed(args: tuple[int, int, int]) -> dict:
    seed, steps, every = args
    agent_cfg = yaml.safe_load((ROOT / "configs" / "cartpole.yaml").read_text())["agent"]
    agent = make_agent("adaptiveh", gym.make("NSCartPoleContinuous-v0", preset="stationary"), seed, agent_cfg)
    t0, curve = time.perf_counter(), []
    for done in range(every, steps + 1, every):
        agent.learn(every)
        curve.append((done, evaluate(agent, seed)))
        print(f"seed {seed}: {done} steps, evaluation {curve[-1][1]:.0f}", flush=True)
    first = next((s for s, ret in curve if ret >= BAR), None)
    return {
        "seed": seed,
        "reached": first is not None,
        "steps_to_400": first,
        "final_evaluation": curve[-1][1],
        "still_400_at_end": curve[-1][1] >= BAR,
        "curve": curve,
        "wall_clock_s": round(time.perf_counter() - t0, 1),
    }


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--seeds", type=int, default=5)
    p.add_argument("--steps", type=int, default=100_000)
    p.add_argument("--every", type=int, default=5_000)
    p.add_argument("--jobs", type=int, default=2)
    p.add_argument("--out", default=str(ROOT / "results" / "learn_check.json"))
    a = p.parse_args()
    with Pool(a.jobs) as pool:
        seeds = pool.map(check_seed, [(s, a.steps, a.every) for s in range(a.seeds)])
    passed = sum(s["reached"] and s["still_400_at_end"] for s in seeds)
    out = {
        "env": "NSCartPoleContinuous-v0 (stationary)",
        "config": "configs/cartpole.yaml agent",
        "steps": a.steps,
        "evaluation": f"10 episodes, mean action, every {a.every} steps",
        "bar": f"reached {BAR:.0f} and still >= {BAR:.0f} at {a.steps} steps for >= 4 of 5 seeds",
        "seeds_passing": passed,
        "passes": passed >= min(4, a.seeds),
        "per_seed": seeds,
    }
    Path(a.out).parent.mkdir(parents=True, exist_ok=True)
    Path(a.out).write_text(json.dumps(out, indent=1))
    print(json.dumps({k: v for k, v in out.items() if k != "per_seed"}, indent=1))


if __name__ == "__main__":
    main()
