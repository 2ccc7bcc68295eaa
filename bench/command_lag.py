"""How far a stack run's command led the hand, and how many misses that explains, read from its recording.

The policy sees, and is rewarded by, the commanded TCP; success is the measured hand's (deploy/zenoh_env.py).
On an arm that lags its command (franky-sim: 3-4 periods), robot-io holds the command within
``robot.command_lead_m`` of the hand. From the robot's states in the ticks that played an action: the
distance from the commanded TCP to the hand (median, 90th percentile, the share at the lead's cap). From
the transitions of the run's last episodes: the misses (the hand ``SUCCESS_M`` or more from the target at
the episode's end), and how many of them ended with the *command* within ``SUCCESS_M`` of the target: a
policy that did its job in its own eyes while the hand trailed.

    python bench/command_lag.py runs/franka_sim/recordings/RUN.mcap [--config configs/franka_sim.yaml]
        [--last 0.5] [--out results/command_lag.json]
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path
from typing import Any

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from bus import messages as m  # noqa: E402
from deploy.config import load_stack_config  # noqa: E402
from monitor import recording  # noqa: E402
from tasks.reach import OBSERVATION_NAMES, SUCCESS_M  # noqa: E402

AT_CAP = 0.98  # a gap at this fraction of the lead or more counts as held at the cap
REL = slice(OBSERVATION_NAMES.index("target_rel_x"), OBSERVATION_NAMES.index("target_rel_z") + 1)


def played_gaps(records: list) -> np.ndarray:
    """|commanded TCP - hand| (m) in each state of a tick that played an action."""
    states = (m.STATE.type.FromString(d) for t, _, _, d in records if t.endswith("/" + m.STATE.name))
    return np.array(
        [np.linalg.norm(np.subtract(s.ee_cmd, s.ee_pos)) for s in states if s.played_index >= 0 and s.ee_cmd]
    )


def episode_ends(records: list) -> list[m.Transition]:
    """Each episode's last recorded transition (each tick once), in episode order."""
    recorded = [m.Transition.FromString(d) for t, _, _, d in records if t.endswith("/" + m.TRANSITIONS.name)]
    last: dict[int, m.Transition] = {}
    for t in recording.each_tick_once(recorded):
        last[t.episode] = t
    return [last[e] for e in sorted(last)]


def command_lag(records: list, lead_m: float, last: float) -> dict[str, Any]:
    """The gaps and misses above, from a recording's records (``monitor.recording.read``)."""
    gaps = played_gaps(records)
    ends = episode_ends(records)
    tail = ends[len(ends) - max(1, round(len(ends) * last)) :] if ends else []
    misses = [t for t in tail if t.distance >= SUCCESS_M]
    command_there = [t for t in misses if np.linalg.norm(np.asarray(t.next_obs)[REL]) < SUCCESS_M]
    return {
        "command_lead_m": lead_m,
        "played_ticks": int(gaps.size),
        "gap_median_m": round(float(np.median(gaps)), 4) if gaps.size else None,
        "gap_p90_m": round(float(np.percentile(gaps, 90)), 4) if gaps.size else None,
        "gap_at_cap_share": round(float(np.mean(gaps >= AT_CAP * lead_m)), 3) if gaps.size else None,
        "episodes": len(ends),
        "episodes_read": len(tail),
        "misses": len(misses),
        "misses_with_command_on_target": len(command_there),
    }


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("recording")
    ap.add_argument("--config", default="configs/franka_sim.yaml", help="the run's stack config (its lead)")
    ap.add_argument("--last", type=float, default=0.5, help="share of episodes read, from the end")
    ap.add_argument("--out", type=Path, default=None, help="also write the result here as JSON")
    args = ap.parse_args()
    if not 0 < args.last <= 1:
        ap.error(f"--last {args.last}: must be in (0, 1]")
    lead = load_stack_config(ROOT / args.config).robot.command_lead_m
    lag = command_lag(recording.read(args.recording), lead, args.last)
    result = {"command": "python " + " ".join(sys.argv), "recording": args.recording, **lag}
    print(json.dumps(result, indent=1))
    if args.out is not None:
        args.out.write_text(json.dumps(result, indent=1) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
