"""The main job's closing report: a table a person reads at a glance, and a learning-curve PNG.

The supervisor's summary dict (``Stack.summary``) stays the record (written as JSON beside the
recording); this module only renders it.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any


def _pct(x: float | None) -> str:
    return "-" if x is None else f"{100 * x:.0f} %"


def actor_counts_path(checkpoint_dir: str | Path, arm: str = "") -> Path:
    """Where the actor of ``arm`` ("": a stack's only one) writes what it did (``actor.json``)."""
    return Path(checkpoint_dir) / (f"actor-{arm}.json" if arm else "actor.json")


def by_quarter(success: list[bool]) -> list[float | None] | None:
    """Success rate in each quarter of the episodes (None with fewer than 4)."""
    if len(success) < 4:
        return None
    q = len(success) // 4
    return [sum(success[i * q : (i + 1) * q]) / q for i in range(4)]


def arm_summaries(episodes: list[dict[str, Any]], actors: dict[str, dict[str, Any]]) -> dict[str, Any]:
    """A row per arm of a fleet: its episodes (the learner's record of them) and its actor's counts."""
    rows = {}
    for arm, actor in actors.items():
        success = [bool(e.get("success")) for e in episodes if e.get("arm", "") == arm]
        rows[arm] = {
            "episodes": len(success),
            "steps": actor.get("steps"),
            "success_rate_by_quarter": by_quarter(success),
            "success_rate": sum(success) / len(success) if success else None,
            "segments": actor.get("segments"),
            "retreats": actor.get("retreats"),
            "policy_version": actor.get("policy_version"),
            "transitions_lost": actor.get("transitions_lost"),
            "error": actor.get("error") or None,
        }
    return rows


def summary_table(s: dict[str, Any]) -> str:
    """The summary as aligned ``what | value`` rows."""
    quarters = s.get("success_rate_by_quarter")
    h = s.get("H") or {}
    reasons = s.get("reasons") or {}
    safety = s.get("safety_events") or {}
    rows = [
        ("policy started from", started_from(s.get("started_from"))),
        (
            "steps, episodes",
            f"{s.get('global_step', 0)}, {s.get('episodes', 0)} in {s['wall_clock_s']:.0f} s",
        ),
        (
            "success by quarter",
            " / ".join(_pct(q) for q in quarters) if quarters else "fewer than 4 episodes",
        ),
        ("segments (retreats)", f"{s.get('segments', 0)} ({reasons.get('retreat', 0)} retreats)"),
        (
            "H mean / median / p10-p90",
            f"{h['mean']:.1f} / {h['median']:.0f} / {h['p10']:.0f}-{h['p90']:.0f}" if h else "-",
        ),
        (
            "planned actions dropped",
            f"{s.get('retreat_dropped') or 0} at retreats, {s.get('dropped_actions') or 0} in all",
        ),
        (
            "safety events",
            ", ".join(f"{k} {v}" for k, v in sorted(safety.items(), key=lambda kv: -kv[1])) or "none",
        ),
        (
            "recoveries (part restarts)",
            ", ".join(f"{k} {v}" for k, v in s.get("restarts", {}).items()) or "none",
        ),
        ("messages refused as forged/bad", str(sum((s.get("rejected_messages") or {}).values()))),
        ("recording", f"{s.get('recording')} ({s.get('recording_lost') or 0} messages lost)"),
    ]
    for arm, row in (s.get("arms") or {}).items():
        quarters = row.get("success_rate_by_quarter")
        success = " / ".join(_pct(q) for q in quarters) if quarters else f"{row['episodes']} episodes"
        rows.append(
            (
                f"arm {arm}",
                f"success {success}, {row.get('steps') or 0} steps, {row.get('retreats') or 0} retreats"
                f" of {row.get('segments') or 0} segments,"
                f" {row.get('transitions_lost') or 0} transitions lost",
            )
        )
    width = max(len(k) for k, _ in rows)
    return "\n".join(f"  {k:<{width}} | {v}" for k, v in rows)


def started_from(handoff: dict[str, Any] | None) -> str:
    """Which policy the run began with: an empty one, or a handoff's source."""
    if not handoff:
        return "an empty policy (no handoff)"
    arm = f" on {handoff['arm']}" if handoff.get("arm") else ""
    commit = f", commit {handoff['commit']}" if handoff.get("commit") else ""
    return f"{handoff['path']} ({handoff['trained_on']}{arm}, {handoff['steps']} steps{commit})"


def learning_curve(result: dict[str, Any], path: Path, window: int = 10) -> Path | None:
    """Episode return and success (running mean over ``window`` episodes) against steps; None (nothing
    written) without episodes."""
    episodes = result.get("episodes") or []
    if not episodes:
        return None
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    import numpy as np

    steps = np.array([e["global_step"] for e in episodes], float)
    ret = np.array([e["ret"] for e in episodes], float)
    success = np.array([bool(e.get("success")) for e in episodes], float)
    k = min(window, len(episodes))
    kernel = np.ones(k) / k
    fig, (a, b) = plt.subplots(1, 2, figsize=(11, 3.8))
    a.plot(steps, ret, ".", alpha=0.35, label="episode")
    a.plot(steps[k - 1 :], np.convolve(ret, kernel, "valid"), lw=2, label=f"mean of {k}")
    a.set(xlabel="environment step", ylabel="return (-sum of distances)", title="return")
    b.plot(steps[k - 1 :], 100 * np.convolve(success, kernel, "valid"), lw=2, color="tab:green")
    b.set(xlabel="environment step", ylabel="success, %", ylim=(-5, 105), title=f"success (mean of {k})")
    for ax in (a, b):
        ax.grid(alpha=0.3)
    a.legend(fontsize=8)
    fig.suptitle(f"{result.get('algo', '')} over the stack: {len(episodes)} episodes")
    fig.tight_layout()
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=100)
    plt.close(fig)
    return path
