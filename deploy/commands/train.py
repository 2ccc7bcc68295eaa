"""``adaptiveh train``: the command line of one in-process training run (``experiments.training``)."""

from __future__ import annotations

import argparse
import json
import sys

from common.config import ConfigError


def register(subparsers: argparse._SubParsersAction) -> None:
    p = subparsers.add_parser("train", help="train an agent in-process on one environment")
    p.add_argument("--env", help="gymnasium id, e.g. NSCartPoleContinuous-v0, NSPendulum-v0, NSReach-v0")
    p.add_argument("--algo", help="adaptiveh | rkhs | td3 | ddpg | sac | ppo")
    p.add_argument("--steps", type=int)
    p.add_argument("--seed", type=int)
    p.add_argument("--preset", help="non-stationarity preset: stationary | slow | fast")
    p.add_argument("--out", required=True, help="output folder (result.json, curve.png, checkpoint.pkl)")
    p.add_argument("--config", help="YAML with any TrainSpec key (env, env_kwargs, algo, steps, seed, agent)")
    p.add_argument("--fresh", action="store_true", help="ignore an existing checkpoint in --out")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from experiments.training import load_spec, train

    overrides = {"env": args.env, "algo": args.algo, "steps": args.steps, "seed": args.seed}
    try:
        spec = load_spec(args.config, overrides)
        if args.preset:
            spec = spec.model_copy(update={"env_kwargs": {**spec.env_kwargs, "preset": args.preset}})
        result = train(spec, args.out, resume=not args.fresh)
    except ConfigError as exc:
        print(f"config error: {exc}", file=sys.stderr)
        return 2
    print(
        json.dumps(
            {
                "out": args.out,
                **result["summary"],
                "wall_clock_s": round(result["wall_clock_s"], 1),
                "steps_per_s": round(result["steps_per_s"] or 0, 1),
            },
            indent=1,
        )
    )
    print(f"wrote {args.out}/result.json and {args.out}/curve.png")
    return 0
