"""The paper bench end to end: build the plan, run what is unfinished (unless ``report_only``), report."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

from experiments.plan import build_plan
from experiments.report import report
from experiments.runner import run_plan


def main_paper(
    quick: bool,
    out: Path,
    jobs: int | None,
    seeds: int | None = None,
    steps: int | None = None,
    envs: list[str] | None = None,
    algos: list[str] | None = None,
    report_only: bool = False,
    overrides: dict[str, dict[str, Any]] | None = None,
    progress: bool = True,
    executor: str = "local",
    ray_address: str | None = None,
) -> dict[str, Any]:
    """Run (unless ``report_only``) with ``executor`` (``experiments.runner``) and report; returns the
    summary."""
    plan = build_plan(quick, seeds, steps, envs, algos, overrides)
    outcome = {"skipped": [], "ran": [], "failed": []}
    if not report_only:
        outcome = run_plan(plan, out, jobs, progress, executor=executor, ray_address=ray_address)
    summary = report(plan, out)
    summary["last_invocation"] = {k: len(v) for k, v in outcome.items()}
    summary["failed_runs"] = outcome["failed"]
    (out / "summary.json").write_text(json.dumps(summary, indent=1, allow_nan=False))
    return summary
