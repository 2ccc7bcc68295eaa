"""How well the Reach plan model predicts the simulated arm: the numbers behind ``tasks.reach``'s TRACK_*.

A Reach plan is made over states the model predicts (``tasks.reach.predict_reach``); the retreat and the
plan's value depend on how far those drift from what the arm does. This plays NS Reach (slow target)
with a learner-like policy (head for the target, Gaussian exploration of 1 and 3 cm), then

- fits the one-period tracking of the arm: |moved| = s * tanh(g * |action| / s) along the action (the
  IK's joint-speed limits saturate it) and the reported end-effector velocity as a ratio of the period's
  mean velocity, on the first half of the episodes;
- compares, on the other half, the open-loop end-effector error after 1, 2, 5, 10 and 20 steps of the
  *commanded* model (the end effector moves by the capped action, the model before) with the
  *tracked* one (``predict_reach`` as it is in the code).

    python bench/reach_model.py             # ~1 min; writes results/reach_model.json

Another arm's tracking (``robot.tracking``) comes from a stack run on it, its recording's transitions
(the actor's executed ticks: whole 50-step episodes of consecutive ticks), fitted and tested the same way:

    python bench/reach_model.py --recording runs/franka_sim/recordings/RUN.mcap \
        --out results/reach_model_franky_sim.json
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from functools import partial
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from tasks.reach import (  # noqa: E402
    FACE_VALUE,
    MAX_STEP_M,
    TRACK_GAIN,
    TRACK_STEP_M,
    TRACK_VELOCITY_RATIO,
    ArmTracking,
    predict_reach,
)
from tasks.reach_env import NSReachEnv  # noqa: E402

HORIZONS = (1, 2, 5, 10, 20)
EPISODE = 50


def play(
    env: NSReachEnv, episodes: int, seed0: int, rng: np.random.Generator
) -> list[tuple[np.ndarray, np.ndarray]]:
    """(observations, actions) of each episode under a head-for-the-target policy with exploration."""
    out = []
    for ep in range(episodes):
        obs, _ = env.reset(seed=seed0 + ep)
        noise = 0.03 if ep % 2 else 0.01
        observations, actions = [obs], []
        for _ in range(EPISODE):
            action = np.clip(0.5 * obs[12:15] + rng.normal(0.0, noise, 3), -MAX_STEP_M, MAX_STEP_M)
            obs, *_ = env.step(action)
            observations.append(obs)
            actions.append(action)
        out.append((np.asarray(observations, float), np.asarray(actions, float)))
    return out


def fit_tracking(episodes: list[tuple[np.ndarray, np.ndarray]], dt: float) -> dict[str, float]:
    """The velocity ratio by least squares; s and g on a grid, for the least open-loop end-effector error
    over 1-10 steps (what a plan needs, rather than the best single step)."""
    num = den = 0.0
    for obs, actions in episodes:
        for t in range(len(actions)):
            mean_v = (obs[t + 1, 0:3] - obs[t, 0:3]) / dt
            num += float(obs[t + 1, 3:6] @ mean_v)
            den += float(mean_v @ mean_v)
    ratio = num / den
    best = (np.inf, 0.0, 0.0)
    steps, gains = np.arange(0.005, 0.0501, 0.0025), np.arange(0.2, 1.501, 0.025)
    for s in steps:
        for g in gains:
            errors = open_loop_errors(
                episodes, partial(predict_reach, tracking=ArmTracking(g, s, ratio)), dt, horizon=10
            )
            best = min(best, (float(np.mean(list(errors.values()))), s, g))
    _, s, g = best
    if s in (steps[0], steps[-1]) or g in (gains[0], gains[-1]):
        print(f"warning: the fit is at the edge of its grid (step_m {s:.4f}, gain {g:.3f}): widen it")
    return {
        "track_step_m": round(float(s), 4),
        "track_gain": round(float(g), 3),
        "track_velocity_ratio": round(ratio, 3),
        "criterion": "mean open-loop ee error over horizons 1-10 (mm)",
        "criterion_mm": round(best[0], 1),
    }


def open_loop_errors(episodes, model, dt: float, horizon: int | None = None) -> dict[str, float]:
    """Mean end-effector error (mm) after each horizon (1..``horizon`` when given, else ``HORIZONS``),
    predicting open loop from every 5th step."""
    longest = horizon or max(HORIZONS)
    sums, counts = np.zeros(longest), 0
    for obs, actions in episodes:
        for start in range(0, EPISODE - max(HORIZONS) + 1, 5):
            p = obs[start]
            for i in range(longest):
                p = model(p, actions[start + i], dt)
                sums[i] += float(np.linalg.norm(p[0:3] - obs[start + i + 1, 0:3]))
            counts += 1
    keys = range(1, longest + 1) if horizon else HORIZONS
    return {str(h): round(1000.0 * sums[h - 1] / counts, 1) for h in keys}


def recorded_episodes(path: str) -> list[tuple[np.ndarray, np.ndarray]]:
    """(observations, executed raw actions) of each whole ``EPISODE``-step episode (or part of a longer
    one) of consecutive ticks in a stack recording's transitions (an episode with an outage or a restart in
    it is left out). A transition the actor sent again (``deploy.transition_stream``: the learner had not
    acked it yet) is recorded twice and counted once, as the learner counts it."""
    from bus import messages as m
    from monitor import recording

    recorded = [
        m.Transition.FromString(data)
        for topic, _, _, data in recording.read(path)
        if topic.endswith("/" + m.TRANSITIONS.name)
    ]
    by_episode: dict[int, list] = {}
    for t in recording.each_tick_once(recorded):
        by_episode.setdefault(t.episode, []).append(t)
    out = []
    for steps in by_episode.values():
        chained = all(np.allclose(a.next_obs, b.obs) for a, b in zip(steps, steps[1:], strict=False))
        if len(steps) % EPISODE or not chained:
            continue
        for k in range(0, len(steps), EPISODE):  # a longer episode (a real arm's 100 steps) in 50-step parts
            part = steps[k : k + EPISODE]
            obs = np.asarray([part[0].obs] + [t.next_obs for t in part], float)
            out.append((obs, np.asarray([t.raw_action for t in part], float)))
    return out


def fit_recording(path: str, out_path: str) -> int:
    """``robot.tracking`` of the arm a stack recording ran on: fitted on even episodes, tested on odd."""
    t0 = time.monotonic()
    episodes = recorded_episodes(path)
    if len(episodes) < 4:
        raise SystemExit(f"{path}: {len(episodes)} whole {EPISODE}-step episodes; need at least 4")
    fit_eps, test_eps = episodes[::2], episodes[1::2]
    dt = 0.05
    fitted = fit_tracking(fit_eps, dt)
    tracking = ArmTracking(fitted["track_gain"], fitted["track_step_m"], fitted["track_velocity_ratio"])
    result = {
        "command": f"python bench/reach_model.py --recording {path} --out {out_path}",
        "recording": path,
        "fitted_on_even_episodes": fitted,
        "robot.tracking": {
            "gain": tracking.gain,
            "step_m": tracking.step_m,
            "velocity_ratio": tracking.velocity_ratio,
        },
        "open_loop_ee_error_mm_by_horizon_on_odd_episodes": {
            "the mock's (tasks.reach.TRACKING)": open_loop_errors(test_eps, predict_reach, dt),
            "fitted": open_loop_errors(test_eps, partial(predict_reach, tracking=tracking), dt),
            "commanded (moves by the action)": open_loop_errors(
                test_eps, partial(predict_reach, tracking=FACE_VALUE), dt
            ),
        },
        "episodes": {"fit": len(fit_eps), "test": len(test_eps), "steps_each": EPISODE},
        "wall_s": round(time.monotonic() - t0, 1),
    }
    print(json.dumps(result, indent=2))
    out = ROOT / out_path
    out.write_text(json.dumps(result, indent=2) + "\n")
    print(f"wrote {out}")
    return 0


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--episodes", type=int, default=16, help="half to fit, half to test")
    ap.add_argument("--recording", default=None, help="fit another arm's tracking from a stack recording")
    ap.add_argument("--out", default="results/reach_model.json")
    args = ap.parse_args()
    if args.recording is not None:
        return fit_recording(args.recording, args.out)
    t0 = time.monotonic()
    env = NSReachEnv(motion="slow", max_episode_steps=EPISODE, seed=0)
    dt = env.config.period
    rng = np.random.default_rng(0)
    half = args.episodes // 2
    fit_eps = play(env, half, 100, rng)
    test_eps = play(env, args.episodes - half, 200, rng)
    env.close()
    fitted = fit_tracking(fit_eps, dt)
    result = {
        "command": "python bench/reach_model.py",
        "env": "NSReach-v0 (slow target), robot_io's controller on the PyBullet Panda, 20 Hz",
        "policy": "head for the target (0.5 x relative position) + Gaussian exploration 1 / 3 cm",
        "fitted_on_first_half": fitted,
        "in_code": {
            "track_step_m": TRACK_STEP_M,
            "track_gain": TRACK_GAIN,
            "track_velocity_ratio": TRACK_VELOCITY_RATIO,
        },
        "open_loop_ee_error_mm_by_horizon": {
            "commanded (moves by the action)": open_loop_errors(
                test_eps, partial(predict_reach, tracking=FACE_VALUE), dt
            ),
            "tracked (predict_reach)": open_loop_errors(test_eps, predict_reach, dt),
        },
        "episodes": {"fit": half, "test": args.episodes - half, "steps_each": EPISODE},
        "wall_s": round(time.monotonic() - t0, 1),
    }
    print(json.dumps(result, indent=2))
    out = ROOT / args.out
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(json.dumps(result, indent=2) + "\n")
    print(f"wrote {out}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
