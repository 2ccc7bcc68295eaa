"""The handoff in-process: the stack's learner (its agent, plan execution) on NS Reach, started from the
in-process policy bench/handoff.py hands to the stack, on the world it was trained on (servo gain 0.3)
and on a slower arm (0.1, the slow_arm gap's), learning on or frozen; and from scratch. Minutes where
the stack bench takes hours, so a change to how the learner learns after a handoff is seen here first.
``--score noise`` (the default) scores each sample as the stack's actor does; ``executed`` as the plans
experiment's in-process runs did (``learner.agent.plan_score``). ``--handoff-step-scale``: the
fine-tuning step after the handoff (``learner.agent.handoff_step_scale``). ``--agent KEY=VALUE``: any
other agent key over the stack's (``learner.agent``; YAML values), e.g. the exploration schedule
(docs/handoff.md, "Where we lose", reads ``schedule_steps`` and ``schedule_gate``).

Per run: success by quarter of 6000 steps. Each run is appended under its label to
``results/handoff_inprocess.json`` (a label run again replaces its runs).

    python bench/handoff_inprocess.py [--score noise|executed] [--seeds 0 1 2] [--variants learn ...]
    python bench/handoff_inprocess.py --variants scratch --seeds $(seq 0 13) --agent schedule_steps=6000 \
        --label "scratch, schedule 6000"
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
from pathlib import Path
from typing import Any

import gymnasium as gym
import numpy as np

import tasks  # noqa: F401  (registers NSReach-v0)
from deploy.config import load_stack_config
from learner.registry import make_agent

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "bench"))
from handoff import agent_override, source_policy  # noqa: E402

OUT = ROOT / "results" / "handoff_inprocess.json"
STEPS = 6000
GAINS = {"trained_world": 0.3, "slow_arm": 0.1}  # robot.mock.position_gain: configs/gaps/slow_arm.yaml's


def run(seed: int, variant: str, gain: float, agent: dict[str, Any]) -> dict[str, Any]:
    agent_cfg = load_stack_config(ROOT / "configs" / "sim.yaml").learner.agent_config() | agent
    if variant == "frozen":
        agent_cfg["frozen"] = True
    env = gym.make("NSReach-v0", motion="slow", max_episode_steps=50, seed=seed)
    env.unwrapped.scene.position_gain = gain
    agent = make_agent("rkhs" if variant == "fixed_h" else "adaptiveh", env, seed, agent_cfg)
    if variant != "scratch":
        agent.start_from(source_policy(seed))
    agent.learn(STEPS)
    quarters = [
        [e.success for e in agent.log.episodes if k * STEPS / 4 < e.global_step <= (k + 1) * STEPS / 4]
        for k in range(4)
    ]
    return {"success_by_quarter": [round(float(np.mean(q)), 3) for q in quarters]}


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--score", default="noise", choices=["noise", "executed"], help="agent.plan_score")
    ap.add_argument("--label", default=None, help="the runs' label (default: the score)")
    ap.add_argument("--seeds", nargs="+", type=int, default=[0, 1, 2])
    ap.add_argument(
        "--variants",
        nargs="+",
        default=["learn", "frozen", "scratch"],
        choices=["learn", "frozen", "scratch", "fixed_h"],
        help="fixed_h: handed off and learning with segments of agent.fixed_h steps (the RKHS baseline)",
    )
    ap.add_argument("--handoff-step-scale", type=float, default=1.0, help="agent.handoff_step_scale")
    ap.add_argument("--agent", nargs="*", default=[], metavar="KEY=VALUE", help="learner.agent keys (YAML)")
    args = ap.parse_args()
    args.label = args.label or f"{args.score} score"
    overrides = dict(agent_override(kv) for kv in args.agent)
    import learner

    tree = Path(learner.__file__).resolve().parents[1]
    commit = subprocess.run(["git", "rev-parse", "HEAD"], cwd=tree, capture_output=True, text=True).stdout
    data = json.loads(OUT.read_text()) if OUT.exists() else {"steps": STEPS, "runs": []}
    data["runs"] = [r for r in data["runs"] if r["label"] != args.label]
    for variant in args.variants:
        for world, gain in GAINS.items():
            for seed in args.seeds:
                row = {"label": args.label, "commit": commit.strip(), "variant": variant, "world": world}
                row |= {"seed": seed, "score": args.score, "handoff_step_scale": args.handoff_step_scale}
                if overrides:
                    row["agent"] = overrides
                agent = {"plan_score": args.score, "handoff_step_scale": args.handoff_step_scale} | overrides
                row |= run(seed, variant, gain, agent)
                print(json.dumps(row), flush=True)
                data["runs"].append(row)
    OUT.write_text(json.dumps(data, indent=1))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
