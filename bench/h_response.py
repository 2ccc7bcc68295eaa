"""Does H respond to an abrupt change of the world? NS CartPole whose gravity jumps by +40 % at 10k steps.

Owed from the learner issue (#2). For the ``slow`` and ``fast`` drift presets, each with the jump added,
5 seeds: mean segment length H over the 2k steps before the jump and the 2k after, for AdaptiveH in the
closed loop (retreat ``local``, the configs/cartpole.yaml agent) and in plan mode (retreat ``plan``,
threshold 0.8; a segment is a committed plan over the nominal model). Reported as it comes out, with a
bootstrap interval of the after - before difference. Writes ``results/h_response.json``.

    python bench/h_response.py            # 2 presets x 2 modes x 5 seeds x 12k steps (~10 min on 2 cores)
"""

from __future__ import annotations

import argparse
import json
from multiprocessing import Pool
from pathlib import Path

import gymnasium as gym
import numpy as np
import yaml

import sim  # noqa: F401  (registers the NS environments)
from experiments.stats import bootstrap_mean
from learner.registry import make_agent
from sim.cartpole import G0, GRAVITY_PRESETS

ROOT = Path(__file__).resolve().parents[1]
JUMP_AT, WINDOW = 10_000, 2_000
MODES = {
    "closed_loop": {},
    "plan": {"execution": "plan", "retreat": "plan", "retreat_threshold": 0.8},
}


def one_run(args: tuple[str, str, int]) -> dict:
    preset, mode, seed = args
    drift = GRAVITY_PRESETS[preset].model_copy(update={"step_at": JUMP_AT, "step_size": 0.4 * G0})
    env = gym.make("NSCartPoleContinuous-v0", drift=drift, seed=seed)
    agent_cfg = yaml.safe_load((ROOT / "configs" / "cartpole.yaml").read_text())["agent"]
    agent = make_agent("adaptiveh", env, seed, {**agent_cfg, **MODES[mode]})
    agent.learn(JUMP_AT + WINDOW)

    def mean_h(lo: int, hi: int) -> float:
        hs = [s.H for s in agent.log.segments if lo < s.global_step <= hi]
        return float(np.mean(hs)) if hs else float("nan")

    before, after = mean_h(JUMP_AT - WINDOW, JUMP_AT), mean_h(JUMP_AT, JUMP_AT + WINDOW)
    print(f"{preset} {mode} seed {seed}: H before {before:.1f}, after {after:.1f}", flush=True)
    return {"preset": preset, "mode": mode, "seed": seed, "H_before": before, "H_after": after}


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--seeds", type=int, default=5)
    p.add_argument("--jobs", type=int, default=2)
    p.add_argument("--out", default=str(ROOT / "results" / "h_response.json"))
    a = p.parse_args()
    jobs = [(pr, mo, s) for pr in ("slow", "fast") for mo in MODES for s in range(a.seeds)]
    with Pool(a.jobs) as pool:
        runs = pool.map(one_run, jobs)
    summary = {}
    for preset in ("slow", "fast"):
        for mode in MODES:
            rs = [r for r in runs if r["preset"] == preset and r["mode"] == mode]
            diff = bootstrap_mean([r["H_after"] - r["H_before"] for r in rs])  # paired by seed
            summary[f"{preset}/{mode}"] = {
                "H_before_mean": float(np.nanmean([r["H_before"] for r in rs])),
                "H_after_mean": float(np.nanmean([r["H_after"] for r in rs])),
                "after_minus_before": diff,
                "shorter_after_jump": diff["hi"] is not None and diff["hi"] < 0,
            }
    out = {
        "env": "NSCartPoleContinuous-v0, gravity +40 % at step 10000 on top of the preset's drift",
        "window_steps": WINDOW,
        "summary": summary,
        "runs": runs,
    }
    Path(a.out).parent.mkdir(parents=True, exist_ok=True)
    Path(a.out).write_text(json.dumps(out, indent=1))
    print(json.dumps(summary, indent=1))


if __name__ == "__main__":
    main()
