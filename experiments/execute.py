"""One run of the plan, in its own process: build the env and agent, learn, write ``runs/<name>.json``.

Each run records its wall-clock (of ``learn``), its process's own peak RSS (``VmHWM``), the commit of
the code it ran, and its episodes and segments, so the report is rebuilt from the run files alone.
``compute_run`` makes the record, ``write_run`` stores it: the local executor does both in the run's
process, the Ray executor (``experiments.runner``) computes on a cluster node and the driver writes.
"""

from __future__ import annotations

import json
import platform
import resource
import socket
import sys
import time
import traceback
from pathlib import Path
from typing import Any

from common.proc_status import status_field
from experiments.metrics import run_metrics
from experiments.plan import RunSpec


def peak_rss_kib() -> float:
    """This process's own peak resident set, KiB: ``VmHWM`` of ``/proc/self/status`` on Linux.

    Not ``ru_maxrss`` there: Linux carries the peak RSS of the address space a process replaced at
    ``exec`` over into it, so a run started from a large parent (a Ray worker, ~100 MB) would report
    at least the parent's size. ``ru_maxrss`` (KiB on Linux) elsewhere.
    """
    hwm = status_field("VmHWM")
    return float(hwm) if hwm is not None else float(resource.getrusage(resource.RUSAGE_SELF).ru_maxrss)


def execute_run(spec: RunSpec, out_dir: str) -> dict[str, Any]:
    """Run one spec to completion and write ``runs/<name>.json``; errors come back, never raise."""
    try:
        result = compute_run(spec)
        write_run(Path(out_dir), result)
        return brief(result)
    except Exception:  # noqa: BLE001 - a failed run is reported and stays missing, the others go on
        return {"name": spec.name, "error": traceback.format_exc(limit=8)}


def brief(result: dict[str, Any]) -> dict[str, Any]:
    """What the runner's progress line needs of a run record."""
    return {k: result[k] for k in ("name", "wall_s", "peak_rss_mb", "global_step")}


def write_run(out_dir: Path, result: dict[str, Any]) -> Path:
    """Store a run record as ``runs/<name>.json``, atomically: the file exists only when complete."""
    runs_dir = out_dir / "runs"
    runs_dir.mkdir(parents=True, exist_ok=True)
    tmp = runs_dir / f".{result['name']}.json.tmp"
    tmp.write_text(json.dumps(result))
    path = runs_dir / f"{result['name']}.json"
    tmp.replace(path)
    return path


# The packages whose versions change a run's numbers (NS CartPole is chaotic: one float apart, another run).
RUN_PACKAGES = (
    "numpy",
    "scipy",
    "gymnasium",
    "torch",
    "stable-baselines3",
    "pybullet",
    "mujoco",
    "pin",
    "mink",
)


def package_versions() -> dict[str, str | None]:
    """The installed version of each of ``RUN_PACKAGES`` (None: not installed)."""
    from importlib.metadata import PackageNotFoundError, version

    found: dict[str, str | None] = {}
    for name in RUN_PACKAGES:
        try:
            found[name] = version(name)
        except PackageNotFoundError:
            found[name] = None
    return found


# numpy's x86 SIMD levels, highest first: AVX-512, AVX2/FMA, SSE4.2/POPCNT.
X86_LEVELS = ("X86_V4", "X86_V3", "X86_V2")


def cpu_description() -> dict[str, str | None]:
    """The CPU a run ran on: its model name and the highest x86 SIMD level numpy finds on it.

    numpy and OpenBLAS (``DYNAMIC_ARCH``) pick their kernels by that level at run time, so the same code
    and packages round differently on another CPU, and the envs (NS CartPole and NS Pendulum most) turn
    that into another run of the same seed. ``simd`` is None off x86 or where numpy does not say."""
    model = None
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                model = line.split(":", 1)[1].strip()
                break
    except OSError:
        pass
    model = model or platform.processor() or None
    try:  # what numpy.show_runtime() reads; private, hence guarded
        from numpy._core._multiarray_umath import __cpu_features__ as found
    except ImportError:
        found = {}
    simd = next((level for level in X86_LEVELS if found.get(level)), None)
    return {"model": model, "simd": simd}


def code_version() -> dict[str, Any]:
    """The commit of the source tree this process imports, and whether its code/configs differ from it."""
    import subprocess

    root = Path(__file__).resolve().parent.parent
    paths = ["learner", "sim", "robot_io", "tasks", "configs", "experiments"]
    try:
        git = ["git", "-C", str(root)]
        commit = subprocess.run(
            [*git, "rev-parse", "HEAD"], capture_output=True, text=True, timeout=20, check=True
        )
        dirty = subprocess.run(
            [*git, "status", "--porcelain", "--", *paths],
            capture_output=True,
            text=True,
            timeout=20,
            check=True,
        )
    except (OSError, subprocess.SubprocessError):
        return {"commit": None, "dirty": None, "root": str(root)}
    return {"commit": commit.stdout.strip(), "dirty": bool(dirty.stdout.strip()), "root": str(root)}


def compute_run(spec: RunSpec, code: dict[str, Any] | None = None, executor: str = "local") -> dict[str, Any]:
    """Learn one spec in this process and return its run record (``code``: the commit it runs, by
    default this tree's; the Ray executor passes the driver's, whose tree it ships to the workers)."""
    from experiments.envs import make_env
    from learner.registry import make_agent  # the learners load torch: only in the process that runs

    env_spec = spec.env_spec
    env = make_env(env_spec.env_id, spec.env_kwargs)
    agent = make_agent(spec.algo, env, spec.seed, dict(spec.config))
    t0 = time.perf_counter()
    log = agent.learn(spec.steps)
    wall = time.perf_counter() - t0
    peak_kb = peak_rss_kib()
    channel = getattr(agent, "channel", None)  # plan execution: what the plan queue played and dropped
    env.close()
    eps = log.episodes
    info_keys = sorted({k for e in eps for k in e.info})
    result = {
        "name": spec.name,
        "env": spec.env,
        "env_id": env_spec.env_id,
        "preset": env_spec.preset,
        "algo": spec.algo,
        "seed": spec.seed,
        "steps": spec.steps,
        "global_step": int(log.global_step),
        "config": spec.config,
        "env_kwargs": spec.env_kwargs,
        "threshold": env_spec.threshold,
        "wall_s": wall,
        "steps_per_s": log.global_step / wall if wall > 0 else None,
        "peak_rss_mb": peak_kb / 1024.0,
        "python": sys.version.split()[0],
        "code": code if code is not None else code_version(),
        "packages": package_versions(),  # where the run ran (a Ray worker's, not the driver's)
        "cpu": cpu_description(),
        "executor": executor,
        "host": socket.gethostname(),
        "finished_at": time.strftime("%Y-%m-%dT%H:%M:%S"),
        "metrics": run_metrics(
            [e.global_step for e in eps], [e.ret for e in eps], spec.steps, env_spec.threshold
        ),
        "episodes": {
            "global_step": [e.global_step for e in eps],
            "ret": [e.ret for e in eps],
            "length": [e.length for e in eps],
            "success": [e.success for e in eps],
            "info": {k: [e.info.get(k) for e in eps] for k in info_keys},
        },
        "segments": {
            "global_step": [s.global_step for s in log.segments],
            "H": [s.H for s in log.segments],
            "reason": [s.reason for s in log.segments],
        },
        "plan_channel": None
        if channel is None
        else {
            "dropped_planned": int(channel.dropped_planned),
            "preemptions": int(getattr(channel, "preemptions", 0)),
            "latency_steps": int(getattr(channel, "latency", 0)),
        },
    }
    return result


def _main(work: str) -> int:
    """``python -m experiments.execute DIR``: the run pickled in ``DIR/spec.pkl`` (with the code
    version to record) into ``DIR/result.json``, an ``error`` record if it fails (the Ray executor's
    fresh process per run)."""
    import pickle

    folder = Path(work)
    spec, code = pickle.loads((folder / "spec.pkl").read_bytes())  # noqa: S301 - written by our runner
    try:
        result = compute_run(spec, code, executor="ray")
    except Exception:  # noqa: BLE001 - reported to the driver, which names the failed run
        result = {"name": spec.name, "error": traceback.format_exc(limit=8)}
    tmp = folder / ".result.json.tmp"
    tmp.write_text(json.dumps(result))
    tmp.replace(folder / "result.json")
    return 0


if __name__ == "__main__":
    raise SystemExit(_main(sys.argv[1]))
