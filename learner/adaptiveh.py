"""AdaptiveH (the paper's algorithm box) and the fixed-H RKHS learner, which is AdaptiveH with the
retreat check off and a segment every ``fixed_h`` steps.

Per step: sample ``a ~ π(·|s)`` from the segment's policy, step the env, fit the critic, form the
functional gradient ``g_t = c · Â_t · score(s_t, a_t)`` (eq. 8, ``c = 1/(1-γ)``, ``Â`` the critic's
advantage — a TD error for the default value critic, i.e. Q̂ with the state baseline ``V`` removed,
which keeps the gradient unbiased), and EVAL the retreat statistic. A retreat, ``h_max`` or the episode's
end closes the segment: UPDATE ``h`` with the segment's gradients, SPARSIFY, and open a new segment.

With ``execution: plan`` a segment is a committed plan (``learner.plans``) played by the segment loop
(``learner.acting``, the actor's loop, with this learner as its own actor): at its first state the
segment's policy samples up to ``h_max`` (fixed-H: ``fixed_h``) actions over the states the env's
nominal model predicts, and they play without waiting for the learner; the segment's end re-plans and
the new plan preempts what is left. Every executed step is learned from as it happens, at the state
it acted in (the critic's TD error measures the action's consequence at ``s_i``). Its score
(``plan_score``) is taken there, ``Σ⁻¹(a_i - h(s_i))`` with the unclipped sample, or is the noise the
policy drew at the predicted state, ``Σ⁻¹(a_i - h(ŝ_i))``, as the actor beside the arm scores every
sample; neither wins everywhere (docs/learner_plans.md). When the model is right (``ŝ_i = s_i``) both
are the on-policy score of the closed loop; fixed H = 1 in plan mode is the closed-loop learner.
"""

from __future__ import annotations

import pickle
from collections import deque
from dataclasses import dataclass, field
from pathlib import Path

import gymnasium as gym
import numpy as np

from learner.acting import PolicyPlanner, SegmentLoop
from learner.config import GATE_EPISODES, AdaptiveHConfig, rkhs_config
from learner.critic import KLSTDCritic
from learner.kernels import GaussianKernel
from learner.normalizer import StateNormalizer
from learner.parts import FIELD_BUDGET, initial_policy, kernels, retreat_threshold, segment_limit
from learner.plan_model import plan_model
from learner.plans import Executed, Played, QueuedChannel
from learner.protocol import EpisodeRecord, RunLog, SegmentRecord, StepCallback
from learner.provenance import TrainedOn, check_handoff, checkpoint_path, trained_on
from learner.replay import Transition, TransitionWindow
from learner.retreat import RetreatCheck, SegmentSamples
from learner.segments import Execution, SegmentEnd, segment_end
from learner.snapshot import PolicySnapshot


def _info_scalars(info: dict) -> dict[str, float]:
    out = {}
    for k, v in info.items():
        if isinstance(v, (bool, np.bool_)):
            out[k] = float(v)
        elif isinstance(v, (int, float, np.floating, np.integer)) and np.isfinite(v):
            out[k] = float(v)
    return out


@dataclass
class StreamProgress:
    """An actor stream's open segment and episode so far: pooled arms' ticks interleave at the learner,
    and each arm's segments and episodes stay its own."""

    arm: str = ""
    segment: SegmentSamples = field(default_factory=SegmentSamples)
    ret: float = 0.0
    length: int = 0


class AdaptiveH:
    """The AdaptiveH agent. ``retreat`` in the config chooses the statistic (``off`` = fixed H)."""

    name = "adaptiveh"

    def __init__(self, env: gym.Env, config: AdaptiveHConfig | None = None, seed: int = 0):
        self.env = env
        self.config = config or AdaptiveHConfig()
        self.seed = seed
        cfg = self.config
        if not isinstance(env.action_space, gym.spaces.Box):
            raise ValueError("the RKHS learner needs a continuous (Box) action space")
        self.normalize = StateNormalizer.for_env(env)
        dim = len(self.normalize.centre)
        self.kernel, plan_tolerance = kernels(cfg, dim)
        self.policy = initial_policy(cfg, env, self.kernel)
        critic_kernel = self.kernel
        if cfg.critic_bandwidth is not None:
            critic_kernel = GaussianKernel(np.asarray(cfg.critic_bandwidth, float), dim)
        self.critic = KLSTDCritic(
            critic_kernel,
            cfg.gamma,
            cfg.critic_budget,
            cfg.critic_ald,
            cfg.critic_forgetting,
            cfg.critic_p0,
            cfg.critic,
            len(self.policy.low),
            np.asarray(cfg.action_bandwidth, float),
            cfg.residual_baseline,
            cfg.visit_memory,
            cfg.residual_fit,
            cfg.critic_lambda,
        )
        self.retreat = RetreatCheck(
            self.kernel,
            cfg.retreat_mode,
            retreat_threshold(cfg, self.kernel),
            cfg.retreat_smoothing,
            min(cfg.policy_budget, FIELD_BUDGET),
            cfg.policy_ald,
            plan_tolerance,
        )
        self.segment_limit = segment_limit(cfg)
        self.grad_scale = 1.0 / (1.0 - cfg.gamma) if cfg.use_discount_factor else 1.0
        self.alpha = cfg.alpha  # the step per sample now (alpha_final: scheduled)
        self.rng = np.random.default_rng(seed)
        self.log = RunLog()
        self.trained_on = trained_on(
            env, (self.normalize.centre - self.normalize.scale, self.normalize.centre + self.normalize.scale)
        )
        # A handoff (``start_from``): the source's path, record and steps; its steps also carry the
        # exploration and step-size schedules on from where the source left them.
        self.started_from: dict | None = None
        self.schedule_offset = 0
        self.gated_steps = 0  # with schedule_gate: the steps of episodes that ended with the gate open
        # Learning from actors: each actor stream's transitions learned, in order (deploy.transition_stream);
        # saved with the policy, so a resumed learner asks for exactly what it lacks.
        self.stream_marks: dict[str, int] = {}
        self.streams: dict[str, StreamProgress] = {}  # each actor stream's open segment and episode
        self.nonfinite_skipped = 0
        # advantage_lambda > 0: samples whose λ-advantage is still accruing [s, score, advantage, weight],
        # and the matured (state, gradient) pairs that the next segment update applies.
        self._pending: deque[list] = deque()
        self._matured: list[tuple[np.ndarray, np.ndarray]] = []
        self.replay = TransitionWindow(cfg.replay_window) if cfg.replay_window > 0 else None
        self._replay_rng = np.random.default_rng([seed, 1])  # its own stream: acting draws stay the same
        self._obs: np.ndarray | None = None
        self._ep_return = 0.0
        self._ep_len = 0
        self._episode_seed = seed
        # Plan execution: the segment loop on a queue in front of the env, this learner its own actor.
        self.channel: QueuedChannel | None = None
        self.acting: SegmentLoop | None = None
        if cfg.execution == Execution.PLAN:
            self._plan_execution(env)

    def _plan_execution(self, env: gym.Env) -> None:
        """The plan model (the env's ``predict_next``), the queue the plans play on, and the loop."""
        nominal = getattr(env.unwrapped, "predict_next", None)
        if nominal is None:
            name = type(env.unwrapped).__name__
            raise ValueError(f"execution: plan needs the env's world model; {name} has no predict_next")
        cfg = self.config
        dims = (len(self.normalize.centre), len(self.policy.low))
        self.model = plan_model(cfg.plan_model, nominal, self.normalize, dims, cfg.plan_model_memory)
        self.channel = QueuedChannel(env, cfg.latency_steps)
        planner = PolicyPlanner(
            self.policy, self.normalize, self.model, self.segment_limit, self.rng, cfg.latency_steps
        )
        self.acting = SegmentLoop(planner, self.channel, self._learn_tick, before_plan=self._schedule)

    # -- acting ---------------------------------------------------------------------------------
    def predict(self, obs: np.ndarray, deterministic: bool = True) -> np.ndarray:
        s = self.normalize(obs)
        if deterministic:
            return np.clip(self.policy.mean(s), self.policy.low, self.policy.high)
        return self.policy.sample(s, self.rng)[0]

    # -- learning -------------------------------------------------------------------------------
    def learn(self, total_steps: int, callback: StepCallback | None = None) -> RunLog:
        for _ in range(total_steps):
            self.step_env()
            if callback is not None and callback(self.log.global_step, self.log) is False:
                break
        return self.log

    def step_env(self) -> SegmentRecord | None:
        """One environment step; returns the segment record when this step closed a segment."""
        if self.acting is not None:
            return self._step_plan()
        if self._obs is None:
            self._reset_episode()
        self._schedule()
        obs = self._obs
        s = self.normalize(obs)
        action, raw = self.policy.sample(s, self.rng)
        next_obs, reward, terminated, truncated, info = self.env.step(action)
        self.log.global_step += 1
        self._ep_return += float(reward)
        self._ep_len += 1
        episode_over = terminated or truncated
        retreat = self._learn_sample(s, raw, float(reward), next_obs, terminated, episode_over)
        end = self._forced_end(episode_over)
        if retreat is not None:
            end = segment_end(retreat, len(self.retreat.states), self.segment_limit, episode_over)
        record = self._close_segment(end)
        if episode_over:
            self._finish_episode(info, self._ep_return, self._ep_len)
        elif np.all(np.isfinite(next_obs)):
            self._obs = np.asarray(next_obs, float)
        # else: keep acting from the last finite observation; a NaN state never reaches the policy
        return record

    # -- plan execution -------------------------------------------------------------------------
    def _step_plan(self) -> SegmentRecord | None:
        """One tick of the segment loop; this learner learns from it as it judges it."""
        if self._obs is None:
            self._reset_episode()
        elif self.acting.obs is None:  # resumed from a checkpoint: act on from its state
            self.acting.begin(self._obs)
        tick = self.acting.tick()
        record = self._close_segment(tick.end)
        if tick.episode_over:
            self._finish_episode(tick.step.info, self._ep_return, self._ep_len)
        else:
            self._obs = self.acting.obs
        return record

    def _learn_tick(self, obs: np.ndarray, step: Executed, played: Played) -> tuple[float | None, bool]:
        """The loop's judge in-process (``learner.acting.Judge``): learn from the tick, then the retreat
        test with the field that includes it; a sample that is not finite closes the segment. With
        ``plan_score: noise`` the sample is scored by the noise that drew it, as the actor's are (a hold:
        zero noise, no gradient)."""
        s = self.normalize(obs)
        raw = played.raw(step)
        noise = None
        if self.config.plan_score == "noise":
            noise = played.source.noise[step.index] if played.source is not None else np.zeros_like(raw)
        predicted = reached = None
        if played.current and np.all(np.isfinite(step.obs)):
            predicted, reached = self.normalize(played.predicted(step)), self.normalize(step.obs)
        self.log.global_step += 1
        self._ep_return += float(step.reward)
        self._ep_len += 1
        judged = len(self.retreat.trace)
        retreat = self._learn_sample(
            s,
            raw,
            step.reward,
            step.obs,
            step.terminated,
            step.terminated or step.truncated,
            predicted,
            reached,
            noise=noise,
            ahead=step.index + 1,
        )
        statistic = self.retreat.trace[-1] if len(self.retreat.trace) > judged else None
        return statistic, True if retreat is None else retreat

    def _learn_sample(
        self,
        s: np.ndarray,
        raw: np.ndarray,
        reward: float,
        next_obs: np.ndarray,
        terminated: bool,
        episode_over: bool,
        predicted: np.ndarray | None = None,
        reached: np.ndarray | None = None,
        judged: bool = False,
        statistic: float | None = None,
        noise: np.ndarray | None = None,
        ahead: int = 0,
    ) -> bool | None:
        """Learn from one executed step (``predicted``: ``ahead`` steps into its plan); whether the retreat
        test failed (``judged``: an actor evaluated it, ``statistic``), or None when the sample was not
        finite and was dropped: a NaN must never reach the dictionaries."""
        s_next = self.normalize(next_obs)
        if not (np.all(np.isfinite(s_next)) and np.isfinite(reward)):
            self.nonfinite_skipped += 1
            return None
        if noise is None:
            log_prob, score = self.policy.log_prob_and_score(s, raw)  # under the policy that drew raw
        else:  # an actor's sample, drawn by a snapshot of this policy: scored by its own noise
            log_prob, score = self.policy.noise_log_prob_and_score(noise)
        g, advantage = self._gradient(s, raw, score, reward, s_next, terminated)
        if not np.isfinite(float(np.linalg.norm(g))):
            self.nonfinite_skipped += 1
            return None
        g = self._shape(s, g)
        if self.config.advantage_lambda > 0.0:
            self._accrue(s, score, advantage, episode_over)
        if self.replay is not None:
            self.replay.push(Transition(s, np.asarray(raw, float), reward, s_next, terminated, log_prob))
        return self.retreat.push(s, g, predicted, reached, judged, statistic, ahead)

    @staticmethod
    def _forced_end(episode_over: bool) -> SegmentEnd:
        """How a segment ends whose sample was dropped as not finite."""
        return SegmentEnd.EPISODE_END if episode_over else SegmentEnd.RETREAT

    # -- learning from an actor ------------------------------------------------------------------
    def learn_transition(
        self,
        obs: np.ndarray,
        raw: np.ndarray,
        reward: float,
        next_obs: np.ndarray,
        terminated: bool,
        truncated: bool,
        info: dict,
        predicted: np.ndarray | None,
        end: str,
        statistic: float | None = None,
        noise: np.ndarray | None = None,
        stream: str = "",
        arm: str = "",
    ) -> SegmentRecord | None:
        """Learn from one tick an actor played (``deploy.actor_node``): it planned with a snapshot of this
        policy, evaluated the retreat where the plan played and says how the segment stands (``end``).
        The critic, the gradient field and the policy update are this learner's, as in :meth:`step_env`;
        the open segment and the episode are ``stream``'s (one per actor process, of ``arm``)."""
        progress = self._progress(stream, arm)
        self.retreat.segment = progress.segment
        if not self.retreat.states:
            self._schedule()  # a new segment: this step's exploration std and step size
        s = self.normalize(obs)
        reached = None
        if predicted is not None and np.all(np.isfinite(next_obs)):
            predicted, reached = self.normalize(predicted), self.normalize(next_obs)
        self.log.global_step += 1
        progress.ret += float(reward)
        progress.length += 1
        episode_over = terminated or truncated
        retreat = self._learn_sample(
            s,
            np.asarray(raw, float),
            reward,
            next_obs,
            terminated,
            episode_over,
            predicted,
            reached,
            judged=True,  # where the plan played, by the same loop (``learner.acting``)
            statistic=statistic,
            noise=noise,
        )
        end = self._forced_end(episode_over) if retreat is None else SegmentEnd(end)
        record = self._close_segment(end, arm)
        progress.segment = self.retreat.segment
        if episode_over:
            self._finish_episode(info, progress.ret, progress.length, arm)
            progress.ret, progress.length = 0.0, 0  # the actor has reset the robot
        return record

    def _progress(self, stream: str, arm: str) -> StreamProgress:
        """``stream``'s progress; a new stream of an arm replaces the arm's old one (its actor restarted),
        whose open segment closes."""
        progress = self.streams.get(stream)
        if progress is None:
            for old in [k for k, p in self.streams.items() if p.arm == arm]:
                self.close_stream(old)
            progress = self.streams[stream] = StreamProgress(arm)
        return progress

    def close_stream(self, stream: str) -> SegmentRecord | None:
        """A stream that ends (its arm is gone): its open segment closes as its plan is gone (``h_max``),
        its unfinished episode is dropped; the record, if a segment was open."""
        progress = self.streams.pop(stream, None)
        if progress is None:
            return None
        self.retreat.segment = progress.segment
        return self._close_segment(SegmentEnd.H_MAX, progress.arm)

    def close_arm(self, arm: str) -> list[SegmentRecord]:
        """Arm ``arm`` is gone: close its streams' open segments (the records of those that were open)."""
        records = [self.close_stream(k) for k, p in list(self.streams.items()) if p.arm == arm]
        return [r for r in records if r is not None]

    def snapshot(self) -> PolicySnapshot:
        """What an actor plans with: this policy's mean, the retreat's gradient field, the std now."""
        f, field = self.policy.f, self.retreat.field
        action_dim = len(self.policy.low)
        weights = field.weights  # (0, 0) until the field's first push sets its output size
        return PolicySnapshot(
            version=self.log.global_step,
            policy_centers=f.dictionary.centers.copy(),
            policy_weights=f.weights.copy(),
            field_centers=field.dictionary.centers.copy(),
            field_weights=weights.copy()
            if weights.shape[1] == action_dim
            else np.zeros((len(field), action_dim)),
            sigma=self.policy.sigma.copy(),
        )

    def _shape(self, s: np.ndarray, g: np.ndarray) -> np.ndarray:
        """The per-sample gradient as the update applies it: norm clipped at ``max_grad_norm``, scaled by the
        local step ``n0 / (n0 + n(s))`` when ``visit_step`` is on."""
        norm = float(np.linalg.norm(g))
        if norm > self.config.max_grad_norm:
            g = g * (self.config.max_grad_norm / norm)
        if self.config.visit_step is not None:
            n0 = self.config.visit_step
            g = g * (n0 / (n0 + self.critic.visits(s)))
        return g

    def _accrue(self, s: np.ndarray, score: np.ndarray, delta: float, episode_over: bool) -> None:
        """GAE(λ) in the forward view: each pending sample's advantage gains ``(γλ)^(t-k) δ_t``; it matures
        when that weight falls below 1 % or its episode ends (the sum is then cut, no bootstrap past
        the last ``δ``), and its gradient ``c Â^λ_k score_k`` waits for the next segment update."""
        decay = self.config.gamma * self.config.advantage_lambda
        for entry in self._pending:
            entry[2] += entry[3] * delta
            entry[3] *= decay
        self._pending.append([s, score, delta, decay])
        self._mature(everything=episode_over)

    def _mature(self, everything: bool) -> None:
        while self._pending and (everything or self._pending[0][3] < 0.01):
            s_k, score_k, adv_k, _ = self._pending.popleft()
            self._matured.append((s_k, self._shape(s_k, self.grad_scale * adv_k * score_k)))

    def _gradient(
        self,
        s: np.ndarray,
        raw: np.ndarray,
        score: np.ndarray,
        reward: float,
        s_next: np.ndarray,
        terminated: bool,
    ) -> tuple[np.ndarray, float]:
        """Fit the critic on one transition; return the per-step functional gradient ``g_t`` (f's units)
        and the advantage it was formed from."""
        policy = self.policy
        sigma = policy.sigma / policy.half_range  # the policy's std in scaled action units
        if self.config.critic != "q":
            advantage = self.critic.update(s, reward, s_next, terminated, score)
            return self._policy_gradient(s, score, advantage, None, sigma), advantage
        action = (np.clip(raw, policy.low, policy.high) - policy.centre) / policy.half_range
        mean = np.tanh(policy.f(s))
        next_mean = np.tanh(policy.f(s_next))
        advantage = self.critic.update(s, reward, s_next, terminated, None, action, mean, next_mean, sigma)
        return self._policy_gradient(s, score, advantage, mean, sigma), advantage

    def frozen_gradient(
        self, s: np.ndarray, raw: np.ndarray, reward: float, s_next: np.ndarray, terminated: bool = False
    ) -> tuple[np.ndarray, float]:
        """(``g_t``, advantage) as :meth:`_gradient` forms them, from the critic as it stands (no fit): what
        a probe of the learner's signal measures (bench/learner_diagnosis.py)."""
        policy, critic = self.policy, self.critic
        score = policy.score(s, raw)
        sigma = policy.sigma / policy.half_range
        mean = None
        if self.config.critic == "value":
            advantage = critic.td_error(s, reward, s_next, terminated)
        elif self.config.critic == "compatible":
            advantage = critic.advantage(s, score)
        else:
            action = (np.clip(raw, policy.low, policy.high) - policy.centre) / policy.half_range
            mean = np.tanh(policy.f(s))
            advantage = critic.q_value(s, action) - critic.value(s, mean, sigma)
        return self._policy_gradient(s, score, advantage, mean, sigma), advantage

    def _policy_gradient(
        self, s: np.ndarray, score: np.ndarray, advantage: float, mean: np.ndarray | None, sigma: np.ndarray
    ) -> np.ndarray:
        """The per-step gradient from the critic's advantage (``sampled``) or its action slope
        (``expected``: ``D(s) = ∂/∂μ̃ E Q̂`` in scaled units, the paper's Σ⁻¹-weighted action integral in
        f's units)."""
        if self.config.policy_gradient == "expected":
            return self.grad_scale * self.critic.expected_gradient(s, mean, sigma)
        return self.grad_scale * advantage * score

    def _replay_update(self) -> None:
        """Apply ``replay_batch`` past transitions' gradients again (learner/replay.py). No weight decay:
        that is charged once per environment sample."""
        states, grads = [], []
        for t in self.replay.sample(self.config.replay_batch, self._replay_rng):
            g = self._replayed_gradient(t)
            if np.all(np.isfinite(g)):
                states.append(t.s)
                grads.append(self._shape(t.s, g))
        if states:
            step = self.alpha * self.config.replay_step
            self.policy.update(states, grads, step, 0.0, self.config.mean_limit)

    def _replayed_gradient(self, t: Transition) -> np.ndarray:
        """``c · min(1, π(a|s)/μ(a|s)) · δ · score``: the TD error as the critic sees it now, the score at the
        current mean, the truncated importance ratio of the policy now against the one that drew ``a``."""
        delta = self.critic.td_error(t.s, t.reward, t.s_next, t.terminated)
        log_prob, score = self.policy.log_prob_and_score(t.s, t.raw)
        ratio = min(1.0, float(np.exp(log_prob - t.log_prob)))
        return self.grad_scale * ratio * delta * score

    def _schedule(self) -> None:
        """This step's exploration std and step size on their schedules (``sigma_final``, ``alpha_final``):
        a policy still moving at full step and full noise late in a run swings between good and bad. After
        a handoff the step is ``handoff_step_scale`` of it."""
        cfg = self.config
        frac = min((self.schedule_offset + self.schedule_clock()) / cfg.schedule_steps, 1.0)
        alpha = cfg.alpha if cfg.alpha_final is None else cfg.alpha + (cfg.alpha_final - cfg.alpha) * frac
        self.alpha = alpha * (cfg.handoff_step_scale if self.started_from is not None else 1.0)
        if cfg.sigma_final is not None:
            self.policy.explore((cfg.sigma + (cfg.sigma_final - cfg.sigma) * frac) * self.policy.half_range)

    def schedule_clock(self) -> int:
        """The steps this run's schedule has gone: every step, or with ``schedule_gate`` only those of
        episodes that ended with the gate open."""
        return self.log.global_step if self.config.schedule_gate is None else self.gated_steps

    def _gate(self, length: int) -> None:
        """An episode of ``length`` steps ended: with ``schedule_gate``, its steps count on the schedule when
        the success rate of the last ``GATE_EPISODES`` episodes is at or above the gate."""
        gate = self.config.schedule_gate
        if gate is None:
            return
        recent = [e.success for e in self.log.episodes[-GATE_EPISODES:]]
        if recent[-1] is None:
            raise ValueError("schedule_gate: this env's episodes report no success to open the gate on")
        if len(recent) == GATE_EPISODES and np.mean(recent) >= gate:
            self.gated_steps += length

    def _close_segment(self, reason: str, arm: str = "") -> SegmentRecord | None:
        """Update the policy with the segment's gradients when ``reason`` closes it (``open``: nothing)."""
        states, grads = self.retreat.states, self.retreat.grads
        if reason == SegmentEnd.OPEN or not states:
            return None
        cfg = self.config
        if cfg.frozen:
            pass  # the policy as it was handed over (the critic and the retreat's field still learn)
        elif cfg.advantage_lambda > 0.0:  # the samples whose λ-advantage is complete, not the segment's own
            matured, self._matured = self._matured, []
            if matured:
                upd_states, upd_grads = zip(*matured, strict=True)
                self.policy.update(
                    list(upd_states), list(upd_grads), self.alpha, cfg.weight_decay, cfg.mean_limit
                )
        else:
            self.policy.update(states, grads, self.alpha, cfg.weight_decay, cfg.mean_limit)
        if self.replay is not None and not cfg.frozen:
            self._replay_update()
        record = SegmentRecord(
            index=self.log.segment_count,
            global_step=self.log.global_step,
            H=len(states),
            reason=reason,
            statistic=[float(x) for x in self.retreat.trace],
            threshold=float(self.retreat.threshold),
            arm=arm,
        )
        self.log.segments.append(record)
        self.retreat.reset()
        return record

    def _reset_episode(self) -> None:
        if self.acting is not None:
            obs, _ = self.acting.reset(seed=self._episode_seed)
        else:
            obs, _ = self.env.reset(seed=self._episode_seed)
        self._episode_seed += 1
        self._obs = np.asarray(obs, float)
        self._ep_return, self._ep_len = 0.0, 0

    def _finish_episode(self, info: dict, ret: float, length: int, arm: str = "") -> None:
        self._mature(everything=True)  # an episode's advantages never reach into the next one
        self.critic.end_episode()
        scalars = _info_scalars(info)
        success = scalars.get("is_success", scalars.get("success"))
        self.log.episodes.append(
            EpisodeRecord(
                episode=self.log.episode_count,
                global_step=self.log.global_step,
                ret=ret,
                length=length,
                success=None if success is None else bool(success),
                info=scalars,
                arm=arm,
            )
        )
        self._gate(length)
        self._obs = None

    # -- checkpoints ----------------------------------------------------------------------------
    def state_dict(self) -> dict:
        env_state = None
        get_state = getattr(self.env.unwrapped, "get_state", None)
        if callable(get_state):
            env_state = get_state()
        return {
            "name": self.name,
            "config": self.config.model_dump(),
            "seed": self.seed,
            "policy": self.policy.f.state_dict(),
            "critic": self.critic.state_dict(),
            "rng": self.rng.bit_generator.state,
            "log": self.log.to_dict(),
            "retreat": self.retreat.state_dict(),
            "obs": self._obs,
            "ep": (self._ep_return, self._ep_len, self._episode_seed),
            "nonfinite_skipped": self.nonfinite_skipped,
            "pending": [list(e) for e in self._pending],
            "matured": list(self._matured),
            "replay": None if self.replay is None else self.replay.state_dict(),
            "replay_rng": self._replay_rng.bit_generator.state,
            "env": env_state,
            "trained_on": self.trained_on.to_dict(),
            "started_from": self.started_from,
            "schedule_offset": self.schedule_offset,
            "schedule_clock": self.schedule_clock(),
            "gated_steps": self.gated_steps,
            "stream_marks": dict(self.stream_marks),
            "streams": {
                k: (p.arm, p.segment.states, p.segment.grads, p.segment.trace, p.ret, p.length)
                for k, p in self.streams.items()
            },
        }

    def load_state_dict(self, state: dict) -> None:
        if state["name"] != self.name:
            raise ValueError(f"checkpoint is for {state['name']!r}, not {self.name!r}")
        self.policy.f.load_state_dict(state["policy"])
        self.critic.load_state_dict(state["critic"])
        self.rng.bit_generator.state = state["rng"]
        self.log = RunLog.from_dict(state["log"])
        self.retreat.load_state_dict(state["retreat"])
        self._obs = state["obs"]
        self._ep_return, self._ep_len, self._episode_seed = state["ep"]
        self.nonfinite_skipped = state["nonfinite_skipped"]
        self.started_from = state.get("started_from")
        self.schedule_offset = state.get("schedule_offset", 0)
        self.gated_steps = state.get("gated_steps", 0)
        self.stream_marks = dict(state.get("stream_marks", {}))
        self.streams = {
            k: StreamProgress(arm, SegmentSamples(list(states), list(grads), list(trace)), ret, length)
            for k, (arm, states, grads, trace, ret, length) in state.get("streams", {}).items()
        }
        self._pending = deque([list(e) for e in state.get("pending", [])])
        self._matured = list(state.get("matured", []))
        if self.replay is not None and state.get("replay") is not None:
            self.replay.load_state_dict(state["replay"])
            self._replay_rng.bit_generator.state = state["replay_rng"]
        set_state = getattr(self.env.unwrapped, "set_state", None)
        if state["env"] is not None and callable(set_state):
            self.env.reset()  # wrappers (gym.make's OrderEnforcing) refuse step() before a reset
            set_state(state["env"])
        else:
            self._obs = None  # the env cannot be restored: resume at a fresh episode

    def save(self, path: str | Path) -> None:
        path = Path(path)
        path.parent.mkdir(parents=True, exist_ok=True)
        tmp = path.with_suffix(path.suffix + ".tmp")
        with open(tmp, "wb") as fh:
            pickle.dump(self.state_dict(), fh)
        tmp.replace(path)  # atomic: a crash mid-write never corrupts the last checkpoint

    def load(self, path: str | Path) -> None:
        with open(path, "rb") as fh:
            self.load_state_dict(pickle.load(fh))

    def start_from(self, path: str | Path) -> dict:
        """Hand off: take the policy, critic, gradient field and plan tolerance another run trained (its
        checkpoint at ``path``, a file or run folder), after checking it was trained on this task
        (``learner.provenance.HandoffMismatch`` names the field that differs); this run's own log, clock
        and randomness start fresh. The normaliser is part of the checked record, so it is the source's.
        Returns ``started_from``: what the summary and the monitor report."""
        ckpt = checkpoint_path(path)
        with open(ckpt, "rb") as fh:
            state = pickle.load(fh)
        if state.get("name") not in ("adaptiveh", "rkhs"):
            raise ValueError(f"{ckpt}: not an RKHS learner's checkpoint (name {state.get('name')!r})")
        if "trained_on" not in state:
            raise ValueError(f"{ckpt}: the checkpoint records no trained_on (made before handoffs existed)")
        recorded = TrainedOn.from_dict(state["trained_on"])
        check_handoff(recorded, self.trained_on, str(ckpt))
        self.policy.f.load_state_dict(state["policy"])
        self.critic.load_state_dict(state["critic"])
        self.retreat.start_from(state["retreat"])
        offset = int(state.get("schedule_offset", 0))
        steps = int(state["log"]["global_step"]) + offset
        self.schedule_offset = int(state.get("schedule_clock", state["log"]["global_step"])) + offset
        self.started_from = {
            "path": str(ckpt),
            "algo": state["name"],
            "steps": steps,
            "trained_on": recorded.source,
            "arm": recorded.arm.model if recorded.arm else "",
            "commit": recorded.commit,
        }
        self._schedule()
        return self.started_from


class RKHSFixedH(AdaptiveH):
    """The paper's RKHS baseline: the same learner, retreat check off, an update every ``fixed_h`` steps."""

    name = "rkhs"

    def __init__(self, env: gym.Env, config: AdaptiveHConfig | None = None, seed: int = 0):
        super().__init__(env, rkhs_config(self.name, config or AdaptiveHConfig()), seed)
