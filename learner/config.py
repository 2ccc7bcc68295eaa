"""Hyperparameters of the learners, typed so a bad config names its key (and says what is allowed)."""

from __future__ import annotations

from typing import Annotated, Literal

from pydantic import AfterValidator, Field, model_validator

from common.config import Section
from learner.retreat import RetreatMode
from learner.segments import Execution

Positive = Annotated[float, Field(gt=0)]
Scale = Annotated[float, Field(gt=0, le=1)]
GATE_EPISODES = 20  # the episodes whose success rate opens ``schedule_gate``


class AdaptiveHConfig(Section):
    """Defaults are the ones that learn NS CartPole; see the README for why each differs from the paper.

    ``alpha`` is the step per sample: a segment of length H moves ``h`` by ``alpha·H·mean_t(...)``, so
    AdaptiveH and the fixed-H learner compare at the same per-sample step whatever H is.
    """

    gamma: float = Field(
        0.99, gt=0, lt=1, description="discount factor of future rewards (per environment step)"
    )
    alpha: float = Field(
        0.02,
        gt=0,
        description="the policy's step size per sample (a segment of H samples moves the policy by alpha·H"
        " times their mean gradient)",
    )
    sigma: float = Field(0.3, gt=0)  # exploration std, as a fraction of the action half-range
    # Schedules, linear from sigma / alpha over schedule_steps, then constant (None: constant). The score
    # keeps sigma's Σ⁻¹, so a smaller std also shrinks the step like a natural gradient's; with the
    # annealed Σ⁻¹ the step grew as 1/std and NS Pendulum runs diverged (docs/learner_measurements.md).
    sigma_final: float | None = Field(None, gt=0)
    alpha_final: float | None = Field(
        None,
        gt=0,
        description="alpha at the end of the schedule, reached linearly over schedule_steps (null: alpha"
        " throughout)",
    )
    schedule_steps: int = Field(
        20000,
        ge=1,
        description="environment steps over which sigma and alpha go linearly to sigma_final and alpha_final",
    )
    schedule_gate: float | None = Field(
        None,
        gt=0,
        le=1,
        description="the schedule runs only through episodes that end with the success rate of the last"
        f" {GATE_EPISODES} at or above this (null: through every step): a start that has not yet learned"
        " keeps its full exploration",
    )
    bandwidth: Positive | list[Positive] = 0.4  # on states normalised to [-1, 1]; one or one per dimension
    policy_budget: int = Field(
        300,
        ge=1,
        description="the most kernel centres the policy function keeps; over it, the centre that matters"
        " least is dropped",
    )
    policy_ald: float = Field(
        0.05,
        ge=0,
        lt=1,
        description="a state becomes a new centre of the policy when its squared RKHS distance from the"
        " span of the centres (ALD test) exceeds this; 0: every state",
    )
    # value: V(s) by RLS-TD(0), the TD error is the advantage. compatible: V + the paper's compatible
    # features. q: kernel LSTD-Q on (state, action) with a product kernel (learner/critic.py).
    critic: Literal["value", "compatible", "q"] = "value"
    action_bandwidth: Positive | list[Positive] = 1.0  # critic q: on actions scaled to [-1, 1]
    # The critic's state kernel, when its function wants another width than the policy's (a value function
    # can be sharper than a good policy); None: the policy's ``bandwidth``.
    critic_bandwidth: Positive | list[Positive] | None = None
    # sampled: eq. 8 per sample, g = c·Â(s,a)·Σ⁻¹(a - h(s)). expected (critic q or compatible): eq. 9's
    # D(s), the action integral done in closed form on Q̂, g = c·D̂(s_t) at each visited state.
    policy_gradient: Literal["sampled", "expected"] = "sampled"
    # value critic: subtract B(s) ≈ E_a[δ | s], fitted to past TD errors (residual_fit; learner/critic.py),
    # from the advantage; the number is the fit's memory per step (0.999: ~1000 steps). None: plain δ.
    residual_baseline: float | None = Field(None, gt=0, lt=1)
    residual_fit: Literal["kernel_mean", "least_squares"] = "kernel_mean"  # how B(s) is fitted
    critic_budget: int = Field(300, ge=1, description="the most kernel centres the critic keeps")
    critic_ald: float = Field(
        0.05,
        ge=0,
        lt=1,
        description="a state becomes a new centre of the critic when its ALD residual exceeds this; 0:"
        " every state",
    )
    critic_forgetting: float = Field(
        0.999,
        gt=0,
        le=1,
        description="the critic's recursive least-squares forgetting factor per step: 1 forgets nothing,"
        " 0.999 weighs roughly the last 1000 steps",
    )
    critic_p0: float = Field(
        10.0,
        gt=0,
        description="the critic's initial inverse-covariance scale (P = p0·I), and the cap on its diagonal",
    )
    critic_lambda: float = Field(0.0, ge=0, lt=1)  # the critic's eligibility trace, LSTD(λ); 0: TD(0)
    # The retreat statistic (learner/retreat.py); None: the execution's own, ``local`` in the closed loop and
    # ``plan`` in plan execution (measured: ``local`` cannot see a plan go stale; results/plans).
    retreat: RetreatMode | None = None
    retreat_smoothing: float = Field(0.05, gt=0, le=1)  # λ of the gradient-field average
    retreat_threshold: float | None = None  # None: derived from the paper (see learner/retreat.py)
    # Read by the plan retreat only (learner/plan_tolerance.py). The kernel that compares the state a plan
    # predicted with the one reached is the policy's with its widths times ``plan_kernel_scale``: the
    # policy's kernel is as wide as generalisation wants, and a plan could drift by a task's whole
    # tolerance unseen (NS Reach: 18 cm wide on the relative coordinates, 5 cm success radius). One factor
    # applies on the dimensions where the policy's kernel is narrowest (every one when it has one width;
    # NS Reach: the relative coordinates), or give one per dimension. 0.15: the plans bench's best
    # single factor on every setting (docs/learner_plans.md), so no task sets its own.
    plan_kernel_scale: Scale | list[Scale] = 0.15
    # ``noise_floor`` (default) widens that kernel by the sensor noise measured along plans, so noise alone
    # retreats on at most ``plan_false_alarm`` of ticks; ``fixed`` keeps it as it is; ``learned``
    # standardises the gap by its running mean square per plan step (a candidate, plan_kernel_scale unused).
    plan_tolerance: Literal["fixed", "learned", "noise_floor"] = "noise_floor"
    plan_false_alarm: float = Field(
        0.01,
        gt=0,
        lt=0.5,
        description="plan retreat with plan_tolerance noise_floor: the fraction of ticks on which sensor"
        " noise alone may end a plan",
    )
    # The plan's world model (learner/plan_model.py): the env's ``nominal`` one, or ``corrected`` online
    # by a linear fit of its one-step residuals over the last ``plan_model_memory`` steps.
    plan_model: Literal["nominal", "corrected"] = "nominal"
    plan_model_memory: int = Field(
        1000,
        ge=2,
        description="plan_model corrected: the environment steps over which the linear correction of the"
        " model's one-step residuals is fitted",
    )
    # The policy is never updated: a handed-off policy measured as it is (bench/handoff.py's "frozen").
    frozen: bool = False
    handoff_step_scale: float = Field(
        1.0,
        gt=0,
        le=1,
        description="after a handoff (learner.policy_from), the policy's step size as a fraction of its"
        " schedule's: a policy trained elsewhere is fine-tuned, not trained again (1: the same step)",
    )
    epsilon: float = Field(1.0, gt=0)  # the ε of Theorem 1, used by the literal threshold Z ε / 2
    h_max: int = Field(
        50,
        ge=1,
        description="the longest segment (environment steps) before the policy is updated, if no retreat"
        " ends it sooner",
    )
    fixed_h: int = Field(10, ge=1)  # segment length of the fixed-H learner (retreat off)
    weight_decay: float = Field(
        1e-3,
        ge=0,
        description="shrinkage of the policy function per update, scaled by the step: f ← (1 -"
        " alpha·weight_decay)·f + ...",
    )
    max_grad_norm: float = Field(
        100.0, gt=0, description="each sample's policy gradient is clipped to this norm"
    )
    # Local step size: a sample at s moves f by alpha·n0/(n0 + n(s)), n(s) the samples that fell near s
    # (forgotten at visit_memory per step; learner/critic.py visits()): averaging where data is plentiful.
    # None: the same alpha everywhere. Value and compatible critics.
    visit_step: float | None = Field(None, gt=0)
    visit_memory: float = Field(
        0.9999,
        gt=0,
        le=1,
        description="visit_step: the factor by which visit counts are forgotten per step (0.9999: ~10 000"
        " steps)",
    )
    # GAE(λ) advantages for the value critic: Σ_k (γλ)^k δ_{t+k} in place of δ_t (less critic bias, more
    # variance); a sample's gradient enters the update once its weight (γλ)^k < 1 %. 0: the TD error.
    advantage_lambda: float = Field(0.0, ge=0, le=1)
    # Re-use of recent samples (learner/replay.py): at each segment update, replay_batch transitions drawn
    # from the last replay_window are applied again, re-scored by the critic as it stands and weighted by
    # their truncated importance ratio, at replay_step times alpha. 0: off. Closed loop, value critic.
    replay_window: int = Field(0, ge=0)
    replay_batch: int = Field(
        32, ge=1, description="replay_window: transitions replayed at each segment update"
    )
    replay_step: float = Field(
        1.0, gt=0, description="replay_window: the replayed samples' step size, as a multiple of alpha"
    )
    # |f| past which a step no longer pushes the squashed mean outward (learner/policy.py); None: unbounded.
    # These options are off by default: NS Pendulum needs them, NS CartPole does worse with them
    # (bench/learner_diagnosis.py, configs/pendulum.yaml).
    mean_limit: float | None = Field(None, gt=0)
    use_discount_factor: bool = True  # the paper's 1/(1-γ) in eq. 8
    # closed_loop: every action sampled at the state it acts in. plan: a segment is a committed plan
    # (learner/plans.py) of up to h_max (AdaptiveH) or fixed_h (RKHS) actions over model-predicted states.
    execution: Literal[Execution.CLOSED_LOOP, Execution.PLAN] = Execution.CLOSED_LOOP
    latency_steps: int = Field(0, ge=0)  # plan mode in-process: a new plan takes effect this many steps late
    plan_score: Literal["executed", "noise"] = Field(
        "executed",
        description="plan mode in-process: how a planned sample is scored, at the state it acted in"
        " (Σ⁻¹(a - h(s)), the plans experiment's runs) or by the noise that drew it at the predicted state"
        " (Σ⁻¹(a - h(ŝ)), as the actor beside the arm scores every sample, whatever this says)",
    )

    @property
    def retreat_mode(self) -> str:
        """``retreat``, or the execution's own when it is None."""
        if self.retreat is not None:
            return self.retreat
        return "plan" if self.execution == Execution.PLAN else "local"

    @model_validator(mode="after")
    def _options_fit_the_critic(self) -> AdaptiveHConfig:
        if self.visit_step is not None and self.critic == "q":
            raise ValueError("visit_step counts visits on the state dictionary: critic value or compatible")
        if self.advantage_lambda > 0 and (self.critic != "value" or self.policy_gradient != "sampled"):
            raise ValueError(
                "advantage_lambda sums TD errors: it needs critic: value, policy_gradient: sampled"
            )
        if self.replay_window > 0 and (self.critic != "value" or self.execution != Execution.CLOSED_LOOP):
            raise ValueError(
                "replay_window re-scores past samples with the value critic's TD error and their sampling "
                "policy's likelihood: it needs critic: value, execution: closed_loop"
            )
        if self.replay_window > 0 and self.advantage_lambda > 0:
            raise ValueError("replay_window re-scores one-step TD errors: set advantage_lambda to 0")
        if self.residual_baseline is not None and self.critic != "value":
            raise ValueError("residual_baseline is for the value critic (critic: value)")
        if self.policy_gradient == "expected" and self.critic == "value":
            raise ValueError(
                "policy_gradient: expected integrates Q̂ over actions; it needs critic: q or compatible"
            )
        return self


def _some_steps(value: int) -> int:
    if value == 0:
        raise ValueError("0 trains nothing: use -1 (as many as env steps) or >= 1")
    return value


# Gradient steps per training of an off-policy baseline: -1 (as many as env steps since the last) or >= 1.
GradientSteps = Annotated[int, Field(ge=-1), AfterValidator(_some_steps)]


def rkhs_config(algo: str, config: AdaptiveHConfig) -> AdaptiveHConfig:
    """An RKHS learner's config as ``algo`` runs it: ``rkhs``, the paper's fixed-H baseline, is AdaptiveH
    with the retreat test off (a segment every ``fixed_h`` steps). The learner and the actor that plays
    its segments beside the arm both take it from here, so the two cannot disagree on how segments end."""
    return config.model_copy(update={"retreat": "off"}) if algo == "rkhs" else config


class SB3Config(Section):
    """TD3/DDPG settings (zoo Pendulum-v1 values, ``learning_starts`` lowered: see learner/baselines.py)."""

    learning_rate: float = Field(
        1e-3, gt=0, lt=1, description="the optimiser's learning rate (Adam), actor and critic"
    )
    gamma: float = Field(
        0.98, gt=0, lt=1, description="discount factor of future rewards (per environment step)"
    )
    buffer_size: int = Field(200_000, ge=1, description="the replay buffer's capacity, in transitions")
    learning_starts: int = Field(
        1_000, ge=0, description="environment steps of random actions before training starts"
    )
    batch_size: int = Field(256, ge=1, description="transitions per gradient step")
    tau: float = Field(
        0.005, gt=0, le=1, description="soft update rate of the target networks (1: copied each step)"
    )
    train_freq_episodes: int = Field(1, ge=1, description="train after every this many episodes")
    gradient_steps: GradientSteps = -1  # -1: as many as env steps since the last training
    noise_std: float = Field(
        0.1,
        ge=0,
        description="standard deviation of the Gaussian exploration noise, as a fraction of the action"
        " range's half-width",
    )
    net_arch: list[Annotated[int, Field(ge=1)]] = Field(
        default_factory=lambda: [400, 300],
        min_length=1,
        description="hidden layer sizes of the actor and critic networks",
    )
    torch_threads: int = Field(1, ge=1, description="CPU threads PyTorch may use (torch.set_num_threads)")
    # Plan execution (learner/baselines_plan.py): every plan_h steps and at each episode start, plan
    # plan_h actions over the env's nominal model and play them open loop. 1: the closed loop.
    plan_h: int = Field(1, ge=1)


class SACConfig(Section):
    """SAC settings: the zoo's Pendulum-v1 (lr 1e-3) and SB3's defaults (see the module docstring)."""

    learning_rate: float = Field(
        1e-3,
        gt=0,
        lt=1,
        description="the optimiser's learning rate (Adam), actor, critics and entropy coefficient",
    )
    gamma: float = Field(
        0.99, gt=0, lt=1, description="discount factor of future rewards (per environment step)"
    )
    buffer_size: int = Field(1_000_000, ge=1, description="the replay buffer's capacity, in transitions")
    learning_starts: int = Field(
        100, ge=0, description="environment steps of random actions before training starts"
    )
    batch_size: int = Field(256, ge=1, description="transitions per gradient step")
    tau: float = Field(
        0.005, gt=0, le=1, description="soft update rate of the target networks (1: copied each step)"
    )
    train_freq: int = Field(1, ge=1)  # env steps between trainings
    gradient_steps: GradientSteps = 1  # per training; -1: as many as env steps since the last one
    ent_coef: Literal["auto"] | Annotated[float, Field(gt=0)] = Field(
        "auto",
        description="the entropy coefficient: auto (learned towards a target entropy) or a fixed number",
    )
    use_sde: bool = Field(
        False,
        description="explore with generalised state-dependent noise (gSDE) instead of independent noise per"
        " step",
    )
    net_arch: list[Annotated[int, Field(ge=1)]] = Field(
        default_factory=lambda: [256, 256],
        min_length=1,
        description="hidden layer sizes of the actor and critic networks",
    )
    torch_threads: int = Field(1, ge=1, description="CPU threads PyTorch may use (torch.set_num_threads)")
    plan_h: int = Field(1, ge=1)  # plan execution, as SB3Config's (1: the closed loop)


class PPOConfig(Section):
    """PPO settings: the zoo's tuned Pendulum-v1 values with one env (see the module docstring)."""

    learning_rate: float = Field(1e-3, gt=0, lt=1, description="the optimiser's learning rate (Adam)")
    n_steps: int = Field(1024, ge=2)  # env steps per rollout (one env)
    batch_size: int = Field(64, ge=2, description="transitions per minibatch")
    n_epochs: int = Field(10, ge=1, description="passes over each rollout")
    gamma: float = Field(
        0.9, gt=0, lt=1, description="discount factor of future rewards (per environment step)"
    )
    gae_lambda: float = Field(
        0.95,
        ge=0,
        le=1,
        description="λ of the generalised advantage estimate (0: one-step TD error, 1: Monte Carlo)",
    )
    clip_range: float = Field(0.2, gt=0, description="the clipping range of the policy's probability ratio")
    ent_coef: float = Field(0.0, ge=0, description="weight of the entropy bonus in the loss")
    vf_coef: float = Field(0.5, ge=0, description="weight of the value function's loss")
    max_grad_norm: float = Field(0.5, gt=0, description="gradients are clipped to this global norm")
    use_sde: bool = Field(
        True,
        description="explore with generalised state-dependent noise (gSDE) instead of independent noise per"
        " step",
    )
    sde_sample_freq: int = Field(
        4,
        ge=-1,
        description="use_sde: draw new exploration noise every this many steps (-1: only at the start of"
        " each rollout)",
    )
    net_arch: list[Annotated[int, Field(ge=1)]] = Field(
        default_factory=lambda: [64, 64],
        min_length=1,
        description="hidden layer sizes of the policy and value networks",
    )
    torch_threads: int = Field(1, ge=1, description="CPU threads PyTorch may use (torch.set_num_threads)")


AGENT_CONFIGS: dict[str, type[AdaptiveHConfig] | type[SB3Config] | type[SACConfig] | type[PPOConfig]] = {
    "adaptiveh": AdaptiveHConfig,
    "rkhs": AdaptiveHConfig,
    "td3": SB3Config,
    "ddpg": SB3Config,
    "sac": SACConfig,
    "ppo": PPOConfig,
}
"""The hyperparameter section of each algorithm, so a stack config checks ``agent:`` before it runs."""
