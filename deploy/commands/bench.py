"""``adaptiveh bench paper`` / ``bench plans``: the paper's experiments (``experiments.paper``) and the plans
experiment (``experiments.plans``)."""

from __future__ import annotations

import argparse
import importlib.util
import os
from pathlib import Path


def register(subparsers: argparse._SubParsersAction) -> None:
    bench = subparsers.add_parser("bench", help="benchmarks: the paper's experiments, the plans experiment")
    kinds = bench.add_subparsers(dest="bench", required=True)
    paper = kinds.add_parser(
        "paper",
        help="AdaptiveH vs TD3, DDPG, SAC, PPO, RKHS fixed-H: learning curves, H window, slow vs fast, "
        "verdicts, cost per method",
        description="Runs every unfinished run of the plan (one process per run, resumable; locally or as "
        "Ray tasks on a cluster), then writes summary.json and the PNG figures from all finished runs and "
        "prints the verdicts and each method's wall-clock, throughput and peak memory.",
    )
    paper.add_argument("--quick", action="store_true", help="2 seeds, 4k steps (2k on Reach): a smoke run")
    paper.add_argument(
        "--out", type=Path, default=None, help="results/paper (results/paper_quick if --quick)"
    )
    _executor_args(paper)
    paper.add_argument("--seeds", type=int, default=None, help="override the number of seeds")
    paper.add_argument("--steps", type=int, default=None, help="override the step budget of every env")
    paper.add_argument("--envs", nargs="+", default=None, help="subset of envs (default: all)")
    paper.add_argument("--algos", nargs="+", default=None, help="subset of algorithms (default: all)")
    paper.add_argument(
        "--report-only", action="store_true", help="only rebuild figures/JSON from finished runs"
    )
    paper.add_argument("--no-progress", action="store_true", help="no progress bar")
    paper.set_defaults(func=_paper)
    plans = kinds.add_parser(
        "plans",
        help="plan execution: AdaptiveH against the fixed-H front (return vs re-plans), latency, H slow/fast",
        description="Every run in plan execution: fixed-H RKHS at H in {1,2,5,10,20,50} as a front, "
        "AdaptiveH (plan retreat at 0.5/0.8/0.9, local retreat) as points, TD3 and SAC in plan mode at "
        "H = 10 (NS CartPole fast, NS Reach slow, seeds 0-2), a learner-latency sweep, on NS "
        "CartPole slow/fast, NS Pendulum, NS Reach slow/fast, seeds 0-4. Resumable; writes summary.json, "
        "summary.md and front.png, latency.png, h_drift.png from all finished runs.",
    )
    plans.add_argument("--quick", action="store_true", help="2 seeds, 1k steps (500 on Reach): a smoke run")
    plans.add_argument(
        "--out", type=Path, default=None, help="results/plans (results/plans_quick if --quick)"
    )
    _executor_args(plans)
    plans.add_argument("--seeds", type=int, default=None, help="override the number of seeds")
    plans.add_argument("--latency-seeds", type=int, default=None, help="seeds of the latency sweep")
    plans.add_argument("--steps", type=int, default=None, help="override the step budget of every setting")
    plans.add_argument("--settings", nargs="+", default=None, help="subset of settings (default: all)")
    plans.add_argument(
        "--paper-dir",
        type=Path,
        default=Path("results/paper"),
        help="the paper bench's results: TD3/DDPG/SAC closed-loop (H = 1) reference points",
    )
    plans.add_argument(
        "--report-only", action="store_true", help="only rebuild the report from finished runs"
    )
    plans.add_argument(
        "--default-only",
        action="store_true",
        help="the front, the default and the corrected option only: no other points, latency sweep or "
        "plan-mode baselines (with its own --out: e.g. --seeds 10 --out results/plans_s10)",
    )
    plans.add_argument("--no-progress", action="store_true", help="no progress bar")
    plans.set_defaults(func=_plans)


def _executor_args(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "--jobs",
        type=int,
        default=None,
        help=f"runs in parallel (local: default {os.cpu_count() or 1}, the CPU count; ray: tasks in "
        "flight, default all pending, queued on the cluster's CPUs)",
    )
    parser.add_argument(
        "--executor",
        choices=("local", "ray"),
        default="local",
        help="local: a process pool on this machine (default); ray: each run a Ray task on the cluster "
        "at --ray-address (needs the 'ray' extra); run files are written here either way",
    )
    parser.add_argument(
        "--ray-address",
        default=None,
        metavar="ADDR",
        help="the Ray cluster: HOST:PORT of its head (GCS) or ray://HOST:10001 (Ray Client); "
        "default RAY_ADDRESS, else a new local Ray instance",
    )


def _check_executor(args: argparse.Namespace) -> None:
    if args.jobs is not None and args.jobs < 1:
        raise SystemExit("--jobs must be >= 1")
    if args.ray_address is not None and args.executor != "ray":
        raise SystemExit("--ray-address needs --executor ray")
    if args.executor == "ray" and importlib.util.find_spec("ray") is None:
        raise SystemExit("--executor ray needs Ray: pip install -e '.[ray]'")


def _paper(args: argparse.Namespace) -> int:
    from experiments.paper import main_paper
    from experiments.tables import format_cost, format_verdicts

    _check_executor(args)
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
        executor=args.executor,
        ray_address=args.ray_address,
    )
    print(format_verdicts(summary))
    print(format_cost(summary))
    print(f"figures and summary.json in {out}; missing runs: {len(summary['missing_runs'])}")
    return 1 if summary["failed_runs"] else 0


def _plans(args: argparse.Namespace) -> int:
    from experiments.plans import DEFAULT_ONLY
    from experiments.plans_bench import main_plans
    from experiments.tables import format_verdicts

    _check_executor(args)
    if args.default_only and (args.out is None or args.latency_seeds):
        raise SystemExit("--default-only needs its own --out and runs no latency sweep (no --latency-seeds)")
    out = args.out or Path("results/plans_quick" if args.quick else "results/plans")
    shape = DEFAULT_ONLY if args.default_only else {"latency_seeds": args.latency_seeds}
    summary = main_plans(
        quick=args.quick,
        out=out,
        jobs=args.jobs,
        seeds=args.seeds,
        steps=args.steps,
        settings=args.settings,
        report_only=args.report_only,
        progress=not args.no_progress,
        paper_dir=args.paper_dir,
        executor=args.executor,
        ray_address=args.ray_address,
        **shape,
    )
    print(format_verdicts(summary))
    print(f"figures, summary.json and summary.md in {out}; missing runs: {len(summary['missing_runs'])}")
    return 1 if summary["failed_runs"] else 0
