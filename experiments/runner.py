"""The local runner: a plan's unfinished runs, ``jobs`` at a time, each in a fresh process.

Resumable: a finished run has written ``runs/<name>.json`` (atomically) and is never recomputed, so an
interrupted experiment picks up where it stopped. One process per run keeps each run's wall-clock,
peak RSS and RNG its own.
"""

from __future__ import annotations

import multiprocessing as mp
import os
import sys
from pathlib import Path
from typing import Any

from experiments.execute import execute_run
from experiments.plan import Plan, RunSpec


def _limit_threads() -> None:
    """One BLAS/torch thread per run: runs are the unit of parallelism (set before workers import numpy)."""
    for var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
        os.environ.setdefault(var, "1")


def run_plan(
    plan: Plan, out_dir: Path, jobs: int, progress: bool = True, label: str = "paper bench"
) -> dict[str, list[str]]:
    """Execute the plan's unfinished runs, ``jobs`` at a time, each in a fresh process."""
    out_dir.mkdir(parents=True, exist_ok=True)
    pending = [r for r in plan.runs if not (out_dir / "runs" / f"{r.name}.json").is_file()]
    done = [r.name for r in plan.runs if r not in pending]
    errors: list[str] = []
    if not pending:
        return {"skipped": done, "ran": [], "failed": []}
    from tqdm import tqdm

    _limit_threads()
    ran: list[str] = []
    bar = tqdm(
        total=sum(r.steps for r in pending),
        unit="step",
        unit_scale=True,
        disable=not progress,
        desc=f"{label}: {len(pending)} runs ({len(done)} done before)",
        dynamic_ncols=True,
    )
    ctx = mp.get_context("spawn")  # fresh interpreter per run: its RSS and RNG are its own
    with ctx.Pool(processes=max(1, jobs), maxtasksperchild=1) as pool:
        by_name = {r.name: r for r in pending}
        results = pool.imap_unordered(_execute_star, [(r, str(out_dir)) for r in pending])
        for res in results:
            spec = by_name[res["name"]]
            bar.update(spec.steps)
            if "error" in res:
                errors.append(res["name"])
                tqdm.write(f"FAILED {res['name']}:\n{res['error']}", file=sys.stderr)
            else:
                ran.append(res["name"])
                bar.set_postfix_str(f"{res['name']} {res['wall_s']:.0f}s {res['peak_rss_mb']:.0f}MB")
    bar.close()
    return {"skipped": done, "ran": ran, "failed": errors}


def _execute_star(args: tuple[RunSpec, str]) -> dict[str, Any]:
    return execute_run(*args)
