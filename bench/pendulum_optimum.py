"""NS Pendulum: how far is the learned policy from the best one, and what does the discount cost?

Issue #15 asks why AdaptiveH stays behind SAC and TD3 on NS Pendulum. Two candidate causes are measured
against the task's own optimum rather than against another learner:

1. The discount. configs/pendulum.yaml learns with γ = 0.95 (a 1 s horizon) where TD3 uses 0.98 and SAC
   0.99; a γ-optimal policy may be myopic on the 200-step undiscounted return the bench scores. Value
   iteration on the pendulum's noise-free dynamics (sim.pendulum's constants and cost, a θ × θ̇ grid with
   bilinear interpolation, ``--actions`` torques) gives the γ-optimal value for each ``--gammas``; its
   one-step greedy policy is scored on the undiscounted 200-step return from ``--starts`` start states
   drawn as the env draws them (θ ~ U[-π, π], θ̇ ~ U[-1, 1]).
2. The learner. The configured learner after its 20k steps (``--seeds`` seeds, the paper bench's worlds),
   frozen, on the same noise-free starts: its mean action, and the one-step greedy policy on its own
   critic (``argmax_u r + γ V̂(s')`` with the true dynamics: a lookahead the learner does not have, asking
   whether the critic is good enough to act on).

Writes ``results/pendulum_optimum.json`` and prints a table.

    python bench/pendulum_optimum.py --jobs 2     # ~5 min on two cores
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

import learner_diagnosis as diagnosis  # noqa: E402

from sim.pendulum import NSPendulum, angle_normalize  # noqa: E402

EPISODE = NSPendulum.max_steps


class PendulumGrid:
    """The noise-free pendulum on a periodic θ grid × a clipped θ̇ grid; every (cell, torque) successor
    is precomputed as bilinear interpolation weights."""

    def __init__(self, n_theta: int, n_speed: int, n_actions: int):
        self.thetas = np.linspace(-np.pi, np.pi, n_theta, endpoint=False)
        self.speeds = np.linspace(-NSPendulum.max_speed, NSPendulum.max_speed, n_speed)
        self.torques = np.linspace(-NSPendulum.max_torque, NSPendulum.max_torque, n_actions)
        th, w, u = np.meshgrid(self.thetas, self.speeds, self.torques, indexing="ij")
        th2, w2, self.reward = diagnosis._pendulum_step(th, w, u)
        self.successor = self.weights(th2, w2)

    def weights(self, th: np.ndarray, w: np.ndarray) -> tuple:
        """Bilinear interpolation weights of the states ``(θ, θ̇)`` on the grid."""
        n_t, n_w = len(self.thetas), len(self.speeds)
        d_t = 2 * np.pi / n_t
        f_t = (angle_normalize(th) + np.pi) / d_t
        i0 = np.floor(f_t).astype(int)
        t_i = f_t - i0
        i0 %= n_t
        d_w = self.speeds[1] - self.speeds[0]
        f_w = (np.clip(w, self.speeds[0], self.speeds[-1]) - self.speeds[0]) / d_w
        j0 = np.clip(np.floor(f_w).astype(int), 0, n_w - 2)
        t_j = np.clip(f_w - j0, 0.0, 1.0)
        return i0, (i0 + 1) % n_t, j0, j0 + 1, t_i, t_j

    @staticmethod
    def interpolate(v: np.ndarray, weights: tuple) -> np.ndarray:
        i0, i1, j0, j1, t_i, t_j = weights
        return (
            (1 - t_i) * (1 - t_j) * v[i0, j0]
            + t_i * (1 - t_j) * v[i1, j0]
            + (1 - t_i) * t_j * v[i0, j1]
            + t_i * t_j * v[i1, j1]
        )

    def value_iteration(
        self, gamma: float, tol: float = 1e-4, max_sweeps: int = 5000
    ) -> tuple[np.ndarray, int]:
        v = np.zeros((len(self.thetas), len(self.speeds)))
        for sweep in range(1, max_sweeps + 1):
            new = (self.reward + gamma * self.interpolate(v, self.successor)).max(axis=2)
            if np.max(np.abs(new - v)) < tol:
                return new, sweep
            v = new
        raise RuntimeError(f"value iteration at gamma {gamma} did not converge in {max_sweeps} sweeps")

    def value_at(self, v: np.ndarray):
        """The grid's value ``v`` as a function of ``(θ, θ̇)`` arrays."""
        return lambda th, w: self.interpolate(v, self.weights(th, w))

    def greedy(self, value_of_next, gamma: float):
        """The policy ``argmax_u r(θ, θ̇, u) + γ value_of_next(θ', θ̇')`` over the grid's torques."""

        def act(th: float, w: float) -> float:
            th2, w2, r = diagnosis._pendulum_step(
                np.full(len(self.torques), th), np.full(len(self.torques), w), self.torques
            )
            return float(self.torques[np.argmax(r + gamma * value_of_next(th2, w2))])

        return act


def episode_returns(policy, starts: np.ndarray) -> np.ndarray:
    """Undiscounted 200-step returns of ``policy(θ, θ̇) -> torque`` from each start, noise-free."""
    out = []
    for th0, w0 in starts:
        th, w, total = np.array([th0]), np.array([w0]), 0.0
        for _ in range(EPISODE):
            u = np.clip(np.array([policy(float(th[0]), float(w[0]))]), -2.0, 2.0)
            th, w, r = diagnosis._pendulum_step(th, w, u)
            total += float(r[0])
        out.append(total)
    return np.asarray(out)


def start_states(n: int) -> np.ndarray:
    return np.random.default_rng(0).uniform([-np.pi, -1.0], [np.pi, 1.0], size=(n, 2))


def optimum_run(args: tuple) -> dict:
    """The γ-optimal policy's undiscounted return from the starts."""
    gamma, grid_shape, n_starts = args
    t0 = time.perf_counter()
    grid = PendulumGrid(*grid_shape)
    v, sweeps = grid.value_iteration(gamma)
    returns = episode_returns(grid.greedy(grid.value_at(v), gamma), start_states(n_starts))
    return {
        "gamma": gamma,
        "mean_return": float(returns.mean()),
        "returns": returns.tolist(),
        "sweeps": sweeps,
        "wall_s": time.perf_counter() - t0,
    }


def learner_run(args: tuple) -> dict:
    """The configured learner after ``steps`` on seed ``seed``'s world, frozen, on the noise-free starts."""
    seed, steps, grid_shape, n_starts = args
    cfg = diagnosis._variant_config("pendulum_slow", {})
    env, agent = diagnosis._build("pendulum_slow", seed, cfg)
    agent.learn(steps)
    env.close()

    def obs(th: np.ndarray, w: np.ndarray) -> np.ndarray:
        return diagnosis._observe(np.atleast_1d(th), np.atleast_1d(w), 0.0, None)  # noise-free

    def mean_action(th: float, w: float) -> float:
        return float(agent.predict(obs(th, w)[0])[0])

    def critic_value(th: np.ndarray, w: np.ndarray) -> np.ndarray:
        return np.array([agent.critic.value(agent.normalize(o)) for o in obs(th, w)])

    grid = PendulumGrid(*grid_shape)
    starts = start_states(n_starts)
    mean_returns = episode_returns(mean_action, starts)
    greedy_returns = episode_returns(grid.greedy(critic_value, cfg["gamma"]), starts)
    return {
        "seed": seed,
        "gamma": cfg["gamma"],
        "mean_policy": float(mean_returns.mean()),
        "critic_greedy": float(greedy_returns.mean()),
        "mean_policy_returns": mean_returns.tolist(),
    }


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--gammas", default="0.9,0.95,0.97,0.98,0.99")
    p.add_argument("--grid", default="181,161", help="θ cells, θ̇ cells")
    p.add_argument("--actions", type=int, default=21)
    p.add_argument("--starts", type=int, default=100)
    p.add_argument("--seeds", type=int, default=5)
    p.add_argument("--steps", type=int, default=20_000)
    p.add_argument("--jobs", type=int, default=1)
    p.add_argument("--out", default="results/pendulum_optimum.json")
    a = p.parse_args()
    shape = (*[int(x) for x in a.grid.split(",")], a.actions)
    gammas = [float(g) for g in a.gammas.split(",")]
    tasks = [(g, shape, a.starts) for g in gammas]
    print(f"value iteration at gamma {gammas}, then the learner on {a.seeds} seeds ...", flush=True)
    optima = diagnosis._pool_map(optimum_run, tasks, a.jobs)
    learned = diagnosis._pool_map(
        learner_run, [(s, a.steps, shape, a.starts) for s in range(a.seeds)], a.jobs
    )
    from experiments.execute import code_version
    from experiments.stats import bootstrap_mean

    out = {
        "command": " ".join(["python", *sys.argv]),
        "code": code_version(),
        "grid": {"theta": shape[0], "speed": shape[1], "torques": shape[2]},
        "starts": a.starts,
        "optimum": optima,
        "learner": learned,
        "summary": {
            "optimum_by_gamma": {str(r["gamma"]): r["mean_return"] for r in optima},
            "learner_mean_policy": bootstrap_mean([r["mean_policy"] for r in learned]),
            "learner_critic_greedy": bootstrap_mean([r["critic_greedy"] for r in learned]),
        },
    }
    Path(a.out).parent.mkdir(parents=True, exist_ok=True)
    Path(a.out).write_text(json.dumps(out, indent=1))
    print("γ-optimal policy, undiscounted 200-step return (mean over the starts):")
    for r in optima:
        print(
            f"  gamma {r['gamma']:.2f}: {r['mean_return']:8.1f}  ({r['sweeps']} sweeps, {r['wall_s']:.0f} s)"
        )
    print("configured learner after its steps, frozen, same starts:")
    for r in learned:
        print(
            f"  seed {r['seed']}: mean action {r['mean_policy']:8.1f}"
            f"   greedy on its critic {r['critic_greedy']:8.1f}"
        )
    print(json.dumps(out["summary"], indent=1))


if __name__ == "__main__":
    main()
