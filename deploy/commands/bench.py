"""``adaptiveh bench paper``: the command line of the paper's experiments (``experiments.paper``)."""

from __future__ import annotations

import argparse
import os
from pathlib import Path


def register(subparsers: argparse._SubParsersAction) -> None:
    bench = subparsers.add_parser("bench", help="benchmarks: the paper's experiments")
    kinds = bench.add_subparsers(dest="bench", required=True)
    paper = kinds.add_parser(
        "paper",
        help="AdaptiveH vs TD3, DDPG, RKHS fixed-H: learning curves, H window, slow vs fast, verdicts",
        description="Runs every unfinished run of the plan (one process per run, resumable), then writes "
        "summary.json and the PNG figures from all finished runs.",
    )
    paper.add_argument("--quick", action="store_true", help="2 seeds, 4k steps (2k on Reach): < 20 min")
    paper.add_argument(
        "--out", type=Path, default=None, help="results/paper (results/paper_quick if --quick)"
    )
    paper.add_argument("--jobs", type=int, default=os.cpu_count() or 1, help="runs in parallel")
    paper.add_argument("--seeds", type=int, default=None, help="override the number of seeds")
    paper.add_argument("--steps", type=int, default=None, help="override the step budget of every env")
    paper.add_argument("--envs", nargs="+", default=None, help="subset of envs (default: all)")
    paper.add_argument("--algos", nargs="+", default=None, help="subset of algorithms (default: all)")
    paper.add_argument(
        "--report-only", action="store_true", help="only rebuild figures/JSON from finished runs"
    )
    paper.add_argument("--no-progress", action="store_true", help="no progress bar")
    paper.set_defaults(func=_paper)


def _paper(args: argparse.Namespace) -> int:
    from experiments.paper import main_paper
    from experiments.tables import format_verdicts

    if args.jobs < 1:
        raise SystemExit("--jobs must be >= 1")
    out = args.out or Path("results/paper_quick" if args.quick else "results/paper")
    summary = main_paper(
        quick=args.quick,
        out=out,
        jobs=args.jobs,
        seeds=args.seeds,
        steps=args.steps,
        envs=args.envs,
        algos=args.algos,
        report_only=args.report_only,
        progress=not args.no_progress,
    )
    print(format_verdicts(summary))
    print(f"figures and summary.json in {out}; missing runs: {len(summary['missing_runs'])}")
    return 1 if summary["failed_runs"] else 0
