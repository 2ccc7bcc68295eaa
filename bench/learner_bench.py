"""Learner cost: steps/s and decision latency at dictionary budgets 250/500/1000 with the dictionaries
full, and memory over a 100k-step run (it must stop growing once the dictionaries are full).

Owed from the learner issue (#2). NS CartPole (slow drift), AdaptiveH (retreat ``local``) and the fixed-H
learner, one core, one BLAS thread. A run first learns until both dictionaries hold ``budget`` centres
(ALD threshold 0 while filling: every new state is admitted, so they fill within ``budget`` steps), then,
back at the default threshold 0.05, times ``--timed`` steps
and ``--decisions`` action choices. Memory: the process's resident set size at 10k, 25k, 50k, 75k and
100k steps of one default AdaptiveH run. Writes ``results/learner_bench.json`` and prints it.

    python bench/learner_bench.py                 # ~10 min on one core
    python bench/learner_bench.py --quick         # budgets 250 only, 20k-step memory run
"""

from __future__ import annotations

import os

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")  # one core: small matrices, BLAS threads only contend

import argparse  # noqa: E402
import json  # noqa: E402
import platform  # noqa: E402
import time  # noqa: E402
from pathlib import Path  # noqa: E402

import gymnasium as gym  # noqa: E402
import numpy as np  # noqa: E402

import sim  # noqa: E402, F401  (registers the NS environments)
from learner.registry import make_agent  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]


def rss_mb() -> float:
    """Current resident set size of this process (Linux ``/proc``), MB."""
    pages = int(Path("/proc/self/statm").read_text().split()[1])
    return pages * os.sysconf("SC_PAGE_SIZE") / 2**20


def _agent(algo: str, budget: int, ald: float):
    cfg = {"policy_budget": budget, "critic_budget": budget, "policy_ald": ald, "critic_ald": ald}
    return make_agent(algo, gym.make("NSCartPoleContinuous-v0", preset="slow"), 0, cfg)


def speed(algo: str, budget: int, timed: int, decisions: int, fill_cap: int = 60_000) -> dict:
    agent = _agent(algo, budget, ald=0.0)  # every new state is admitted: full after ``budget`` steps
    steps = 0
    while min(len(agent.policy.f), len(agent.critic.dictionary)) < budget and steps < fill_cap:
        agent.learn(500)
        steps += 500
    full = (len(agent.policy.f), len(agent.critic.dictionary))
    # Timed at the default ALD threshold: a full dictionary then projects most samples and admits (and
    # prunes for) the novel ones, as in a normal run.
    agent.policy.f.ald_threshold = agent.critic.ald_threshold = 0.05
    t0 = time.perf_counter()
    agent.learn(timed)
    steps_per_s = timed / (time.perf_counter() - t0)
    obs, _ = agent.env.reset(seed=123)
    latency = []
    for _ in range(decisions):
        t = time.perf_counter()
        agent.predict(obs, deterministic=False)
        latency.append(time.perf_counter() - t)
    lat_ms = np.asarray(latency) * 1e3
    return {
        "algo": algo,
        "budget": budget,
        "filled_after_steps": steps,
        "dictionary_sizes": {"policy": full[0], "critic": full[1]},
        "steps_per_s": round(steps_per_s, 1),
        "decision_latency_ms": {
            "p50": round(float(np.percentile(lat_ms, 50)), 4),
            "p99": round(float(np.percentile(lat_ms, 99)), 4),
        },
    }


def memory(total: int, budget: int = 300) -> list[dict]:
    """RSS along one AdaptiveH run whose dictionaries are full after the first ``budget`` steps (ALD 0
    while filling, the default 0.05 after): 10k..100k is the full regime."""
    agent = _agent("adaptiveh", budget, ald=0.0)
    agent.learn(budget)
    agent.policy.f.ald_threshold = agent.critic.ald_threshold = 0.05
    marks = sorted({m for m in (10_000, 25_000, 50_000, 75_000, total) if m <= total})
    out, done = [], 0
    for mark in marks:
        agent.learn(mark - done)
        done = mark
        out.append(
            {
                "steps": mark,
                "rss_mb": round(rss_mb(), 1),
                "policy_centres": len(agent.policy.f),
                "critic_centres": len(agent.critic.dictionary),
                "segments": len(agent.log.segments),
            }
        )
        print(out[-1], flush=True)
    return out


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--quick", action="store_true")
    p.add_argument("--timed", type=int, default=3000)
    p.add_argument("--decisions", type=int, default=2000)
    p.add_argument("--out", default=str(ROOT / "results" / "learner_bench.json"))
    a = p.parse_args()
    budgets = (250,) if a.quick else (250, 500, 1000)
    rows = []
    for budget in budgets:
        for algo in ("adaptiveh", "rkhs"):
            rows.append(speed(algo, budget, a.timed, a.decisions))
            print(rows[-1], flush=True)
    mem = memory(20_000 if a.quick else 100_000)
    grow = mem[-1]["rss_mb"] - mem[0]["rss_mb"]
    out = {
        "machine": {"cpu": platform.processor() or platform.machine(), "cores_used": 1},
        "env": "NSCartPoleContinuous-v0 (slow)",
        "speed": rows,
        "memory": mem,
        "rss_growth_mb_after_first_mark": round(grow, 1),
    }
    Path(a.out).parent.mkdir(parents=True, exist_ok=True)
    Path(a.out).write_text(json.dumps(out, indent=1))
    print(json.dumps(out, indent=1))


if __name__ == "__main__":
    main()
