"""Which CPU made each run: numpy and OpenBLAS pick their kernels by the CPU's SIMD level, and the envs
amplify the rounding (NS CartPole and NS Pendulum most, NS Reach's long fixed-H plans too), so one seed's
run on another CPU is another draw (docs/paper_plans.md)."""

from __future__ import annotations

from collections import Counter
from typing import Any


def machine_of(run: dict[str, Any]) -> str:
    """The CPU a run file names (``experiments.execute.cpu_description``), or ``unrecorded``."""
    cpu = run.get("cpu")
    return f"{cpu.get('model')} ({cpu.get('simd')})" if cpu else "unrecorded"


def machines(runs: dict[str, dict[str, Any]]) -> dict[str, dict[str, int]]:
    """Per env (setting), how many of its runs each CPU made. A chaotic env's runs of one seed differ
    from one SIMD level to another, so a front and its points are draws of one machine only when their
    setting names one."""
    by_env: dict[str, list[str]] = {}
    for run in runs.values():
        by_env.setdefault(str(run.get("env")), []).append(machine_of(run))
    return {env: dict(sorted(Counter(labels).items())) for env, labels in sorted(by_env.items())}


def mixed_machines(counts: dict[str, dict[str, int]]) -> list[str]:
    """The envs whose runs come from more than one CPU (an unrecorded one counting as another)."""
    return [env for env, by_cpu in counts.items() if len(by_cpu) > 1]
