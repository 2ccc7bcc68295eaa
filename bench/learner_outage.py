"""Nothing lost while the learner is away: robot-io (PyBullet), the actor and the learner as processes,
the learner SIGKILLed mid-run and started again after an outage while the arm plays on.

Per trial: the actor's steps when the new learner starts, how long until that learner learns again
(its first ack with more learned than its checkpoint held) and until it has caught up with the actor,
and, from its final checkpoint, whether every transition was learned once: the stream's contiguous
count learned (no gap) equals the learner's step count (no repeat) and reaches past the outage; the
actor's and the learner's counts of transitions lost. Writes ``results/learner_outage.json``.

    python bench/learner_outage.py [--trials 3] [--outage-s 10]
"""

from __future__ import annotations

import argparse
import json
import os
import pickle
import platform
import signal
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path
from typing import Any

import yaml

ROOT = Path(__file__).resolve().parents[1]
sys.path[:0] = [str(ROOT), str(ROOT / "tests")]
from loopback import free_endpoint, unique_name  # noqa: E402

from bus import messages as m  # noqa: E402
from bus.signing import mac_key  # noqa: E402
from bus.transport import Bus, ZenohConfig, open_session, wait_listening  # noqa: E402
from deploy.config import compose_stack_yaml  # noqa: E402
from deploy.part_env import TOKEN_ENV  # noqa: E402

OUT = ROOT / "results" / "learner_outage.json"
TOKEN = "outage-bench-token"


class Watch:
    """The bench's peer: every transition's (stream, step) and every ack, with arrival times."""

    def __init__(self, cfg: dict) -> None:
        self.bus = Bus(open_session(ZenohConfig(connect=(cfg["zenoh"]["hub"],))), cfg["name"], mac_key(TOKEN))
        self.lock = threading.Lock()
        self.steps: list[int] = []
        self.acks: list[tuple[float, m.TransitionAck]] = []
        self.bus.subscribe(m.TRANSITIONS, self._on_transition)
        self.bus.subscribe(m.TRANSITION_ACKS, self._on_ack)

    def _on_transition(self, t: m.Transition) -> None:
        with self.lock:
            self.steps.append(t.step)

    def _on_ack(self, a: m.TransitionAck) -> None:
        with self.lock:
            self.acks.append((time.monotonic(), a))

    def played(self) -> int:
        with self.lock:
            return max(self.steps, default=-1) + 1

    def learned_by(self, learners: set[str]) -> int:
        with self.lock:
            return max((a.learned for _, a in self.acks if a.learner in learners and a.stream), default=0)

    def learners(self) -> set[str]:
        with self.lock:
            return {a.learner for _, a in self.acks}

    def wait(self, pred: Any, timeout: float, what: str) -> float:
        t0 = time.monotonic()
        while not pred():
            if time.monotonic() - t0 > timeout:
                raise TimeoutError(f"no {what} within {timeout} s")
            time.sleep(0.02)
        return time.monotonic()


def _part(part: str, cfg_path: Path, log: Path, *args: str) -> subprocess.Popen:
    cmd = [sys.executable, "-m", "deploy.cli", part, "--config", str(cfg_path), "--log-level", "WARNING"]
    return subprocess.Popen(
        [*cmd, *args],
        stdout=log.open("w"),
        stderr=subprocess.STDOUT,
        env={**os.environ, TOKEN_ENV: TOKEN},
        cwd=ROOT,
    )


def _config(tmp: Path, seed: int) -> tuple[dict, Path]:
    cfg = compose_stack_yaml(ROOT / "configs" / "sim.yaml")
    cfg.pop("vision")
    cfg.pop("monitor")
    cfg["name"] = unique_name("outage")
    cfg["zenoh"]["hub"] = free_endpoint()
    cfg["robot"]["seed"] = seed
    cfg["learner"].update(
        steps=1_000_000,
        seed=seed,
        execution="actor",
        target_topic="sim/target_truth",
        checkpoint_dir=str(tmp / "learner"),
    )
    path = tmp / "stack.yaml"
    path.write_text(yaml.safe_dump(cfg))
    return cfg, path


def trial(seed: int, outage_s: float, before: int) -> dict[str, Any]:
    with tempfile.TemporaryDirectory() as d:
        tmp = Path(d)
        cfg, path = _config(tmp, seed)
        procs = [_part("robot-io", path, tmp / "robot-io.log", "--watch", "actor")]
        watch = None
        try:
            wait_listening(cfg["zenoh"]["hub"])
            watch = Watch(cfg)
            procs.append(_part("act", path, tmp / "act.log"))
            learner = _part("learn", path, tmp / "learn-1.log")
            watch.wait(lambda: watch.learned_by(watch.learners()) >= before, 120, f"{before} steps learned")
            learner.send_signal(signal.SIGKILL)
            learner.wait(10)
            first = watch.learners()
            time.sleep(outage_s)
            ckpt = Path(cfg["learner"]["checkpoint_dir"]) / "checkpoint.pkl"
            with ckpt.open("rb") as fh:
                saved = next(iter(pickle.load(fh)["stream_marks"].values()))
            played_at_restart = watch.played()
            t_restart = time.monotonic()
            learner = _part("learn", path, tmp / "learn-2.log")
            new = lambda: watch.learners() - first  # noqa: E731
            t_learning = watch.wait(lambda: watch.learned_by(new()) > saved, 60, "learning again")
            t_caught_up = watch.wait(
                lambda: watch.learned_by(new()) >= played_at_restart + 100, 120, "catching up"
            )
            learner.send_signal(signal.SIGTERM)
            learner.wait(30)
            with ckpt.open("rb") as fh:
                state = pickle.load(fh)
            result = json.loads((ckpt.parent / "result.json").read_text())
        finally:
            if watch is not None:
                watch.bus.close()  # its Zenoh session would keep the process from exiting
            for p in procs:
                p.send_signal(signal.SIGTERM)
            for p in procs:
                try:
                    p.wait(15)
                except subprocess.TimeoutExpired:
                    p.kill()
        actor = json.loads((ckpt.parent / "actor.json").read_text())
    (learned,) = state["stream_marks"].values()
    return {
        "seed": seed,
        "outage_s": outage_s,
        "learned_before_kill": before,
        "saved_at_kill": saved,
        "played_at_restart": played_at_restart,
        "learning_again_after_restart_s": round(t_learning - t_restart, 2),
        "caught_up_after_restart_s": round(t_caught_up - t_restart, 2),
        "learned_in_order": learned,
        "learner_steps": state["log"]["global_step"],
        "each_learned_once": learned == state["log"]["global_step"],
        "none_missing": learned >= played_at_restart,
        "lost_actor": actor["transitions_lost"],
        "lost_learner": result["transitions_lost"],
        "resent": actor["transitions_resent"],
    }


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--trials", type=int, default=3)
    ap.add_argument("--outage-s", type=float, default=10.0)
    ap.add_argument("--before", type=int, default=400, help="steps learned before the kill")
    args = ap.parse_args()
    trials = []
    for seed in range(args.trials):
        print(f"[{seed + 1}/{args.trials}] learner killed after {args.before} steps, {args.outage_s} s away")
        trials.append(trial(seed, args.outage_s, args.before))
        print("  " + json.dumps(trials[-1]), flush=True)
    commit = subprocess.run(["git", "rev-parse", "HEAD"], cwd=ROOT, capture_output=True, text=True)
    out = {
        "command": "python bench/learner_outage.py " + " ".join(sys.argv[1:]),
        "commit": commit.stdout.strip(),
        "machine": {"cpus": os.cpu_count(), "python": platform.python_version(), "load": os.getloadavg()},
        "trials": trials,
        "lost": sum(t["lost_actor"] + t["lost_learner"] for t in trials),
        "all_learned_once_in_order": all(t["each_learned_once"] and t["none_missing"] for t in trials),
        "learning_again_after_restart_s_max": max(t["learning_again_after_restart_s"] for t in trials),
    }
    OUT.write_text(json.dumps(out, indent=1))
    print(
        f"lost {out['lost']}; every transition learned once, in order: {out['all_learned_once_in_order']}; "
        f"learning again at most {out['learning_again_after_restart_s_max']} s after the restart -> {OUT}"
    )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
