"""Learner ingest: transitions per second through ``AdaptiveH.learn_transition`` alone (no env, no Zenoh) at
policy = critic budgets 100/250/500/1000, the stack's agent config otherwise (configs/sim.yaml's
``learner.agent`` as ``deploy.config`` composes it: reach.yaml's agent in plan execution).

The stream is recorded first, as the stack makes it: an actor (``learner.actor.Actor`` in
``learner.acting.SegmentLoop``) plays plans on in-process NS Reach (slow target) and judges the retreat;
a learner at the stack's config learns from each tick and the actor takes its snapshot at its next plan.
Each tick keeps what ``deploy.actor_node`` sends: (obs, raw, reward, next_obs, terminated, truncated,
predicted, end, statistic, noise). The learner under test (built on ``deploy.zenoh_env.ReachSpec`` as
the learner node builds it) then ingests that stream: first with ALD thresholds 0 (every new state is
admitted) until the policy, critic and retreat-field dictionaries hold their budgets, then, at the
config's thresholds again, ``--timed`` transitions are timed on copies of the warmed learner (best of
``--repeats``; each budget in a process of its own). Reach at the config's ALD threshold (0.05) stays
near 100 centres, so a larger budget is full only because the warm-up filled it.

Beside each rate: ``window``, what the timed transitions did to the dictionaries (the smaller budgets,
filled from fewer episodes, keep meeting novel states; 1000 none); ``novel_state``, what a novel state
costs the critic and the policy at the budget; ``arithmetic``, the ops one transition must do at that
size timed alone (the floor this code can reach); a cProfile of one window at the largest budget. One
BLAS thread, as ``adaptiveh`` runs (deploy/cli.py): the learner shares its machine with the arms.

    python bench/learner_ingest.py --stream /tmp/learner_ingest_stream.pkl     # ~1 min; the stream is
    # recorded there if missing (seeded: the same ticks each time); results/learner_ingest.json "after"
    PYTHONPATH=/tmp/learner-base python bench/learner_ingest.py --label before --stream ...  # older code
"""

from __future__ import annotations

import os

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")  # the learner shares two cores with the arms

import argparse  # noqa: E402
import copy  # noqa: E402
import cProfile  # noqa: E402
import hashlib  # noqa: E402
import io  # noqa: E402
import json  # noqa: E402
import pickle  # noqa: E402
import platform  # noqa: E402
import pstats  # noqa: E402
import subprocess  # noqa: E402
import sys  # noqa: E402
import tempfile  # noqa: E402
import time  # noqa: E402
from pathlib import Path  # noqa: E402

import gymnasium as gym  # noqa: E402
import numpy as np  # noqa: E402

import learner  # noqa: E402
import tasks  # noqa: E402, F401  (registers NSReach-v0)
from deploy.config import load_stack_config  # noqa: E402
from deploy.zenoh_env import ReachSpec, env_settings  # noqa: E402
from learner.acting import SegmentLoop  # noqa: E402
from learner.actor import Actor  # noqa: E402
from learner.config import AdaptiveHConfig  # noqa: E402
from learner.plans import QueuedChannel  # noqa: E402
from learner.registry import make_agent  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
STACK = ROOT / "configs" / "sim.yaml"
BUDGETS = (100, 250, 500, 1000)
GOALS = {1000: 400.0, 100: 2000.0}  # issue #47: 20 arms at 20 Hz at budget 1000; 2,000/s at 100


def stack_agent(budget: int | None = None) -> tuple[str, dict]:
    """The stack's learner algo and agent config (``LearnerConfig.agent_config``), budgets overridden."""
    lc = load_stack_config(STACK).learner
    cfg = lc.agent_config()
    if budget is not None:
        cfg.update(policy_budget=budget, critic_budget=budget)
    return lc.algo, cfg


def record_stream(steps: int, seed: int = 0) -> list[tuple]:
    """``steps`` ticks (then to the episode's end) of an actor on NS Reach with a learner at the stack's
    config behind it; each tick as ``deploy.actor_node`` sends it."""
    algo, cfg = stack_agent()
    config = AdaptiveHConfig(**cfg)
    episode_steps = load_stack_config(STACK).learner.max_episode_steps
    env = gym.make("NSReach-v0", motion="slow", max_episode_steps=episode_steps)
    actor = Actor(env, config, seed)
    agent = make_agent(algo, ReachSpec(env_settings(load_stack_config(STACK))), seed, cfg)
    offered: list = []

    def take() -> None:
        if offered:
            actor.load(offered.pop())

    loop = SegmentLoop(actor, QueuedChannel(env, 0), actor.judge, before_plan=take)
    stream: list[tuple] = []
    episode = 0
    loop.reset(seed=seed)
    while True:
        tick = loop.tick()
        step, played = tick.step, tick.played
        raw, source = played.raw(step), played.source
        noise = source.noise[step.index] if source is not None else np.zeros_like(raw)
        predicted = played.predicted(step)
        info = {k: float(step.info.get(k, 0.0)) for k in ("success", "distance")}
        t = (
            np.asarray(tick.obs, float).copy(),
            np.asarray(raw, float).copy(),
            float(step.reward),
            np.asarray(step.obs, float).copy(),
            bool(step.terminated),
            bool(step.truncated),
            info,
            None if predicted is None else np.asarray(predicted, float).copy(),
            tick.end.value,
            tick.statistic,
            np.asarray(noise, float).copy(),
        )
        stream.append(t)
        if agent.learn_transition(*t) is not None:
            offered[:] = [agent.snapshot()]
        if tick.episode_over:
            episode += 1
            if len(stream) >= steps:
                return stream
            loop.reset(seed=seed + episode)


def _thresholds(agent, policy: float, critic: float, field: float) -> None:
    agent.policy.f.ald_threshold = policy
    agent.critic.ald_threshold = critic
    agent.retreat.field.ald_threshold = field


def sizes(agent) -> dict[str, int]:
    return {"policy": len(agent.policy.f), "critic": len(agent.critic), "field": len(agent.retreat.field)}


def warmed(stream: list[tuple], budget: int) -> tuple[object, int]:
    """A learner at ``budget`` whose dictionaries are full; the stream position it stopped at."""
    algo, cfg = stack_agent(budget)
    agent = make_agent(algo, ReachSpec(env_settings(load_stack_config(STACK))), 0, cfg)
    c = agent.config
    field_budget = agent.retreat.field.budget
    _thresholds(agent, 0.0, 0.0, 0.0)
    i = 0
    while True:
        agent.learn_transition(*stream[i % len(stream)])
        i += 1
        s = sizes(agent)
        if s["policy"] >= budget and s["critic"] >= budget and s["field"] >= field_budget:
            break
        if i > 20 * budget + 5000:
            raise RuntimeError(f"budget {budget}: the dictionaries did not fill ({s})")
    _thresholds(agent, c.policy_ald, c.critic_ald, c.policy_ald)
    return agent, i


def feed(agent, stream: list[tuple], start: int, n: int) -> float:
    """Seconds to learn ``n`` transitions of ``stream`` from ``start`` (wrapping at its end)."""
    items = [stream[(start + k) % len(stream)] for k in range(n)]
    learn = agent.learn_transition
    t0 = time.perf_counter()
    for t in items:
        learn(*t)
    return time.perf_counter() - t0


def churn(agent, stream: list[tuple], start: int, n: int) -> dict[str, int]:
    """What the timed window does to the dictionaries (an untimed pass on a copy): transitions whose state
    the critic's ALD test admits (at the budget: a center added and pruned at once) and the policy's and
    the field's prunes (a center admitted, another dropped)."""
    trial = copy.deepcopy(agent)
    removes = {"policy": 0, "field": 0}
    for name, d in (("policy", trial.policy.f.dictionary), ("field", trial.retreat.field.dictionary)):
        remove = d.remove

        def counted(j: int, _remove=remove, _name=name) -> None:
            removes[_name] += 1
            _remove(j)

        d.remove = counted
    admitted = 0
    for k in range(n):
        t = stream[(start + k) % len(stream)]
        admitted += trial.critic.dictionary.ald(trial.normalize(t[0]))[2] > trial.critic.ald_threshold
        trial.learn_transition(*t)
    return {"critic_admitted": int(admitted), **{f"{k}_pruned": n for k, n in removes.items()}}


def admissions(agent, stream: list[tuple], start: int, k: int = 5) -> dict[str, list[float]]:
    """Milliseconds a novel state costs at the budget (the timed window of Reach may hold none): ``k``
    states of the stream moved a unit (three kernel widths) along the last coordinate, each further than
    the one before, fed one after the other to the critic (admitted, then pruned at once: its weight is
    zero) and to the policy (a center admitted, the least important one pruned)."""
    trial = copy.deepcopy(agent)
    out: dict[str, list[float]] = {"critic_ms": [], "policy_ms": []}
    for i in range(k):
        t = stream[(start + 37 * i) % len(stream)]
        s, s_next = trial.normalize(t[0]), trial.normalize(t[3])
        s[-1] += 1.0 + i
        t0 = time.perf_counter()
        trial.critic.update(s, t[2], s_next, False)
        t1 = time.perf_counter()
        trial.policy.f.add(s, np.full(len(trial.policy.low), 0.1))
        t2 = time.perf_counter()
        out["critic_ms"].append(round((t1 - t0) * 1e3, 2))
        out["policy_ms"].append(round((t2 - t1) * 1e3, 2))
    return out


def measure(stream: list[tuple], budget: int, timed: int, repeats: int) -> tuple[dict, object, int]:
    agent, start = warmed(stream, budget)
    full = sizes(agent)
    seconds = []
    after = None
    for _ in range(repeats):
        trial = copy.deepcopy(agent)
        seconds.append(feed(trial, stream, start, timed))
        after = sizes(trial)
    best = min(seconds)
    row = {
        "budget": budget,
        "centres_at_start": full,
        "centres_at_end": after,
        "warmup_transitions": start,
        "timed_transitions": timed,
        "repeats": repeats,
        "seconds": [round(s, 4) for s in seconds],
        "transitions_per_s": round(timed / best, 1),
        "transitions_per_s_median": round(timed / float(np.median(seconds)), 1),
        "us_per_transition": round(best / timed * 1e6, 1),
        "window": churn(agent, stream, start, timed),
        "novel_state": admissions(agent, stream, start),
        "arithmetic": arithmetic(budget, len(agent.normalize.centre), agent.retreat.field.budget),
    }
    row["measured_over_arithmetic"] = round(row["us_per_transition"] / row["arithmetic"]["us_total"], 2)
    return row, agent, start


def profile(agent, stream: list[tuple], start: int, timed: int, top: int = 25) -> list[dict]:
    """cProfile of one timed window on a copy of the warmed learner: the top functions by own time."""
    trial = copy.deepcopy(agent)
    prof = cProfile.Profile()
    prof.enable()
    feed(trial, stream, start, timed)
    prof.disable()
    stats = pstats.Stats(prof, stream=io.StringIO())
    rows = []
    for (file, line, name), (_cc, nc, tt, ct, _callers) in stats.stats.items():
        where = f"{Path(file).name}:{line}({name})" if line else name
        rows.append({"function": where, "calls": nc, "tottime_s": tt, "cumtime_s": ct})
    total = sum(r["tottime_s"] for r in rows)
    rows.sort(key=lambda r: -r["tottime_s"])
    out = []
    for r in rows[:top]:
        out.append(
            {
                "function": r["function"],
                "calls": r["calls"],
                "tottime_s": round(r["tottime_s"], 4),
                "cumtime_s": round(r["cumtime_s"], 4),
                "share_of_total": round(r["tottime_s"] / total, 3),
                "us_per_transition": round(r["tottime_s"] / timed * 1e6, 1),
            }
        )
    return out


def arithmetic(m: int, dim: int, field: int, reps: int = 30) -> dict:
    """What one transition must compute at ``m`` centres (``field`` in the retreat's field), by itself: the
    critic's P z and vᵀP, its rank-one update and the division by the forgetting factor (P is M×M, not
    symmetric), the critic's ALD solve, the policy's two solves for its sample's state at the segment's
    update, the field's two, and four kernel vectors; each op timed alone on random data (best of
    ``reps``, caches warm) and summed. Flops and the bytes of the M×M matrices they stream, too."""
    from scipy.linalg import blas, lapack

    rng = np.random.default_rng(0)

    def best(f) -> float:
        times = []
        for _ in range(reps):
            t0 = time.perf_counter()
            f()
            times.append(time.perf_counter() - t0)
        return min(times)

    def chol(n: int) -> np.ndarray:
        x = rng.normal(size=(n, n))
        return np.linalg.cholesky(x @ x.T / n + np.eye(n))

    p, z = rng.normal(size=(m, m)), rng.normal(size=m)
    lm, lf, zf = chol(m), chol(field), rng.normal(size=field)
    centres, s, inv = rng.normal(size=(m, dim)), rng.normal(size=dim), np.full(dim, 2.0)

    def kernel_vector(c: np.ndarray, x: np.ndarray, w: np.ndarray) -> np.ndarray:
        d = (c - x) * w
        return np.exp(-0.5 * np.einsum("ij,ij->i", d, d))

    parts = {
        "P z + vᵀP": best(lambda: p @ z) + best(lambda: z @ p),
        "P -= g wᵀ": best(lambda: blas.dgemm(-1e-9, z[:, None], z[None, :], 1.0, p.T, overwrite_c=True)),
        "P /= β": best(lambda: np.divide(p, 0.999, out=p)),
        "3 solves (M)": 3 * best(lambda: lapack.dtrtrs(lm.T, z, lower=0, trans=1)),
        "2 solves (field)": 2 * best(lambda: lapack.dtrtrs(lf.T, zf, lower=0, trans=1)),
        "4 kernel vectors": 4 * best(lambda: kernel_vector(centres, s, inv)),
    }
    return {
        "flops": 10 * m * m + 2 * field * field,
        "bytes_streamed": 8 * (5 * m * m + 3 * m * m // 2),
        "us_parts": {k: round(v * 1e6, 1) for k, v in parts.items()},
        "us_total": round(sum(parts.values()) * 1e6, 1),
    }


def _git(tree: Path, *args: str) -> str:
    return subprocess.run(["git", *args], cwd=tree, capture_output=True, text=True).stdout.strip()


def machine() -> dict:
    cpu = platform.processor() or platform.machine()
    for line in Path("/proc/cpuinfo").read_text().splitlines():
        if line.startswith("model name"):
            cpu = line.split(":", 1)[1].strip()
            break
    return {
        "cpu": cpu,
        "cores": os.cpu_count(),
        "blas_threads": os.environ.get("OPENBLAS_NUM_THREADS"),
        "python": platform.python_version(),
        "numpy": np.__version__,
    }


def load() -> list[float]:
    return [float(x) for x in Path("/proc/loadavg").read_text().split()[:3]]


def one_budget(stream_file: str, budget: int, timed: int, repeats: int, with_profile: bool) -> dict:
    """One budget's row (and profile), in a process of its own: no budget inherits another's heap."""
    stream = pickle.loads(Path(stream_file).read_bytes())
    row, agent, start = measure(stream, budget, timed, repeats)
    goal = GOALS.get(budget)
    row["goal_per_s"] = goal
    row["goal_met"] = None if goal is None else row["transitions_per_s"] >= goal
    if with_profile:
        top = profile(agent, stream, start, timed)
        row["profile"] = {"budget": budget, "timed_transitions": timed, "top_by_own_time": top}
    return row


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--budgets", type=int, nargs="+", default=list(BUDGETS))
    p.add_argument("--timed", type=int, default=2000, help="transitions timed per repeat")
    p.add_argument("--repeats", type=int, default=3, help="timed windows per budget (the best counts)")
    p.add_argument("--record", type=int, default=6000, help="ticks of stream to record")
    p.add_argument("--stream", default=None, help="recorded stream (pickle): read if there, else written")
    p.add_argument("--label", default="after", help="the key in the output file's runs (before, after, ...)")
    p.add_argument("--no-profile", action="store_true")
    p.add_argument("--out", default=str(ROOT / "results" / "learner_ingest.json"))
    p.add_argument("--one", type=int, default=None, help=argparse.SUPPRESS)  # internal: one budget, JSON out
    a = p.parse_args()
    if a.one is not None:
        print(json.dumps(one_budget(a.stream, a.one, a.timed, a.repeats, not a.no_profile)))
        return
    tree = Path(learner.__file__).resolve().parents[1]
    load_start = load()
    stream_file = a.stream or str(Path(tempfile.mkdtemp()) / "stream.pkl")
    if Path(stream_file).exists():
        stream = pickle.loads(Path(stream_file).read_bytes())
    else:
        t0 = time.perf_counter()
        stream = record_stream(a.record)
        print(f"recorded {len(stream)} ticks in {time.perf_counter() - t0:.1f} s", flush=True)
        Path(stream_file).write_bytes(pickle.dumps(stream))
    digest = hashlib.sha256(Path(stream_file).read_bytes()).hexdigest()[:16]
    rows, prof = [], None
    heads = ("budget", "policy", "critic", "field", "trans/s", "us/trans", "arith")
    print(" ".join(f"{h:>{w}}" for h, w in zip(heads, (6, 6, 6, 5, 8, 8, 6), strict=True)) + "  goal")
    for budget in a.budgets:
        cmd = [sys.executable, __file__, "--one", str(budget), "--stream", stream_file]
        cmd += ["--timed", str(a.timed), "--repeats", str(a.repeats)]
        if a.no_profile or budget != max(a.budgets):
            cmd.append("--no-profile")
        done = subprocess.run(cmd, capture_output=True, text=True)
        if done.returncode != 0:
            raise SystemExit(f"budget {budget} failed:\n{done.stderr}")
        row = json.loads(done.stdout.strip().splitlines()[-1])
        prof = row.pop("profile", prof)
        rows.append(row)
        c, goal = row["centres_at_start"], row["goal_per_s"]
        met = "" if goal is None else f">= {goal:.0f}: {'met' if row['goal_met'] else 'NOT met'}"
        print(
            f"{budget:>6} {c['policy']:>6} {c['critic']:>6} {c['field']:>5} "
            f"{row['transitions_per_s']:>8.1f} {row['us_per_transition']:>8.1f} "
            f"{row['arithmetic']['us_total']:>6.0f}  {met}",
            flush=True,
        )
    if prof is not None:
        print(f"\ncProfile at budget {prof['budget']} (own time per transition):")
        for r in prof["top_by_own_time"][:15]:
            share, calls = r["share_of_total"], r["calls"]
            print(f"  {r['us_per_transition']:8.1f} us  {share:6.1%}  {calls:>7}  {r['function']}")
    command = " ".join(["python", "bench/learner_ingest.py", *sys.argv[1:]])
    if os.environ.get("PYTHONPATH"):
        command = f"PYTHONPATH={os.environ['PYTHONPATH']} {command}"
    run = {
        "command": command,
        "tree": str(tree),
        "commit": _git(tree, "rev-parse", "HEAD"),
        "learner_changed_since_commit": bool(_git(tree, "status", "--porcelain", "--", "learner")),
        "when": time.strftime("%Y-%m-%dT%H:%M:%S%z"),
        "machine": machine(),
        "loadavg_start": load_start,
        "loadavg_end": load(),
        "stream": {
            "ticks": len(stream),
            "sha256_16": digest,
            "made_by": "NS Reach (slow): an actor and a learner at the stack's config (budget 100)",
        },
        "agent": stack_agent()[1],
        "rows": rows,
        "profile": prof,
    }
    out_path = Path(a.out)
    doc = json.loads(out_path.read_text()) if out_path.exists() else {}
    doc["what"] = __doc__.split("\n\n")[0].replace("\n", " ")
    doc["goals_per_s"] = {str(k): v for k, v in GOALS.items()}
    doc.setdefault("runs", {})[a.label] = run
    out_path.parent.mkdir(parents=True, exist_ok=True)
    out_path.write_text(json.dumps(doc, indent=1))
    print(f"-> {out_path} (runs: {', '.join(doc['runs'])})")


if __name__ == "__main__":
    main()
