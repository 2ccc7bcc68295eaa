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
3. Critic or actor. The same learner with its actor fed the optimal advantage ``r + γV*(s') - V*(s)`` on
   the env's true states (V* from the value iteration at the learner's γ; the critic still fits, the
   actor ignores it), at the configured step and at twice it (``VARIANTS``): what the learner reaches
   with a perfect critic, its final return paired per seed against its own critic's and against SAC's
   in results/paper.

Writes ``results/pendulum_optimum.json`` and prints a table.

    python bench/pendulum_optimum.py --jobs 2     # ~9 min on two cores
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import gymnasium as gym
import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from learner_diagnosis import paper_finals, pool_map  # noqa: E402  (bench/, this script's folder)

from experiments.envs import make_env  # noqa: E402
from experiments.metrics import run_metrics  # noqa: E402
from experiments.plan import ENVS, agent_config, env_kwargs  # noqa: E402
from sim.pendulum import NSPendulum, angle_normalize  # noqa: E402

EPISODE = NSPendulum.max_steps
SETTING = ENVS["pendulum_slow"]  # the paper bench's NS Pendulum: its worlds, budget and threshold
PAPER_SUMMARY = ROOT / "results" / "paper" / "summary.json"
# The learner's variants measured with and without the oracle: the step as configured and doubled (the
# step the oracle-fed actor did best with; on the learner's own critic its gain was chance, README).
VARIANTS: dict[str, dict] = {"configured": {}, "alpha_0.04": {"alpha": 0.04}}


class PendulumGrid:
    """The noise-free pendulum on a periodic θ grid × a clipped θ̇ grid; every (cell, torque) successor
    is precomputed as bilinear interpolation weights."""

    def __init__(self, n_theta: int, n_speed: int, n_actions: int):
        self.thetas = np.linspace(-np.pi, np.pi, n_theta, endpoint=False)
        self.speeds = np.linspace(-NSPendulum.max_speed, NSPendulum.max_speed, n_speed)
        self.torques = np.linspace(-NSPendulum.max_torque, NSPendulum.max_torque, n_actions)
        th, w, u = np.meshgrid(self.thetas, self.speeds, self.torques, indexing="ij")
        th2, w2, self.reward = NSPendulum.transition(th, w, u)
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
            th2, w2, r = NSPendulum.transition(
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
            th, w, r = NSPendulum.transition(th, w, u)
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


class TrueStateProbe(gym.Wrapper):
    """Keeps the pendulum's true ``(θ, θ̇)`` before and after each step, for the oracle; the learner still
    sees only the noisy observation."""

    def step(self, action):
        self.before = self.unwrapped.state.copy()
        out = self.env.step(action)
        self.after = self.unwrapped.state.copy()
        return out


class OptimalAdvantage:
    """The learner's own critic, fitted as always (its visit counts and baseline stay live), whose
    advantage for the actor is replaced by ``r + γ V*(s') - V*(s)`` on the true states: a sample of the
    optimal advantage, the best signal any critic could hand this actor."""

    def __init__(self, critic, probe: TrueStateProbe, value_of, gamma: float):
        self.critic, self.probe, self.value_of, self.gamma = critic, probe, value_of, gamma

    def update(self, s, r, s_next, terminal, *args, **kwargs) -> float:
        self.critic.update(s, r, s_next, terminal, *args, **kwargs)
        before, after = self.probe.before, self.probe.after
        v_next = 0.0 if terminal else float(self.value_of(after[:1], after[1:])[0])
        return float(r + self.gamma * v_next - self.value_of(before[:1], before[1:])[0])

    def __getattr__(self, name: str):
        return getattr(self.critic, name)


def _learn(seed: int, steps: int, overrides: dict, oracle_value=None):
    """The configured learner (plus ``overrides``) after ``steps`` on seed ``seed``'s world, and its final
    return as the paper bench scores it; ``oracle_value``: the actor learns from the optimal advantage."""
    from learner.registry import make_agent  # the learners load torch: only in the process that runs

    cfg = {**agent_config(SETTING, "adaptiveh"), **overrides}
    env = TrueStateProbe(make_env(SETTING.env_id, env_kwargs(SETTING, seed)))
    agent = make_agent("adaptiveh", env, seed, cfg)
    if oracle_value is not None:
        agent.critic = OptimalAdvantage(agent.critic, env, oracle_value, cfg["gamma"])
    agent.learn(steps)
    env.close()
    eps = agent.log.episodes
    metrics = run_metrics([e.global_step for e in eps], [e.ret for e in eps], steps, SETTING.threshold)
    return agent, cfg, metrics["final_return"]


def learner_run(args: tuple) -> dict:
    """The learner (``VARIANTS[variant]`` on configs/pendulum.yaml) after ``steps`` on seed ``seed``'s world,
    frozen, on the noise-free starts. With ``oracle`` (a grid's γ-optimal value), its actor learned from
    the optimal advantage instead of its critic's."""
    seed, steps, grid_shape, n_starts, *rest = args
    variant, oracle = rest if rest else ("configured", None)
    overrides = VARIANTS[variant]
    grid = PendulumGrid(*grid_shape)
    oracle_value = None if oracle is None else grid.value_at(oracle)
    agent, cfg, final_return = _learn(seed, steps, overrides, oracle_value)

    def obs(th: np.ndarray, w: np.ndarray) -> np.ndarray:
        return NSPendulum.observation(np.atleast_1d(th), np.atleast_1d(w))  # noise-free

    def mean_action(th: float, w: float) -> float:
        return float(agent.predict(obs(th, w)[0])[0])

    def critic_value(th: np.ndarray, w: np.ndarray) -> np.ndarray:
        return np.array([agent.critic.value(agent.normalize(o)) for o in obs(th, w)])

    starts = start_states(n_starts)
    mean_returns = episode_returns(mean_action, starts)
    out = {
        "seed": seed,
        "gamma": cfg["gamma"],
        "variant": variant,
        "overrides": overrides,
        "oracle": oracle is not None,
        "final_return": final_return,
        "mean_policy": float(mean_returns.mean()),
        "mean_policy_returns": mean_returns.tolist(),
    }
    if oracle is None:  # greedy on the learned critic; the oracle's would be the optimum's own
        out["critic_greedy"] = float(episode_returns(grid.greedy(critic_value, cfg["gamma"]), starts).mean())
    return out


def _oracle_summary(runs: list[dict]) -> dict:
    """Per variant: the learned and the oracle-fed actor's final returns, paired per seed, and against SAC."""
    from experiments.stats import bootstrap_mean, bootstrap_paired_diff

    sac = paper_finals(PAPER_SUMMARY, "pendulum_slow", "sac") or None
    out = {}
    for name in VARIANTS:
        mine = [r for r in runs if r["variant"] == name]
        learned = {r["seed"]: r["final_return"] for r in mine if not r["oracle"]}
        oracle = {r["seed"]: r["final_return"] for r in mine if r["oracle"]}
        out[name] = {
            "learned": bootstrap_mean(list(learned.values())) | {"per_seed": learned},
            "oracle": bootstrap_mean(list(oracle.values())) | {"per_seed": oracle},
            "oracle_minus_learned": bootstrap_paired_diff(oracle, learned),
            "oracle_seeds_at_or_above_-250": sum(x >= -250 for x in oracle.values()),
            "learned_mean_policy": bootstrap_mean([r["mean_policy"] for r in mine if not r["oracle"]]),
            "oracle_mean_policy": bootstrap_mean([r["mean_policy"] for r in mine if r["oracle"]]),
        }
        if sac is not None:
            out[name]["oracle_minus_sac"] = bootstrap_paired_diff(oracle, sac)
            out[name]["learned_minus_sac"] = bootstrap_paired_diff(learned, sac)
    return {"sac_final_return_per_seed": sac, "variants": out}


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
    optima = pool_map(optimum_run, tasks, a.jobs)
    learner_gamma = agent_config(SETTING, "adaptiveh")["gamma"]
    oracle_v, _ = PendulumGrid(*shape).value_iteration(learner_gamma)
    runs = [
        (s, a.steps, shape, a.starts, name, oracle_v if oracle else None)
        for name in VARIANTS
        for oracle in (False, True)
        for s in range(a.seeds)
    ]
    learned = pool_map(learner_run, runs, a.jobs)
    from experiments.execute import code_version
    from experiments.stats import bootstrap_mean

    configured = [r for r in learned if r["variant"] == "configured" and not r["oracle"]]
    out = {
        "command": " ".join(["python", *sys.argv]),
        "code": code_version(),
        "grid": {"theta": shape[0], "speed": shape[1], "torques": shape[2]},
        "starts": a.starts,
        "optimum": optima,
        "learner": learned,
        "summary": {
            "optimum_by_gamma": {str(r["gamma"]): r["mean_return"] for r in optima},
            "learner_mean_policy": bootstrap_mean([r["mean_policy"] for r in configured]),
            "learner_critic_greedy": bootstrap_mean([r["critic_greedy"] for r in configured]),
            "optimal_advantage": _oracle_summary(learned),
        },
    }
    Path(a.out).parent.mkdir(parents=True, exist_ok=True)
    Path(a.out).write_text(json.dumps(out, indent=1))
    print("γ-optimal policy, undiscounted 200-step return (mean over the starts):")
    for r in optima:
        print(
            f"  gamma {r['gamma']:.2f}: {r['mean_return']:8.1f}  ({r['sweeps']} sweeps, {r['wall_s']:.0f} s)"
        )
    print("the learner after its steps (final return in training; frozen mean action on the starts):")
    for r in learned:
        who = "optimal advantage" if r["oracle"] else "its own critic   "
        greedy = f"   greedy on its critic {r['critic_greedy']:8.1f}" if "critic_greedy" in r else ""
        print(
            f"  {r['variant']:<10} {who} seed {r['seed']}: final {r['final_return']:8.1f}"
            f"   mean action {r['mean_policy']:8.1f}{greedy}"
        )
    print(json.dumps(out["summary"], indent=1))


if __name__ == "__main__":
    main()
