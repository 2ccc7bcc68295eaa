"""The runner: a plan's unfinished runs, each in a fresh process, on this machine or on a Ray cluster.

Resumable: a finished run has written ``runs/<name>.json`` (atomically) and is never recomputed, so an
interrupted experiment picks up where it stopped, whichever executor made the runs already there. One
process per run keeps each run's wall-clock, peak RSS and RNG its own.

Executors:

* ``local`` (the default): a process pool, ``jobs`` runs at a time, each run in a fresh interpreter
  that writes its own run file.
* ``ray``: each run is a Ray task (1 CPU) on the cluster at ``ray_address``; the task starts a fresh
  interpreter for the run (so wall-clock and peak RSS are measured as locally, without Ray's own
  imports) and returns the run record, which this process writes into ``out_dir``: the run files live
  with the driver whether or not the cluster's nodes share its disk. This tree is shipped to the
  workers (a Ray ``working_dir``), so they run the driver's code; each node needs the project's
  dependencies installed (``pip install .[baselines]``). ``jobs`` caps the tasks in flight (default:
  all pending, Ray queues them on the cluster's CPUs).
"""

from __future__ import annotations

import json
import multiprocessing as mp
import os
import sys
import traceback
from collections.abc import Iterator
from pathlib import Path
from typing import Any

from experiments.execute import brief, code_version, execute_run, write_run
from experiments.plan import Plan, RunSpec

EXECUTORS = ("local", "ray")
THREAD_VARS = ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS")
ROOT = Path(__file__).resolve().parent.parent
# Not shipped to Ray workers (besides what .gitignore names, which Ray leaves out too): results, history.
RAY_EXCLUDES = [".git", ".venv*", "results", "shared", "tests", "*.egg-info", "__pycache__", ".*_cache",
                ".hypothesis", "runs"]  # fmt: skip


def _limit_threads() -> None:
    """One BLAS/torch thread per run: runs are the unit of parallelism (set before workers import numpy)."""
    for var in THREAD_VARS:
        os.environ.setdefault(var, "1")


def run_plan(
    plan: Plan,
    out_dir: Path,
    jobs: int | None = None,
    progress: bool = True,
    label: str = "paper bench",
    executor: str = "local",
    ray_address: str | None = None,
) -> dict[str, list[str]]:
    """Execute the plan's unfinished runs with ``executor``; returns the names skipped, ran, failed."""
    if executor not in EXECUTORS:
        raise ValueError(f"unknown executor {executor!r}; choose one of {EXECUTORS}")
    if jobs is not None and jobs < 1:
        raise ValueError(f"jobs must be >= 1, got {jobs}")
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
    by_name = {r.name: r for r in pending}
    if executor == "ray":
        results = _ray_results(pending, out_dir, jobs, ray_address)
    else:
        results = _local_results(pending, out_dir, jobs or os.cpu_count() or 1)
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


def _local_results(pending: list[RunSpec], out_dir: Path, jobs: int) -> Iterator[dict[str, Any]]:
    """The local process pool: each run in a fresh interpreter that writes its own run file."""
    ctx = mp.get_context("spawn")  # fresh interpreter per run: its RSS and RNG are its own
    with ctx.Pool(processes=max(1, jobs), maxtasksperchild=1) as pool:
        yield from pool.imap_unordered(_execute_star, [(r, str(out_dir)) for r in pending])


def _execute_star(args: tuple[RunSpec, str]) -> dict[str, Any]:
    return execute_run(*args)


def ray_runtime_env() -> dict[str, Any]:
    """What every Ray task gets: this tree as its working directory, one BLAS thread per run."""
    return {
        "working_dir": str(ROOT),
        "excludes": RAY_EXCLUDES,
        "env_vars": {var: os.environ.get(var, "1") for var in THREAD_VARS},
    }


def _ray_results(
    pending: list[RunSpec], out_dir: Path, jobs: int | None, address: str | None
) -> Iterator[dict[str, Any]]:
    """Each run a Ray task on the cluster at ``address``; this process writes the run files.

    A Ray session already open in this process (``ray.init`` by the caller) is used as it is, and
    left open; otherwise this connects to ``address`` (None: Ray's own default, ``RAY_ADDRESS`` or a
    new local instance) with ``ray_runtime_env()`` and disconnects at the end.
    """
    try:
        import ray
    except ImportError as exc:
        raise RuntimeError("the ray executor needs Ray: pip install -e '.[ray]'") from exc

    own = not ray.is_initialized()
    if own:
        ray.init(address=address, runtime_env=ray_runtime_env(), logging_level="WARNING")
    try:
        code = code_version()  # the tree shipped to the workers, recorded in every run file
        task = ray.remote(num_cpus=1, max_retries=1)(_ray_task)
        queue = list(pending)
        in_flight: dict[Any, RunSpec] = {}
        cap = jobs or len(queue)
        while queue or in_flight:
            while queue and len(in_flight) < cap:
                spec = queue.pop(0)
                in_flight[task.remote(spec, code)] = spec
            ready, _ = ray.wait(list(in_flight), num_returns=1)
            for ref in ready:
                spec = in_flight.pop(ref)
                try:
                    result = ray.get(ref)
                except Exception:  # noqa: BLE001 - a lost task (node or worker died) fails its run only
                    yield {"name": spec.name, "error": traceback.format_exc(limit=4)}
                    continue
                if "error" not in result:
                    write_run(out_dir, result)
                    result = brief(result)
                yield result
    finally:
        if own:
            ray.shutdown()


def _ray_task(spec: RunSpec, code: dict[str, Any]) -> dict[str, Any]:
    """On a Ray worker: the run in a fresh interpreter (``python -m experiments.execute``); its record.

    Not in the worker itself: a Ray worker is reused across tasks and carries Ray's own imports, so
    its peak RSS would be neither the run's own nor comparable with the local executor's.
    """
    import pickle
    import subprocess
    import tempfile

    with tempfile.TemporaryDirectory(prefix="adaptiveh-run-") as tmp:
        work = Path(tmp)
        (work / "spec.pkl").write_bytes(pickle.dumps((spec, code)))
        env = {**os.environ, "PYTHONPATH": os.pathsep.join(p for p in sys.path if p)}
        proc = subprocess.run(
            [sys.executable, "-m", "experiments.execute", str(work)],
            env=env,
            capture_output=True,
            text=True,
            check=False,
        )
        out = work / "result.json"
        if proc.returncode != 0 or not out.is_file():
            error = f"run process exited {proc.returncode}:\n{proc.stderr[-4000:]}"
            return {"name": spec.name, "error": error}
        return json.loads(out.read_text())
