"""The plans bench end to end: build the plan, run what is unfinished (unless ``report_only``), report.

Apart from ``experiments.plans`` so that the imports go one way: the plan (what the worker processes
import) knows nothing of the runner or the report, which import it.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

from experiments.plans import build_plans_plan
from experiments.plans_report import plans_report
from experiments.runner import run_plan


def main_plans(
    quick: bool,
    out: Path,
    jobs: int | None,
    seeds: int | None = None,
    latency_seeds: int | None = None,
    steps: int | None = None,
    settings: list[str] | None = None,
    report_only: bool = False,
    progress: bool = True,
    paper_dir: Path | None = None,
    executor: str = "local",
    ray_address: str | None = None,
    **shape: Any,
) -> dict[str, Any]:
    """Run what is unfinished (unless ``report_only``), then report; returns the summary."""
    plan = build_plans_plan(quick, seeds, latency_seeds, steps, settings, **shape)
    outcome: dict[str, list[str]] = {"skipped": [], "ran": [], "failed": []}
    if not report_only:
        outcome = run_plan(  # type: ignore[arg-type]
            plan, out, jobs, progress, label="plans bench", executor=executor, ray_address=ray_address
        )
    summary = plans_report(plan, out, paper_dir)
    summary["last_invocation"] = {k: len(v) for k, v in outcome.items()}
    summary["failed_runs"] = outcome["failed"]
    (out / "summary.json").write_text(json.dumps(summary, indent=1, allow_nan=False))
    return summary
