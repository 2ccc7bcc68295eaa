"""Same behaviour after a refactor of how the learner acts: re-make runs of ``results/plans`` in this tree
and compare every episode's return with the run's file.

The runs: on each of the plans experiment's six settings, seed 0, the default AdaptiveH and the fixed-H
learner at H = 10 (all in plan execution, in-process). A run whose returns all equal its file's to 1e-9
is unchanged; a run recorded at another commit may differ for reasons older than the refactor (the
file's ``code`` commit is reported beside it): ``--base`` re-makes each run in another checkout too, the
commit before the refactor (``git worktree add /tmp/base REV``), and compares the two.

    python bench/refactor_check.py [--base /tmp/base] [--out results/refactor/plans_check.json]
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
RUNS = ROOT / "results" / "plans" / "runs"
SETTINGS = ("cartpole_fast", "cartpole_slow", "pendulum_slow", "reach_slow", "reach_fast", "reach_erratic")
METHODS = ("adaptiveh-default", "rkhs-h10")
TOLERANCE = 1e-9

REMAKE = """
import json, sys
from experiments.execute import compute_run
from experiments.plans import PlanRunSpec
rec = json.load(open(sys.argv[1]))
spec = PlanRunSpec(rec["env"], rec["algo"], rec["seed"], rec["steps"], rec["config"], rec["env_kwargs"],
                   rec["name"].split("__")[1], 0)
print(json.dumps(list(compute_run(spec)["episodes"]["ret"])))
"""


def remake(path: Path, tree: Path) -> list[float]:
    """The episode returns of the run recorded at ``path``, re-made by the code in ``tree``."""
    out = subprocess.run(
        [sys.executable, "-c", REMAKE, str(path)],
        cwd=tree,
        env={**os.environ, "PYTHONPATH": str(tree)},
        capture_output=True,
        text=True,
        check=True,
    )
    return json.loads(out.stdout.strip().splitlines()[-1])


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--tree", default=str(ROOT), help="the checkout whose code re-makes the runs")
    ap.add_argument("--base", default=None, help="a checkout before the refactor: re-made there too")
    ap.add_argument("--out", default=str(ROOT / "results" / "refactor" / "plans_check.json"))
    args = ap.parse_args()
    rows = []
    for setting in SETTINGS:
        for method in METHODS:
            (path,) = RUNS.glob(f"{setting}__{method}__s0__*.json")
            rec = json.loads(path.read_text())
            recorded = list(rec["episodes"]["ret"])
            made = remake(path, Path(args.tree))
            n = min(len(recorded), len(made))
            diff = max((abs(a - b) for a, b in zip(recorded[:n], made[:n], strict=True)), default=0.0)
            same = len(recorded) == len(made) and diff <= TOLERANCE
            base = remake(path, Path(args.base)) if args.base else None
            same_as_base = (
                base is not None
                and len(base) == len(made)
                and max((abs(a - b) for a, b in zip(base, made, strict=True)), default=0.0) <= TOLERANCE
            )
            rows.append(
                {
                    "run": rec["name"],
                    "recorded_at": rec["code"]["commit"] if isinstance(rec["code"], dict) else rec["code"],
                    "episodes": [len(recorded), len(made)],
                    "final_return": [recorded[-1], made[-1]],
                    "max_abs_diff": diff,
                    "same": same,
                    "same_as_base": same_as_base if base is not None else None,
                }
            )
            vs_base = (
                "" if base is None else ("; as before the refactor" if same_as_base else "; NOT as before")
            )
            print(f"{rec['name']:48s} {'same' if same else 'differs'} as its file{vs_base}", flush=True)
    out = Path(args.out)
    out.parent.mkdir(parents=True, exist_ok=True)
    command = "python bench/refactor_check.py" + (f" --base {args.base}" if args.base else "")
    head = subprocess.run(["git", "rev-parse", "HEAD"], cwd=args.tree, capture_output=True, text=True).stdout
    base_rev = ""
    if args.base:
        base_rev = subprocess.run(
            ["git", "rev-parse", "HEAD"], cwd=args.base, capture_output=True, text=True
        ).stdout
    summary = {"command": command, "tolerance": TOLERANCE, "tree": head.strip(), "base": base_rev.strip()}
    out.write_text(json.dumps({**summary, "runs": rows}, indent=1))
    print(f"{sum(r['same'] for r in rows)} of {len(rows)} runs as their files", end="")
    if args.base:
        print(f"; {sum(bool(r['same_as_base']) for r in rows)} of {len(rows)} as before the refactor", end="")
    print(f" -> {out}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
