"""Why AdaptiveH loses on NS Pendulum, measured, before and after the learner changes (issue #15).

Eight parts, each a list of runs made in fresh processes (``--jobs`` at a time):

1. ``probe`` (NS Pendulum, ``--probe-seeds`` seeds, instrumented): along the learner's own run,
   - the critic against Monte-Carlo returns: explained variance and correlation of ``V̂(s_t)`` (read
     before the critic fits the step) with the discounted return that followed in the same episode;
   - every ``--every`` steps, a rollout probe at ``--probe-states`` states the learner visited in the
     last 2000 steps, the policy frozen: the true advantage ``A(s,a) = Q(s,a) - V(s)`` of a sampled
     action and the true ascent direction ``dQ/da`` at the mean (central difference ±σ), both from
     batched pendulum rollouts with common random numbers; against them the learner's advantage
     (corr, sign agreement where the truth is 2 standard errors from 0) and its expected gradient
     ``E_a[g | s]`` (sign agreement), the per-sample signal-to-noise ``|E g| / std g`` of its gradient,
     the same with the oracle state baseline ``E_a[δ | s]`` removed (what the critic's Bellman
     residual costs), the size of that residual, and the share of the TD target's variance that the
     observation noise puts there;
   - the policy: ``|f|`` at the visited states (``f`` the RKHS function inside the tanh; ``|f| > 3``
     is a saturated mean), executed actions clipped at the box, the gradient norm and how often
     ``max_grad_norm`` clips it; dictionary sizes and how well they cover the upright region (mean
     ALD residual of a grid of near-upright states: 0 covered, 1 not).
2. ``performance`` (NS Pendulum, ``--seeds`` seeds, not instrumented): final return (mean of the
   episodes in the last 10 % of steps, as in results/paper), steps to -400, wall-clock of ``learn``,
   peak RSS and the RSS at 25/50/100 % of the steps (flat memory).
3. ``reach`` (NS Reach, ``--seeds`` seeds): the final return of each of ``--reach-variants``
   (``REACH_VARIANTS``, on top of configs/reach.yaml), its difference from the unscheduled learner, and
   paired per seed from the scheduled learner and from TD3's runs in ``--paper-summary``.
4. ``reach_baselines`` (NS Reach, ``--seeds`` seeds): TD3 with each of ``--reach-baselines``
   (``REACH_BASELINE_VARIANTS``: its exploration noise on the grid NS Reach's std was tuned on), paired
   per seed against the paper bench's TD3 and AdaptiveH: what the same tuning does for the baseline.
5. ``pendulum_variants`` (NS Pendulum, ``--seeds`` seeds): the final return of each of
   ``PENDULUM_VARIANTS`` on top of configs/pendulum.yaml, and its paired difference from the configured
   learner (the same seed is the same world).
6. ``noise`` (NS Pendulum as configured, ``--seeds`` seeds): is the gap to TD3 the exploration noise
   or the policy? After the run, its policy frozen on ``--eval-episodes`` fresh episodes with the same
   start states each way: the mean action, and actions sampled at its final std and at half of it.
7. ``env_cost`` (every setting, ``--check-seeds`` seeds): the env alone for a run's steps, uniform random
   actions: the wall-clock every method's run pays before it learns anything, against TD3's wall-clock
   per run in ``--paper-summary`` (the issue asks AdaptiveH for 1/10 of TD3's: on a setting whose env
   alone costs more, no learner can meet it), and on NS Reach the part of it spent in the arm's physics
   and IK (``arm_floor_vs_td3``: what remains with all the glue code gone, the same arm simulated).
8. ``checks`` (NS CartPole slow and fast, NS Reach; ``--check-seeds`` seeds): the final return of
   ``before``, ``after`` and ``options`` with 95 % bootstrap intervals and the intervals of the
   differences from ``before``; ``after_identical_to_before`` says whether the after-learner replayed
   the before-learner's episodes exactly (it should where its settings are the defaults).

Variants, each on top of the env's configs/<env>.yaml agent section as ``adaptiveh bench paper`` runs
it: ``before`` the learner as it was (every option this work added, off); ``after`` the learner as
configured now (``AFTER``: the defaults, which keep the options off, plus NS Pendulum's settings);
``options`` the NS Pendulum options (``OPTIONS``, without its sigma) on another env, the evidence for
keeping them out of the defaults; ``scheduled`` the after-learner with the exploration std and the step
annealed over the run (``SCHEDULES``).

    python bench/learner_diagnosis.py                       # everything (~90 min on 2 cores)
    python bench/learner_diagnosis.py --parts reach --jobs 1 --merge   # NS Reach's variants only
    python bench/learner_diagnosis.py --parts reach_baselines --merge  # TD3's noise on NS Reach (~15 min)
    python bench/learner_diagnosis.py --parts probe --probe-seeds 1 --steps 8000   # a quick look
    python bench/learner_diagnosis.py --parts noise,env_cost --merge   # the noise and the env's cost
    python bench/learner_diagnosis.py --parts pendulum_variants --merge   # NS Pendulum's variants
    python bench/learner_diagnosis.py --parts pendulum_variants --merge --first-seed 5 \
        --pendulum-variants configured,alpha_0.04   # five more seeds (5-9) of two variants
Writes ``results/learner_diagnosis.json`` (``--out``) and prints a summary.
"""

from __future__ import annotations

import argparse
import hashlib
import json
import os
import resource
import sys
import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from multiprocessing import get_context
from pathlib import Path
from typing import Any

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

# The learner as it was before issue #15: every option this work added, off.
BEFORE: dict[str, Any] = {
    "critic": "value",
    "policy_gradient": "sampled",
    "mean_limit": None,
    "visit_step": None,
    "residual_baseline": None,
    "advantage_lambda": 0.0,
}
# The learner options this work added, as NS Pendulum uses them (the "after" learner there); the config
# defaults keep them off because they hurt NS CartPole (the ``options`` variant of the checks shows it).
OPTIONS: dict[str, Any] = {
    "mean_limit": 3.0,
    "visit_step": 20.0,
    "residual_baseline": 0.999,
    "residual_fit": "least_squares",
}
# The learner as it is now, per env: the config defaults plus, on NS Pendulum, the options and a wider
# exploration (sigma 0.5 of the half-range). These are the settings to put in configs/<env>.yaml.
AFTER: dict[str, dict[str, Any]] = {
    "pendulum_slow": {**OPTIONS, "sigma": 0.5},
    "cartpole_slow": {},
    "cartpole_fast": {},
    "reach_slow": {},
}
# Annealing on top of ``after``: measured, the after-learner's mean policy at 20k steps scores -100 to
# -134 on fresh episodes, its training episodes of the last 10 % -268 to -456 (it still swings there).
SCHEDULES: dict[str, Any] = {"sigma_final": 0.2, "alpha_final": 0.004}
UPRIGHT = (0.3, 1.0)  # |θ| (rad) and |θ̇| (rad/s) of the "upright" region


def _variant_config(env_key: str, overrides: dict[str, Any], algo: str = "adaptiveh") -> dict[str, Any]:
    """``algo``'s config as the paper bench runs it on ``env_key`` (AdaptiveH: configs/<env>.yaml's agent
    section; a baseline: its defaults) with a variant's overrides on top."""
    from experiments.plan import ENVS, agent_config

    return {**agent_config(ENVS[env_key], algo), **overrides}


# configs/pendulum.yaml now carries the scheduled learner; every variant starts from the learner as the
# paper bench first ran it (no schedules, NS Pendulum at sigma 0.3), so the measurements stay comparable.
FIRST: dict[str, dict[str, Any]] = {"pendulum_slow": {"sigma": 0.3}}
UNSCHEDULED: dict[str, Any] = {"sigma_final": None, "alpha_final": None}


# NS Reach's variants (part ``reach``), each on top of configs/reach.yaml's agent section with its
# schedules spelled out, so a variant means the same whatever the config anneals to. The training
# episodes of the last 10 % are what the bench scores: at a constant step and std the policy still jitters
# there, and the exploration noise itself costs distance (an oracle that steps straight at the target
# loses ~0.23 of return per 0.5 cm of action noise).
_REACH_KERNEL = {"bandwidth": [5.0] * 12 + [0.5] * 3}  # the kernel the schedules were first tuned with
_STD_TO_01 = {**_REACH_KERNEL, "sigma_final": 0.1, "alpha_final": 0.125}


def _relative_kernel(width: float) -> dict[str, Any]:
    return {"bandwidth": [5.0] * 12 + [width] * 3}


REACH_VARIANTS: dict[str, dict[str, Any]] = {
    "unscheduled": {**_REACH_KERNEL, **UNSCHEDULED},  # configs/reach.yaml before the schedules
    "sigma_only": {**_REACH_KERNEL, "sigma_final": 0.2, "alpha_final": None},
    "small_step": {**_REACH_KERNEL, **UNSCHEDULED, "alpha": 0.1},  # a constant smaller step, no annealing
    "scheduled": {**_REACH_KERNEL, "sigma_final": 0.2, "alpha_final": 0.125},  # the schedules first adopted
    # annealed further: froze a seed
    "step_to_0.02": {**_REACH_KERNEL, "sigma_final": 0.1, "alpha_final": 0.02},
    # The std annealed to the baselines' exploration noise (0.1 of the half-range), the step as scheduled
    "std_to_0.1": _STD_TO_01,
    "std_to_0.05": {**_STD_TO_01, "sigma_final": 0.05},
    "std_to_0.1_step_0.25": {**_STD_TO_01, "alpha_final": 0.25},
    # with the std to 0.1: the policy kernel's width on the relative target coordinates (0.5 above)
    "std_to_0.1_relative_bw_0.4": {**_STD_TO_01, **_relative_kernel(0.4)},
    "std_to_0.1_relative_bw_0.3": {**_STD_TO_01, **_relative_kernel(0.3)},  # configs/reach.yaml now
    "std_to_0.1_relative_bw_0.2": {**_STD_TO_01, **_relative_kernel(0.2)},
    "std_to_0.1_relative_bw_1": {**_STD_TO_01, **_relative_kernel(1.0)},
    "std_to_0.1_relative_bw_0.3_budget_200": {**_STD_TO_01, **_relative_kernel(0.3), "policy_budget": 200},
    "std_to_0.1_q_critic": {**_STD_TO_01, "critic": "q", "policy_gradient": "expected"},
    "std_to_0.1_residual": {**_STD_TO_01, "residual_baseline": 0.999, "residual_fit": "least_squares"},
}


# The same lever for the baseline (part ``reach_baselines``): TD3's exploration noise on NS Reach, on the
# grid NS Reach's std got (0.2 / 0.1 / 0.05 of the half-range there; 0.1 is the zoo's, the paper bench's
# TD3, which ``td3_noise_0.1`` replays seed for seed).
REACH_BASELINE_VARIANTS: dict[str, tuple[str, dict[str, Any]]] = {
    "td3_noise_0.1": ("td3", {}),
    "td3_noise_0.05": ("td3", {"noise_std": 0.05}),
    "td3_noise_0.2": ("td3", {"noise_std": 0.2}),
}


# NS Pendulum's variants (part ``pendulum_variants``), each on top of configs/pendulum.yaml as configured;
# none beat it (docs/learner_measurements.md). A longer horizon with the step scaled by (1 - γ) so that the
# actor's α/(1-γ) stays; GAE(λ) advantages; the critic's own, narrower kernel (a value function can be
# sharper than a policy needs to be); a longer critic memory, longer GAE traces, shorter segments and a
# wider start of the annealed exploration.
PENDULUM_VARIANTS: dict[str, dict[str, Any]] = {
    "configured": {},
    "gamma_0.98_scaled": {"gamma": 0.98, "alpha": 0.008, "alpha_final": 0.0016},
    "gamma_0.97_scaled": {"gamma": 0.97, "alpha": 0.012, "alpha_final": 0.0024},
    "gae_0.5": {"advantage_lambda": 0.5},
    "critic_bandwidth_0.25": {"critic_bandwidth": 0.25},
    "critic_bandwidth_0.2": {"critic_bandwidth": 0.2},
    "critic_bandwidth_0.15": {"critic_bandwidth": 0.15},
    "critic_forgetting_0.9995": {"critic_forgetting": 0.9995},
    "gae_0.8": {"advantage_lambda": 0.8},
    "h_max_20": {"h_max": 20},
    "sigma_0.7": {"sigma": 0.7},
    # Session of 2026-12-01: re-used samples (learner/replay.py: a window of recent transitions re-scored
    # by the critic as it stands, truncated importance ratio), the critic's eligibility trace (LSTD(λ)),
    # the critic's prior/cap P0 (with a longer horizon too), a wider and a finer critic, no weight decay, a
    # larger step and a looser gradient clip.
    "replay_256_8": {"replay_window": 256, "replay_batch": 8},
    "replay_256_32": {"replay_window": 256, "replay_batch": 32},
    "replay_1000_16_half_step": {"replay_window": 1000, "replay_batch": 16, "replay_step": 0.5},
    "critic_lambda_0.5": {"critic_lambda": 0.5},
    "critic_lambda_0.8": {"critic_lambda": 0.8},
    "critic_p0_100": {"critic_p0": 100.0},
    "gamma_0.97_scaled_p0_100": {"gamma": 0.97, "alpha": 0.012, "alpha_final": 0.0024, "critic_p0": 100.0},
    "critic_bandwidth_0.5": {"critic_bandwidth": 0.5},
    "critic_ald_0.02_budget_500": {"critic_ald": 0.02, "critic_budget": 500},
    "weight_decay_0": {"weight_decay": 0.0},
    "alpha_0.03": {"alpha": 0.03, "alpha_final": 0.006},
    "grad_norm_300": {"max_grad_norm": 300.0},
    # The step's schedule around the configured 0.02 -> 0.004: how far apart neighbouring settings land.
    "alpha_0.04": {"alpha": 0.04},
    "alpha_0.04_to_0.002": {"alpha": 0.04, "alpha_final": 0.002},
    "alpha_0.03_to_0.004": {"alpha": 0.03},
    "alpha_0.05": {"alpha": 0.05},
}


def _overrides(env_key: str, variant: str) -> dict[str, Any]:
    base = {**UNSCHEDULED, **FIRST.get(env_key, {})}
    if variant == "before":
        return {**base, **BEFORE}
    if variant == "options":
        return {**base, **OPTIONS}
    if variant == "scheduled":
        return {**base, **AFTER.get(env_key, {}), **SCHEDULES}
    return {**base, **AFTER.get(env_key, {})}


def _rss_mb() -> float:
    from common.proc_status import status_field

    rss = status_field("VmRSS")
    return int(rss) / 1024.0 if rss is not None else float("nan")


def _build(env_key: str, seed: int, cfg: dict[str, Any], algo: str = "adaptiveh", wrap=None):
    """The paper bench's env for ``seed`` (inside ``wrap`` when given, e.g. a probe) and the agent on it."""
    from experiments.envs import make_env
    from experiments.plan import ENVS, env_kwargs
    from learner.registry import make_agent

    env = make_env(ENVS[env_key].env_id, env_kwargs(ENVS[env_key], seed))
    if wrap is not None:
        env = wrap(env)
    return env, make_agent(algo, env, seed, cfg)


def _run_metrics(agent, env_key: str, steps: int) -> dict[str, Any]:
    """The paper bench's metrics (final return, steps to threshold, curve) of the agent's episodes."""
    from experiments.metrics import run_metrics
    from experiments.plan import ENVS

    episodes = agent.log.episodes
    return run_metrics(
        [e.global_step for e in episodes], [e.ret for e in episodes], steps, ENVS[env_key].threshold
    )


# ---------------------------------------------------------------------------------------------------
# Batched NS Pendulum under the learner's frozen policy (the env's own constants and reward)
# ---------------------------------------------------------------------------------------------------


def _observe(th: np.ndarray, w: np.ndarray, b: float, rng: np.random.Generator) -> np.ndarray:
    """The env's observation of each state with its uniform noise in ``[-b, b]``, from ``rng``."""
    from sim.pendulum import NSPendulum

    obs = NSPendulum.observation(th, w)
    noise = rng.uniform(-b, b, obs.shape) if b > 0 else 0.0  # drawn always: streams stay aligned
    return obs + noise if b > 0 else obs


def _batch_f(agent, obs: np.ndarray) -> np.ndarray:
    """``f`` (inside the tanh) of the policy at a batch of raw observations: (n, action_dim)."""
    s = agent.normalize(obs)
    f = agent.policy.f
    if len(f) == 0:
        return np.zeros((len(obs), len(agent.policy.low)))
    return agent.kernel(s, f.dictionary.centers) @ f.weights


def _batch_mean(agent, obs: np.ndarray) -> np.ndarray:
    return agent.policy.centre + agent.policy.half_range * np.tanh(_batch_f(agent, obs))


def _returns(agent, th, w, first_u, b, horizon, seed) -> np.ndarray:
    """Discounted returns from true states ``(th, w)``: ``first_u`` first, then the agent's policy."""
    from sim.pendulum import NSPendulum

    rng = np.random.default_rng(seed)
    sig, lo, hi = agent.policy.sigma[0], agent.policy.low[0], agent.policy.high[0]
    gamma = agent.config.gamma
    g, disc = np.zeros(len(th)), 1.0
    for t in range(horizon):
        obs = _observe(th, w, b, rng)
        eps = rng.standard_normal(len(th))
        u = np.clip(first_u if t == 0 else _batch_mean(agent, obs)[:, 0] + sig * eps, lo, hi)
        th, w, r = NSPendulum.transition(th, w, u)
        g += disc * r
        disc *= gamma
    return g


def _batch_value(agent, obs: np.ndarray) -> np.ndarray:
    """The value critic's ``V̂`` at a batch of raw observations."""
    s = agent.normalize(obs)
    c = agent.critic
    return c.state_kernel(s, c.dictionary.centers) @ c.theta if len(c) else np.zeros(len(obs))


def gae_probe(agent, th0, w0, obs0, mu0, d_true, d_sig, b, n_act, seed) -> dict:
    """Bias and noise of GAE(λ) advantages from the value critic, at each λ: a batch of ``n_act`` sampled
    actions per state, each followed by the frozen policy; ``Â^λ = Σ_k (γλ)^k δ_{t+k}`` with the
    critic's ``δ``. Reports the sign agreement / corr of ``E_a[c Â^λ score]`` with the true ``dQ/da`` and
    the per-sample SNR, the quantities the λ trade-off is about (λ = 0 is the TD error)."""
    from sim.pendulum import NSPendulum

    gamma, sig = agent.config.gamma, agent.policy.sigma[0]
    lo, hi = agent.policy.low[0], agent.policy.high[0]
    horizon = int(min(300, np.ceil(np.log(0.01) / np.log(gamma * 0.95))))
    rng = np.random.default_rng(seed)
    n = len(th0)
    th, w = np.repeat(th0, n_act), np.repeat(w0, n_act)
    a = np.repeat(mu0, n_act) + sig * rng.standard_normal(n * n_act)
    v_prev = np.repeat(_batch_value(agent, obs0), n_act)
    deltas = np.zeros((horizon, n * n_act))
    u = np.clip(a, lo, hi)
    for t in range(horizon):
        th, w, r = NSPendulum.transition(th, w, u)
        obs = _observe(th, w, b, rng)
        v = _batch_value(agent, obs)
        deltas[t] = r + gamma * v - v_prev
        v_prev = v
        u = np.clip(_batch_mean(agent, obs)[:, 0] + sig * rng.standard_normal(len(th)), lo, hi)
    score = agent.policy.half_range[0] * (a - np.repeat(mu0, n_act)) / sig**2
    out = {}
    for lam in (0.0, 0.5, 0.8, 0.9, 0.95):
        adv = ((gamma * lam) ** np.arange(horizon)) @ deltas
        g = (agent.grad_scale * adv * score).reshape(n, n_act)
        d = g.mean(1)
        out[str(lam)] = {
            "gradient_sign_agreement": float(np.mean(np.sign(d[d_sig]) == np.sign(d_true[d_sig])))
            if d_sig.any()
            else None,
            "gradient_corr": float(np.corrcoef(d, d_true)[0, 1]),
            "per_sample_snr": float(np.median(np.abs(d) / (g.std(1) + 1e-12))),
        }
    return out


def rollout_probe(agent, states: np.ndarray, b: float, n_states: int, reps: int, seed: int) -> dict:
    """The rollout measurements of the module docstring at ``n_states`` of ``states`` (rows th, θ̇); the
    learner's advantage and gradient are its own (``AdaptiveH.frozen_gradient``), its critic not fitted."""
    from sim.pendulum import NSPendulum

    cfg = agent.config
    horizon = int(min(300, np.ceil(np.log(0.01) / np.log(cfg.gamma))))
    rng = np.random.default_rng(seed)
    pick = states[rng.choice(len(states), min(n_states, len(states)), replace=False)]
    n = len(pick)
    th0, w0 = pick[:, 0], pick[:, 1]
    obs0 = _observe(th0, w0, b, rng)
    mu0 = _batch_mean(agent, obs0)[:, 0]
    sig, lo, hi = agent.policy.sigma[0], agent.policy.low[0], agent.policy.high[0]
    a0 = mu0 + sig * rng.standard_normal(n)
    rep = lambda x: np.repeat(x, reps)  # noqa: E731
    th_r, w_r = rep(th0), rep(w0)
    base_u = rep(mu0) + sig * rng.standard_normal(n * reps)
    run = lambda u: _returns(agent, th_r, w_r, u, b, horizon, seed + 1).reshape(n, reps)  # noqa: E731
    gq, gv, gp, gm = run(rep(a0)), run(base_u), run(rep(mu0 + sig)), run(rep(mu0 - sig))
    a_true, a_se = (gq - gv).mean(1), (gq - gv).std(1) / np.sqrt(reps)
    fd = (gp - gm) / (2 * sig)
    d_true, d_se = fd.mean(1), fd.std(1) / np.sqrt(reps)

    n_act = 48
    a_hat, d_hat, snr, snr_oracle, resid, noise_share = [], [], [], [], [], []
    for i in range(n):
        s = agent.normalize(obs0[i])
        th1, w1, r1 = NSPendulum.transition(th0[i : i + 1], w0[i : i + 1], np.clip(a0[i : i + 1], lo, hi))
        s1 = agent.normalize(_observe(th1, w1, b, rng)[0])
        a_hat.append(agent.frozen_gradient(s, a0[i : i + 1], float(r1[0]), s1)[1])
        acts = mu0[i] + sig * rng.standard_normal(n_act)
        th1, w1, r1 = NSPendulum.transition(
            np.full(n_act, th0[i]), np.full(n_act, w0[i]), np.clip(acts, lo, hi)
        )
        o1, o1_clean = _observe(th1, w1, b, rng), _observe(th1, w1, 0.0, rng)
        rows = [
            agent.frozen_gradient(s, acts[j : j + 1], float(r1[j]), agent.normalize(o1[j]))
            for j in range(n_act)
        ]
        g = np.array([row[0][0] for row in rows])
        d_hat.append(g.mean())
        snr.append(abs(g.mean()) / (g.std() + 1e-12))
        if cfg.critic == "value":  # the TD error itself: the advantage with the state baseline put back
            td = np.array([row[1] for row in rows]) + agent.critic.residual(s)
            score = np.array([agent.policy.score(s, acts[j : j + 1])[0] for j in range(n_act)])
            g_oracle = agent.grad_scale * (td - td.mean()) * score
            snr_oracle.append(abs(g_oracle.mean()) / (g_oracle.std() + 1e-12))
            resid.append(abs(td.mean()))
            v1 = np.array([agent.critic.value(agent.normalize(o)) for o in o1])
            v1c = np.array([agent.critic.value(agent.normalize(o)) for o in o1_clean])
            noise_share.append(np.var(cfg.gamma * (v1 - v1c)) / (np.var(r1 + cfg.gamma * v1) + 1e-12))
    a_hat, d_hat = np.array(a_hat), np.array(d_hat)
    a_sig, d_sig = np.abs(a_true) > 2 * a_se, np.abs(d_true) > 2 * d_se

    def agree(est, truth, mask):
        return float(np.mean(np.sign(est[mask]) == np.sign(truth[mask]))) if mask.any() else None

    med = lambda x: float(np.median(x)) if len(x) else None  # noqa: E731
    gae = None
    if cfg.critic == "value":
        gae = gae_probe(agent, th0, w0, obs0, mu0, d_true, d_sig, b, 32, seed + 7)
    return {
        "gae_lambda": gae,
        "states": n,
        "noise_bound": b,
        "advantage_corr": float(np.corrcoef(a_hat, a_true)[0, 1]),
        "advantage_sign_agreement": agree(a_hat, a_true, a_sig),
        "advantage_abs_learner": float(np.abs(a_hat).mean()),
        "advantage_abs_true": float(np.abs(a_true).mean()),
        "gradient_sign_agreement": agree(d_hat, d_true, d_sig),
        "gradient_corr": float(np.corrcoef(d_hat, d_true)[0, 1]),
        "significant_states": int(d_sig.sum()),
        "per_sample_snr": med(snr),
        "per_sample_snr_oracle_baseline": med(snr_oracle),
        "bellman_residual_abs": med(resid),
        "obs_noise_share_of_target_var": med(noise_share),
    }


def _coverage(agent) -> dict[str, float]:
    """Mean ALD residual of a grid of upright states against each dictionary (0: covered, 1: not)."""
    ths, ws = np.linspace(-UPRIGHT[0], UPRIGHT[0], 7), np.linspace(-UPRIGHT[1], UPRIGHT[1], 5)
    grid = np.array([[np.cos(t), np.sin(t), w] for t in ths for w in ws])
    out = {}
    for name, dic in (("policy", agent.policy.f.dictionary), ("critic", agent.critic.dictionary)):
        res = []
        for o in grid:
            s = agent.normalize(o)
            if dic.kernel.dim > len(s):  # the state-action critic: the upright states at the mean action
                s = np.concatenate([s, np.tanh(agent.policy.f(s))])
            res.append(dic.ald(s)[2])
        out[name] = float(np.mean(res))
    return out


def probe_run(args: tuple[str, dict, int, int, int, int, int]) -> dict:
    """One instrumented NS Pendulum run with rollout probes every ``every`` steps."""
    variant, overrides, seed, steps, every, n_states, reps = args
    cfg = _variant_config("pendulum_slow", overrides)
    env, agent = _build("pendulum_slow", seed, cfg)
    base = env.unwrapped
    rec: dict[str, list] = {k: [] for k in ("v", "r", "gnorm", "f", "clipped", "episode")}
    inner = agent._gradient

    def recorded(s, raw, score, reward, s_next, terminated):
        c = agent.critic
        if agent.config.critic == "q":
            sig = agent.policy.sigma / agent.policy.half_range
            v = c.value(s, np.tanh(agent.policy.f(s)), sig)
        else:
            v = c.value(s)
        g, adv = inner(s, raw, score, reward, s_next, terminated)
        rec["v"].append(v)
        rec["r"].append(reward)
        rec["gnorm"].append(float(np.linalg.norm(g)))
        rec["f"].append(float(np.abs(agent.policy.f(s)).max()))
        rec["clipped"].append(bool(np.any((raw < agent.policy.low) | (raw > agent.policy.high))))
        rec["episode"].append(len(agent.log.episodes))
        return g, adv

    agent._gradient = recorded
    states, probes = [], []
    t0 = time.perf_counter()
    for t in range(1, steps + 1):
        agent.step_env()
        if base.state is not None:
            states.append(np.array(base.state, float))
        if t % every == 0:
            recent = np.array(states[-2000:])
            recent[:, 0] = (recent[:, 0] + np.pi) % (2 * np.pi) - np.pi
            p = rollout_probe(agent, recent, base.noise_schedule.value, n_states, reps, seed * 1000 + t)
            lo = max(0, len(rec["f"]) - every)
            f = np.array(rec["f"][lo:])
            gn = np.array(rec["gnorm"][lo:])
            eps = [e.ret for e in agent.log.episodes if e.global_step > t - every]
            p.update(
                step=t,
                return_mean=float(np.mean(eps)) if eps else None,
                f_abs_percentiles={str(q): float(np.percentile(f, q)) for q in (10, 50, 90)},
                frac_mean_saturated=float(np.mean(f > 3.0)),
                frac_actions_clipped=float(np.mean(rec["clipped"][lo:])),
                grad_norm_percentiles={str(q): float(np.percentile(gn, q)) for q in (10, 50, 90)},
                frac_grad_clipped=float(np.mean(gn >= agent.config.max_grad_norm * (1 - 1e-9))),
                dictionary={"policy": len(agent.policy.f), "critic": len(agent.critic)},
                upright_coverage_ald_residual=_coverage(agent),
                frac_upright=float(
                    np.mean((np.abs(recent[:, 0]) < UPRIGHT[0]) & (np.abs(recent[:, 1]) < UPRIGHT[1]))
                ),
                H_mean=float(np.mean([s.H for s in agent.log.segments if s.global_step > t - every] or [0])),
            )
            probes.append(p)
    wall = time.perf_counter() - t0
    critic_mc = _critic_vs_mc(rec, agent.config.gamma, every, steps)
    return {
        "variant": variant,
        "seed": seed,
        "config": cfg,
        "wall_s_with_probes": wall,
        "probes": probes,
        "critic_vs_mc": critic_mc,
    }


def _critic_vs_mc(rec: dict, gamma: float, every: int, steps: int) -> list[dict]:
    """Explained variance / correlation of the online ``V̂(s_t)`` against the discounted return that
    followed in its episode (only steps whose tail beyond the episode's end weighs < 1 %)."""
    v, r, ep = np.array(rec["v"]), np.array(rec["r"]), np.array(rec["episode"])
    tail = int(np.ceil(np.log(0.01) / np.log(gamma)))
    g = np.full(len(r), np.nan)
    for e in np.unique(ep):
        idx = np.nonzero(ep == e)[0]
        acc, out = 0.0, np.zeros(len(idx))
        for k in range(len(idx) - 1, -1, -1):
            acc = r[idx[k]] + gamma * acc
            out[k] = acc
        keep = len(idx) - tail
        if len(idx) >= 200 and keep > 0:  # complete (truncated) episodes only
            g[idx[:keep]] = out[:keep]
    blocks = []
    for lo in range(0, steps, every):
        m = np.isfinite(g[lo : lo + every])
        if m.sum() < 20:
            continue
        gg, vv = g[lo : lo + every][m], v[lo : lo + every][m]
        blocks.append(
            {
                "steps": [lo, lo + every],
                "explained_variance": float(1 - np.var(gg - vv) / np.var(gg)),
                "corr": float(np.corrcoef(gg, vv)[0, 1]),
                "rmse": float(np.sqrt(np.mean((gg - vv) ** 2))),
                "mc_return_mean": float(gg.mean()),
            }
        )
    return blocks


# ---------------------------------------------------------------------------------------------------
# Plain runs: performance and the other envs
# ---------------------------------------------------------------------------------------------------


def plain_run(args: tuple) -> dict:
    """One run of AdaptiveH (or, with a sixth element, of that algorithm on its paper-bench config plus
    the overrides) as the paper bench runs it, uninstrumented."""
    env_key, variant, overrides, seed, steps, *rest = args
    algo = rest[0] if rest else "adaptiveh"
    cfg = _variant_config(env_key, overrides, algo)
    env, agent = _build(env_key, seed, cfg, algo)
    rss, wall, cpu = {}, 0.0, 0.0
    # a baseline learns in one call, as in the paper bench (SB3 trains a cut rollout at each call's end)
    marks = sorted({steps // 4, steps // 2, steps}) if algo == "adaptiveh" else [steps]
    done = 0
    for m in marks:
        t0, c0 = time.perf_counter(), time.process_time()
        agent.learn(m - done)
        wall += time.perf_counter() - t0
        cpu += time.process_time() - c0
        done = m
        rss[str(m)] = _rss_mb()
    log = agent.log
    metrics = _run_metrics(agent, env_key, steps)
    env.close()
    return {
        "env": env_key,
        "variant": variant,
        "seed": seed,
        "steps": steps,
        "final_return": metrics["final_return"],
        "returns_digest": hashlib.sha256(np.asarray([e.ret for e in log.episodes]).tobytes()).hexdigest()[
            :16
        ],
        "steps_to_threshold": metrics["steps_to_threshold"],
        "reached": metrics["reached"],
        "curve": metrics["curve"],
        "wall_s": wall,
        "cpu_s": cpu,  # this process's CPU time in learn: what the run costs, whatever else the machine ran
        "steps_per_s": steps / wall,
        "peak_rss_mb": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0,
        "rss_mb_at_step": rss,
        "algo": algo,
        "dictionary": {"policy": len(agent.policy.f), "critic": len(agent.critic)}
        if algo == "adaptiveh"
        else None,
        "config": cfg,
    }


def noise_run(args: tuple[int, int, int]) -> dict:
    """The configured NS Pendulum learner, then its frozen policy on paired fresh episodes."""
    seed, steps, episodes = args
    cfg = _variant_config("pendulum_slow", {})
    env, agent = _build("pendulum_slow", seed, cfg)
    agent.learn(steps)
    final = _run_metrics(agent, "pendulum_slow", steps)["final_return"]
    std = agent.policy.sigma / agent.policy.half_range  # the final exploration std, of the half-range
    out: dict[str, Any] = {"seed": seed, "steps": steps, "train_final_return": final}
    world = env.unwrapped.get_state()  # the noise drifts with every step: each mode starts from this world
    for label, scale in (("mean_action", None), ("sampled_final_std", 1.0), ("sampled_half_std", 0.5)):
        env.unwrapped.set_state(world)
        if scale is not None:
            agent.policy.explore(scale * std * agent.policy.half_range)
        rng = np.random.default_rng(10_000 + seed)
        returns = []
        for episode in range(episodes):
            obs, _ = env.reset(seed=10_000 + episode)  # the same start states for every label
            total, done = 0.0, False
            while not done:
                if scale is None:
                    action = agent.predict(obs, deterministic=True)
                else:
                    action = agent.policy.sample(agent.normalize(obs), rng)[0]
                obs, reward, terminated, truncated, _ = env.step(action)
                total, done = total + float(reward), terminated or truncated
            returns.append(total)
        out[label] = float(np.mean(returns))
    out["final_std"] = float(np.mean(std))
    env.close()
    return out


@contextmanager
def _timed(owner: Any, name: str, spent: dict[str, float], key: str) -> Iterator[None]:
    """Inside the block, ``owner.name`` adds its calls' wall-clock to ``spent[key]``; restored after."""
    inner = getattr(owner, name)

    def wrapper(*args: Any, **kwargs: Any) -> Any:
        t = time.perf_counter()
        try:
            return inner(*args, **kwargs)
        finally:
            spent[key] += time.perf_counter() - t

    setattr(owner, name, wrapper)
    try:
        yield
    finally:
        setattr(owner, name, inner)


def env_cost_run(args: tuple[str, int]) -> dict:
    """One setting's env alone for a run's steps (seeded uniform random actions), timed as ``learn`` is,
    with the part of it spent in the arm's physics (PyBullet's ``stepSimulation``) and its IK (mink's
    ``solve_ik``): what no faster glue code can remove without simulating a different arm."""
    import mink
    import pybullet

    from experiments.envs import make_env
    from experiments.plan import ENVS, env_kwargs

    env_key, seed = args
    spec = ENVS[env_key]
    env = make_env(spec.env_id, env_kwargs(spec, seed))
    env.action_space.seed(seed)
    env.reset(seed=seed)
    spent = {"physics_s": 0.0, "ik_s": 0.0}
    with _timed(pybullet, "stepSimulation", spent, "physics_s"), _timed(mink, "solve_ik", spent, "ik_s"):
        t0, c0 = time.perf_counter(), time.process_time()
        for _ in range(spec.steps):
            _, _, terminated, truncated, _ = env.step(env.action_space.sample())
            if terminated or truncated:
                env.reset()
        wall, cpu = time.perf_counter() - t0, time.process_time() - c0
    env.close()
    return {"env": env_key, "seed": seed, "steps": spec.steps, "wall_s": wall, "cpu_s": cpu, **spent}


def _env_cost_summary(runs: list[dict], paper_summary: Path) -> dict:
    """Per setting: the env's wall-clock per run, TD3's and AdaptiveH's in the paper bench, and the
    floor, env / TD3: the smallest wall-clock ratio to TD3 that any learner could reach there."""
    cost = json.loads(paper_summary.read_text())["cost"] if paper_summary.is_file() else {}
    shown = paper_summary.relative_to(ROOT) if paper_summary.is_relative_to(ROOT) else paper_summary
    out: dict[str, Any] = {"paper_summary": str(shown)}
    for env_key in dict.fromkeys(r["env"] for r in runs):
        mine = [r for r in runs if r["env"] == env_key]
        env_s = float(np.mean([r["wall_s"] for r in mine]))
        # NS Reach: the arm's physics and IK, the part of the env no glue code can remove (none for an env
        # without an arm, or runs recorded before the split)
        timed = all("physics_s" in r for r in mine)
        arm_s = float(np.mean([r["physics_s"] + r["ik_s"] for r in mine])) if timed else 0.0
        entry: dict[str, Any] = {"env_only_wall_s_per_run": round(env_s, 2)}
        if arm_s > 0:
            entry["arm_physics_ik_s_per_run"] = round(arm_s, 2)
        for algo in ("td3", "adaptiveh"):
            wall = cost.get(algo, {}).get("by_env", {}).get(env_key, {}).get("wall_s_per_run")
            entry[f"{algo}_wall_s_per_run"] = None if wall is None else round(wall, 2)
        if entry["td3_wall_s_per_run"]:
            entry["floor_vs_td3"] = round(env_s / entry["td3_wall_s_per_run"], 3)
            if arm_s > 0:
                entry["arm_floor_vs_td3"] = round(arm_s / entry["td3_wall_s_per_run"], 3)
        out[env_key] = entry
    return out


def _names(csv: str) -> list[str]:
    return [v for v in csv.split(",") if v]


def pool_map(fn: Callable[[Any], Any], tasks: list, jobs: int) -> list:
    """``fn`` over ``tasks`` in ``jobs`` fresh one-thread processes at a time (also pendulum_optimum's)."""
    if jobs <= 1:
        return [fn(t) for t in tasks]
    with get_context("spawn").Pool(jobs, maxtasksperchild=1, initializer=_one_thread) as pool:
        return pool.map(fn, tasks, chunksize=1)


def _one_thread() -> None:
    for var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
        os.environ[var] = "1"


def _group(runs: list[dict], key: str = "final_return") -> dict:
    from experiments.stats import bootstrap_mean

    return bootstrap_mean([r[key] for r in runs])


def _finals(runs: list[dict], variant: str) -> dict[int, float]:
    """A variant's final return per seed (a seed is one world for every variant: the pairing key)."""
    return {r["seed"]: r["final_return"] for r in runs if r["variant"] == variant}


def _pendulum_variants_summary(runs: list[dict]) -> dict:
    """Each variant's final return, and its paired difference from the configured learner."""
    from experiments.stats import bootstrap_paired_diff

    base = _finals(runs, "configured")
    out = {}
    for v in dict.fromkeys(r["variant"] for r in runs):
        rs = [r for r in runs if r["variant"] == v]
        entry = {**_group(rs), "per_seed": [round(r["final_return"], 1) for r in rs]}
        entry["seeds_at_or_above_-250"] = sum(r["final_return"] >= -250 for r in rs)
        if v != "configured" and base:
            entry["minus_configured_paired"] = bootstrap_paired_diff(_finals(runs, v), base)
        out[v] = entry
    return out


def paper_finals(paper_summary: Path, setting: str, method: str) -> dict[int, float]:
    """``method``'s final return per seed on ``setting`` in the paper bench's summary."""
    if not paper_summary.is_file():
        return {}
    runs = json.loads(paper_summary.read_text()).get("per_run", {})
    prefix = f"{setting}__{method}__s"
    return {
        int(k[len(prefix) :].split("__")[0]): r["final_return"]
        for k, r in runs.items()
        if k.startswith(prefix)
    }


def _reach_summary(reach: list[dict], paper_summary: Path) -> dict:
    """Each NS Reach variant's final return; its difference from the unscheduled learner (unpaired, as
    first reported), and paired per seed from the scheduled learner and from TD3 in the paper bench."""
    from experiments.stats import bootstrap_diff, bootstrap_paired_diff

    td3, out = paper_finals(paper_summary, "reach_slow", "td3"), {}
    unscheduled, scheduled = _finals(reach, "unscheduled"), _finals(reach, "scheduled")
    for variant in REACH_VARIANTS:
        rs = [r for r in reach if r["variant"] == variant]
        if not rs:
            continue
        mine = _finals(reach, variant)
        entry = {**_group(rs), "per_seed": [round(r["final_return"], 2) for r in rs]}
        if variant != "unscheduled" and unscheduled:
            entry["minus_unscheduled"] = bootstrap_diff(
                [r["final_return"] for r in rs], list(unscheduled.values())
            )
        if variant != "scheduled" and scheduled:
            entry["minus_scheduled_paired"] = bootstrap_paired_diff(mine, scheduled)
        if td3:
            entry["minus_td3_paired"] = bootstrap_paired_diff(mine, td3)
        entry["dictionary_mean"] = {
            k: float(np.mean([r["dictionary"][k] for r in rs])) for k in ("policy", "critic")
        }
        out[f"reach_{variant}"] = entry
    return out


def _reach_baselines_summary(runs: list[dict], paper_summary: Path) -> dict:
    """Each baseline variant's final return, paired per seed against the paper bench's TD3 (the zoo's
    noise) and against AdaptiveH there: what the lever NS Reach's std was tuned with does for TD3."""
    from experiments.stats import bootstrap_paired_diff

    td3 = paper_finals(paper_summary, "reach_slow", "td3")
    ours = paper_finals(paper_summary, "reach_slow", "adaptiveh")
    out = {}
    for v in dict.fromkeys(r["variant"] for r in runs):
        finals = _finals(runs, v)
        entry = {
            **_group([r for r in runs if r["variant"] == v]),
            "per_seed": [round(x, 2) for x in finals.values()],
        }
        if td3:
            entry["minus_paper_td3_paired"] = bootstrap_paired_diff(finals, td3)
            entry["replays_paper_td3"] = all(abs(finals[k] - td3[k]) < 1e-9 for k in finals if k in td3)
        if ours:
            entry["paper_adaptiveh_minus_this_paired"] = bootstrap_paired_diff(ours, finals)
        out[v] = entry
    return out


def summarize(out: dict, paper_summary: Path) -> dict:
    from experiments.stats import bootstrap_diff

    summary: dict[str, Any] = {}
    perf = out.get("performance") or []
    for variant in ("before", "after", "scheduled"):
        rs = [r for r in perf if r["variant"] == variant]
        if not rs:
            continue
        summary[f"pendulum_{variant}"] = {
            "final_return": _group(rs),
            "per_seed": [round(r["final_return"], 1) for r in rs],
            "seeds_at_or_above_-250": sum(r["final_return"] >= -250 for r in rs),
            "seeds_reaching_-400": sum(r["reached"] for r in rs),
            "wall_s_mean": float(np.mean([r["wall_s"] for r in rs])),
            "cpu_s_mean": float(np.mean([r.get("cpu_s", np.nan) for r in rs])),
            "peak_rss_mb_mean": float(np.mean([r["peak_rss_mb"] for r in rs])),
        }
    by_variant = {v: [r["final_return"] for r in perf if r["variant"] == v] for v in ("after", "scheduled")}
    if all(by_variant.values()):
        diff = bootstrap_diff(by_variant["scheduled"], by_variant["after"])
        summary["pendulum_scheduled_minus_after"] = diff
    for env_key in sorted({r["env"] for r in out.get("checks") or []}):
        rs = [r for r in out["checks"] if r["env"] == env_key]
        by = {v: [r for r in rs if r["variant"] == v] for v in ("before", "after", "options")}
        b = [r["final_return"] for r in by["before"]]
        entry: dict[str, Any] = {}
        for v in ("before", "after", "options"):
            if not by[v]:
                continue
            entry[v] = _group(by[v])
            entry[v]["per_seed"] = [round(r["final_return"], 1) for r in by[v]]
            entry[v]["wall_s_mean"] = float(np.mean([r["wall_s"] for r in by[v]]))
            if v != "before" and b:
                entry[f"{v}_minus_before"] = bootstrap_diff([r["final_return"] for r in by[v]], b)
        if by["after"] and by["before"]:
            digests = {r["seed"]: r["returns_digest"] for r in by["before"]}
            entry["after_identical_to_before"] = all(
                digests.get(r["seed"]) == r["returns_digest"] for r in by["after"]
            )
        summary[env_key] = entry
    summary.update(_reach_summary(out.get("reach") or [], paper_summary))
    if out.get("reach_baselines"):
        summary["reach_baselines"] = _reach_baselines_summary(out["reach_baselines"], paper_summary)
    probes = out.get("probe") or []
    for variant in ("before", "after"):
        ps = [p for run in probes if run["variant"] == variant for p in run["probes"]]
        if not ps:
            continue
        keys = (
            "advantage_corr",
            "advantage_sign_agreement",
            "gradient_sign_agreement",
            "gradient_corr",
            "per_sample_snr",
            "per_sample_snr_oracle_baseline",
            "bellman_residual_abs",
            "frac_mean_saturated",
            "frac_grad_clipped",
        )
        summary[f"probe_{variant}"] = {
            k: float(np.mean([p[k] for p in ps if p.get(k) is not None]))
            if any(p.get(k) is not None for p in ps)
            else None
            for k in keys
        }
        summary[f"probe_{variant}"]["f_abs_median"] = float(
            np.mean([p["f_abs_percentiles"]["50"] for p in ps])
        )
        mc = [b for run in probes if run["variant"] == variant for b in run["critic_vs_mc"][1:]]
        summary[f"probe_{variant}"]["critic_explained_variance_vs_mc"] = (
            float(np.mean([b["explained_variance"] for b in mc])) if mc else None
        )
    if out.get("pendulum_variants"):
        summary["pendulum_variants"] = _pendulum_variants_summary(out["pendulum_variants"])
    if out.get("noise"):
        keys = ("train_final_return", "mean_action", "sampled_final_std", "sampled_half_std")
        summary["pendulum_noise"] = {
            k: {**_group(out["noise"], k), "per_seed": [round(r[k], 1) for r in out["noise"]]} for k in keys
        }
    if out.get("env_cost"):
        summary["env_cost"] = _env_cost_summary(out["env_cost"], paper_summary)
    return summary


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument(
        "--parts", default="probe,performance,reach,reach_baselines,pendulum_variants,noise,env_cost,checks"
    )
    p.add_argument("--eval-episodes", type=int, default=30, help="of the noise part")
    p.add_argument("--pendulum-variants", default=",".join(PENDULUM_VARIANTS), help="of pendulum_variants")
    p.add_argument("--reach-variants", default=",".join(REACH_VARIANTS), help="of the reach part")
    p.add_argument("--reach-baselines", default="td3_noise_0.05,td3_noise_0.2", help="of reach_baselines")
    p.add_argument("--variants", default="before,after", help="of the probe and performance parts")
    p.add_argument("--check-variants", default="before,after,options")
    p.add_argument("--steps", type=int, default=20_000)
    p.add_argument("--every", type=int, default=4_000)
    p.add_argument("--seeds", type=int, default=5)
    p.add_argument("--first-seed", type=int, default=0, help="of the variant parts: seeds from here")
    p.add_argument("--probe-seeds", type=int, default=2)
    p.add_argument("--probe-states", type=int, default=96)
    p.add_argument("--probe-reps", type=int, default=16)
    p.add_argument("--check-seeds", type=int, default=3)
    p.add_argument("--check-envs", default="cartpole_slow,cartpole_fast,reach_slow")
    p.add_argument("--jobs", type=int, default=2)
    p.add_argument("--after", default=None, help="JSON: replace the after-settings of every env (exploring)")
    p.add_argument("--out", default=str(ROOT / "results" / "learner_diagnosis.json"))
    p.add_argument("--paper-summary", default=str(ROOT / "results" / "paper" / "summary.json"))
    p.add_argument("--merge", action="store_true", help="keep the parts of --out that this call does not run")
    a = p.parse_args()
    if a.first_seed < 0:
        p.error(f"--first-seed must be >= 0, got {a.first_seed}")
    if a.after is not None:
        global AFTER
        AFTER = {k: json.loads(a.after) for k in AFTER}
    parts, variants = a.parts.split(","), a.variants.split(",")
    old: dict[str, Any] = {}
    if a.merge and Path(a.out).is_file():
        old = json.loads(Path(a.out).read_text())
    out: dict[str, Any] = {
        **{
            k: old[k]
            for k in (
                "probe",
                "performance",
                "checks",
                "reach",
                "reach_baselines",
                "noise",
                "env_cost",
                "pendulum_variants",
            )
            if k in old
        },
        "commands": [c for c in old.get("commands", [old.get("command")]) if c]
        + ["python bench/learner_diagnosis.py " + " ".join(sys.argv[1:])],
        "before_overrides": BEFORE,
        "after_overrides": AFTER,
        "options_overrides": OPTIONS,
        "scheduled_overrides": SCHEDULES,
        "reach_variants": REACH_VARIANTS,
        "reach_baseline_variants": REACH_BASELINE_VARIANTS,
        "pendulum_variants_overrides": PENDULUM_VARIANTS,
        "started_at": time.strftime("%Y-%m-%dT%H:%M:%S"),
    }
    from experiments.execute import code_version
    from experiments.plan import ENVS

    out["code"] = code_version()
    if "probe" in parts:
        tasks = [
            (v, _overrides("pendulum_slow", v), s, a.steps, a.every, a.probe_states, a.probe_reps)
            for v in variants
            for s in range(a.probe_seeds)
        ]
        out["probe"] = pool_map(probe_run, tasks, a.jobs)

    def variant_runs(part: str, names: list[str], task: Callable[[str, int], tuple]) -> list[dict]:
        """Each named variant's ``plain_run`` over the seeds; with --merge, every other (variant, seed)'s
        run kept (``--first-seed`` adds more seeds to a variant)."""
        seeds = range(a.first_seed, a.first_seed + a.seeds)
        tasks = [task(v, s) for v in names for s in seeds]
        kept = [r for r in old.get(part, []) if not (r["variant"] in names and r["seed"] in seeds)]
        return kept + pool_map(plain_run, tasks, a.jobs)

    reach_steps = ENVS["reach_slow"].steps
    if "performance" in parts:
        out["performance"] = variant_runs(
            "performance",
            variants,
            lambda v, s: ("pendulum_slow", v, _overrides("pendulum_slow", v), s, a.steps),
        )
    if "reach" in parts:
        out["reach"] = variant_runs(
            "reach",
            _names(a.reach_variants),
            lambda v, s: ("reach_slow", v, REACH_VARIANTS[v], s, reach_steps),
        )
    if "reach_baselines" in parts:
        out["reach_baselines"] = variant_runs(
            "reach_baselines",
            _names(a.reach_baselines),
            lambda v, s: (
                "reach_slow",
                v,
                REACH_BASELINE_VARIANTS[v][1],
                s,
                reach_steps,
                REACH_BASELINE_VARIANTS[v][0],
            ),
        )
    if "pendulum_variants" in parts:
        out["pendulum_variants"] = variant_runs(
            "pendulum_variants",
            _names(a.pendulum_variants),
            lambda v, s: ("pendulum_slow", v, PENDULUM_VARIANTS[v], s, a.steps),
        )
    if "noise" in parts:
        out["noise"] = pool_map(noise_run, [(s, a.steps, a.eval_episodes) for s in range(a.seeds)], a.jobs)
    if "env_cost" in parts:
        tasks = [(e, s) for e in ENVS for s in range(a.check_seeds)]
        out["env_cost"] = pool_map(env_cost_run, tasks, a.jobs)
    if "checks" in parts:
        envs = [e for e in a.check_envs.split(",") if e]
        cvs = a.check_variants.split(",")
        tasks = [
            (e, v, _overrides(e, v), s, ENVS[e].steps)
            for e in envs
            for v in cvs
            for s in range(a.check_seeds)
        ]
        out["checks"] = pool_map(plain_run, tasks, a.jobs)
    out["summary"] = summarize(out, Path(a.paper_summary).resolve())
    Path(a.out).parent.mkdir(parents=True, exist_ok=True)
    Path(a.out).write_text(json.dumps(out, indent=1, default=float))
    print(json.dumps(out["summary"], indent=1))


if __name__ == "__main__":
    main()
