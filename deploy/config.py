"""The stack config: one typed model of a top-level YAML (``configs/sim.yaml``), parsed once per process.

Each section's model lives beside its library (``robot_io.config``, ``vision.config``,
``learner.config``, ``bus.transport``, ``monitor.server``); this module binds them into
:class:`StackConfig` and adds the two sections that belong to the deploy layer itself (the learner
process and the recorder). ``load_stack_config`` is the only reader of these files: nodes and commands
take the result (or its sections), so a key is read, coerced and checked in one place.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any, Literal

from pydantic import Field, ValidationInfo, field_validator, model_validator

from bus.messages import TOPIC_ROOTS
from bus.transport import ZenohConfig
from common.config import Box3, ConfigError, Section, compose_yaml, describe, load_yaml, overlay, parse
from learner.config import AGENT_CONFIGS
from learner.registry import Algo
from learner.segments import Execution
from monitor.server import MonitorConfig
from monitor.view_limits import ViewLimits
from robot_io.config import RobotConfig
from vision.config import VisionConfig

__all__ = [
    "ConfigError",
    "LearnerConfig",
    "RecordingConfig",
    "StackConfig",
    "compose_stack_yaml",
    "load_stack_config",
    "load_yaml",
]


ACTOR_ALGOS = ("adaptiveh", "rkhs")  # the RKHS learners: their policy travels as a snapshot


class LearnerConfig(Section):
    """The ``learner:`` section: the learner process (``adaptiveh learn``)."""

    algo: Algo = Field(
        "adaptiveh",
        description="the learning algorithm: adaptiveh (the paper's, adaptive horizon), rkhs (fixed"
        " horizon), or a stable-baselines3 baseline (td3, ddpg, sac, ppo)",
    )
    steps: int = Field(4000, ge=1)  # total environment steps (a resumed run counts those already done)
    seed: int = Field(0, description="the learning agent's random seed (its initial policy and exploration)")
    agent: dict[str, Any] = {}  # the algorithm's hyperparameters (learner.config), checked against ``algo``
    chunk_len: int = Field(
        10,
        ge=1,
        description="actions per chunk sent to robot-io: this step's action, then the tail played if the"
        " next chunk is late (1: no tail)",
    )
    # The chunk's tail after this step's action, played if the learner is late for a tick: ``hold``
    # (zero displacements) or ``policy`` (AdaptiveH's mean rolled forward). Measured: with ``policy`` a
    # late learner's transitions mix in planned actions and NS Reach did not learn over Zenoh in 2400
    # steps; with ``hold`` a late tick only costs time.
    plan: Literal["hold", "policy"] = "hold"
    max_episode_steps: int = Field(
        200,
        ge=1,
        description="environment steps per episode (each one control period): the episode ends, the arm"
        " goes home and a new target is drawn",
    )
    # vision's tracked target, or the simulator's ground truth (tests and benchmarks only).
    target_topic: Literal["target", "sim/target_truth"] = "target"
    # Where the target moves and how fast: the learner scales its state with these, so they must match
    # the real target's range (NSReach-v0 scales with its motion preset's box and speed). Measured: with
    # the workspace as the box and 0.2 m/s, in-process NS Reach seed 0 stopped learning (0 % vs 90 %).
    target_box: Box3 = ((0.35, -0.3, 0.12), (0.65, 0.3, 0.45))
    target_speed_max: float = Field(
        0.06,
        gt=0,
        description="the fastest the target moves (m/s): the learner scales the target's velocity in its"
        " state by it",
    )
    # The policy's scales, with target_box and target_speed_max: a policy is a function of its scaled
    # state and action, so an arm whose box or step is tighter than the simulator's keeps the simulator's
    # here to run the simulator's policy (--policy-from refuses a checkpoint of other scales), while
    # robot-io holds the arm to its own robot.workspace and robot.max_step_m.
    state_workspace: Box3 | None = Field(
        None,
        description="the box the policy's state scales the hand's position by, as the policy was trained"
        " (null: robot.workspace); robot-io still holds the arm to robot.workspace",
    )
    action_step_m: float | None = Field(
        None,
        gt=0,
        le=0.05,
        description="the policy's largest step per axis (m), as it was trained (null: robot.max_step_m);"
        " what is sent is still capped at robot.max_step_m",
    )
    step_timeout_s: float = Field(
        2.0,
        gt=0,
        description="how long one environment step waits (seconds) for robot-io to report its chunk played;"
        " not played by then (the arm held, paused, e-stopped), the chunk is sent again",
    )
    # A target older than this (or reported lost) is not guessed from: the closed loop waits for a fresh
    # fix (the arm holds meanwhile: no chunk, so robot-io's watchdog stops it).
    target_timeout_s: float = Field(0.5, gt=0)
    checkpoint_dir: str = Field(
        "runs/stack/learner",
        description="where the learner saves its checkpoint (checkpoint.pkl) and resumes from; relative to"
        " the working directory",
    )
    checkpoint_every: int = Field(
        500, ge=1, description="save a checkpoint every this many environment steps (and at the end)"
    )
    unsaved_limit: int = Field(
        20_000,
        ge=100,
        description="execution actor: the transitions an actor keeps until the learner has checkpointed"
        " them (sent again to a learner that lacks them); beyond it the oldest are dropped, counted and"
        " reported as lost (20,000: over 16 minutes at 20 Hz)",
    )
    # A handoff: start from the policy (critic, gradient field, plan tolerance) of another run's
    # checkpoint, a file or its run folder (``adaptiveh train`` or another stack's checkpoint_dir), then
    # keep learning. Checked against this task when the stack starts (learner.provenance); a run that
    # already has its own checkpoint resumes that instead. Relative to the working directory.
    policy_from: str | None = None
    # actor: the plans are made and judged by an actor beside the arm (``adaptiveh act``,
    # deploy/actor_node.py) from the newest policy snapshot this learner published; the learner learns
    # from the actor's stream of executed ticks, wherever it runs (adaptiveh and rkhs only).
    # closed_loop: the learner drives the arm, one action per step sent as a chunk (above): every
    # registry agent, the SB3 baselines included.
    execution: Literal[Execution.CLOSED_LOOP, Execution.ACTOR] = Execution.CLOSED_LOOP
    # The learner's thinking time made real: each chunk (actor: each policy snapshot) is published this
    # late (closed loop: the last chunk's tail plays meanwhile; actor: the actor keeps planning with the
    # snapshot it has).
    latency_ms: float = Field(0.0, ge=0, le=10_000)

    @field_validator("agent")
    @classmethod
    def _agent_fits_algo(cls, agent: dict[str, Any], info: ValidationInfo) -> dict[str, Any]:
        """Checked at load time against the algorithm's own section, not when the learner starts."""
        algo = info.data.get("algo")
        if algo is not None:
            model = AGENT_CONFIGS[algo]
            try:
                model.model_validate(agent)
            except ValueError as exc:  # pydantic's ValidationError: say which keys, for this algo
                raise ValueError(f"for algo {algo}: {describe(exc, model)}") from None
        owned = sorted({"execution", "latency_steps"} & set(agent))
        if owned:  # one place says how the learner executes: this section, not the agent's
            raise ValueError(f"{owned}: set by learner.execution and learner.latency_ms, not learner.agent")
        return agent

    @model_validator(mode="after")
    def _actor_supported(self) -> LearnerConfig:
        if self.execution == Execution.ACTOR and self.algo not in ACTOR_ALGOS:
            raise ValueError(f"execution actor: algo {self.algo} has no actor; use one of {ACTOR_ALGOS}")
        if self.policy_from is not None and self.algo not in ACTOR_ALGOS:
            raise ValueError(
                f"policy_from: algo {self.algo} cannot start from a handoff; use one of {ACTOR_ALGOS}"
            )
        return self

    @property
    def longest_segment(self) -> int | None:
        """No segment of this learner is longer (its h_max or fixed H); None for one without segments."""
        agent = AGENT_CONFIGS[self.algo].model_validate(self.agent)
        bounds = [getattr(agent, name) for name in ("h_max", "fixed_h") if hasattr(agent, name)]
        return max(bounds) if bounds else None

    def agent_config(self) -> dict[str, Any]:
        """``agent`` with the execution mode: an actor's agent plans (from the state the arm is in: no
        latency to plan over, the snapshot is what arrives late)."""
        if self.execution == Execution.CLOSED_LOOP:
            return dict(self.agent)
        return {**self.agent, "execution": Execution.PLAN.value, "latency_steps": 0}


class RecordingConfig(Section):
    """The ``recording:`` section: where MCAP files go and which topics are left out (raw frames)."""

    enabled: bool = Field(True, description="record the bus to MCAP while the stack runs (``adaptiveh up``)")
    dir: str = Field(
        "runs/stack/recordings",
        description="the folder the MCAP files are written to; relative to the working directory",
    )
    exclude: tuple[str, ...] = Field(
        (),
        description="topics left out of the recording, as prefixes of the key after adaptiveh/<name>/ (e.g."
        " camera/frame: the raw frames)",
    )
    # Written to disk at least this often: a supervisor killed outright loses at most this much.
    flush_s: float = Field(1.0, gt=0, le=60)
    # A new file (<name>.part2.mcap, ...) after this long: the MCAP writer's index grows with each flush
    # until its file ends. ``adaptiveh replay`` and ``recording.read`` of the first file read them all.
    split_s: float = Field(900.0, ge=10)


class SupervisorConfig(Section):
    """The ``supervisor:`` section of ``adaptiveh up``: how a crashed part is brought back."""

    max_restarts: int = Field(3, ge=0)  # per part; the run ends when a part has used them all
    backoff_s: float = Field(1.0, gt=0)  # wait before the first restart, doubled each time
    backoff_max_s: float = Field(
        30.0,
        gt=0,
        description="the longest wait (seconds) before a restart, however many restarts came before",
    )
    # Linux niceness (0..19) per part: under CPU contention robot-io's control loop and the learner come
    # before the camera's rendering and the operator's pages (measured: with a hammered monitor, starved
    # robot-io ticks delayed e-stops past 2 periods).
    nice: dict[Literal["robot_io", "vision", "monitor", "learner"], int] = {"vision": 5, "monitor": 5}

    @field_validator("nice")
    @classmethod
    def _niceness(cls, value: dict[str, int]) -> dict[str, int]:
        bad = {part: n for part, n in value.items() if not 0 <= n <= 19}
        if bad:
            raise ValueError(f"niceness must be 0..19 (raising priority needs privileges): {bad}")
        return value


class ArmConfig(Section):
    """One arm of a fleet: its own robot-io and actor (and camera, when the stack has ``vision``)."""

    name: str = Field(
        pattern=r"^[A-Za-z0-9_-]+$", description="the arm's part of its keys: adaptiveh/<name>/<arm>/..."
    )
    seed: int = Field(
        description="the arm's own seed: its target's motion (robot.seed) and its actor's exploration and"
        " episodes (learner.seed)"
    )

    @field_validator("name")
    @classmethod
    def _not_a_topic(cls, name: str) -> str:
        if name in TOPIC_ROOTS:
            raise ValueError(f"{name!r} is a topic's key part ({sorted(TOPIC_ROOTS)} are taken)")
        return name


class FleetConfig(Section):
    """The ``fleet:`` section: several arms feed one learner, which publishes one policy to all."""

    arms: tuple[ArmConfig, ...] = Field(
        min_length=1,
        description="the arms, each {name: its key part (adaptiveh/<name>/<arm>/...), seed: its target's"
        " motion and its actor's exploration}, each with its own robot-io and actor (adaptiveh up starts"
        " them all)",
    )

    @field_validator("arms")
    @classmethod
    def _unique(cls, arms: tuple[ArmConfig, ...]) -> tuple[ArmConfig, ...]:
        names = [a.name for a in arms]
        twice = sorted({n for n in names if names.count(n) > 1})
        if twice:
            raise ValueError(f"arm names must differ: {twice} named twice")
        return arms

    def arm(self, name: str) -> ArmConfig:
        for arm in self.arms:
            if arm.name == name:
                return arm
        raise ValueError(f"no arm {name!r} in the fleet (arms: {[a.name for a in self.arms]})")


# Learner state that runs across an episode's ticks: pooled arms' ticks interleave, so each would need
# one per arm; the fleet's learner keeps the open segment and the episode's return per arm only.
PER_EPISODE_TRACES = ("critic_lambda", "advantage_lambda")


class StackConfig(Section):
    """A whole top-level config: one robot's stack. ``vision``/``monitor`` absent: that part is not run."""

    name: str = Field("panda", pattern=r"^[^/*$?#]+$")  # one Zenoh key segment: adaptiveh/<name>/...
    zenoh: ZenohConfig = Field(
        ZenohConfig(), description="how every part joins the bus: endpoints, lease, TLS, authentication"
    )
    robot: RobotConfig = Field(
        RobotConfig(), description="robot-io: the arm's backend, control rate, limits and safety"
    )
    vision: VisionConfig | None = Field(
        None, description="the vision part: camera, detection, tracking, calibration (null: not run)"
    )
    learner: LearnerConfig = Field(
        LearnerConfig(),
        description="the learner process: algorithm, steps, how it drives the arm, checkpoints",
    )
    monitor: MonitorConfig | None = Field(
        None, description="the operator's web page and Foxglove live view (null: not run)"
    )
    recording: RecordingConfig = Field(RecordingConfig(), description="the MCAP recording of the bus")
    supervisor: SupervisorConfig = Field(
        SupervisorConfig(), description="how ``adaptiveh up`` restarts a part that crashed"
    )
    fleet: FleetConfig | None = Field(
        None, description="several arms, one learner (null: one arm, keyed adaptiveh/<name>/...)"
    )
    arm: str | None = Field(
        None,
        description="the arm of the fleet this process serves (set by the parts' --arm, not in a file);"
        " its keys are adaptiveh/<name>/<arm>/...",
    )

    @property
    def bus_key(self) -> str:
        """This process's own keys: the stack's name, or ``<name>/<arm>`` for an arm of a fleet."""
        return f"{self.name}/{self.arm}" if self.arm else self.name

    @property
    def arm_names(self) -> list[str]:
        """The arms ``adaptiveh up`` starts: the fleet's, or [""] for the one arm of a plain stack."""
        return [a.name for a in self.fleet.arms] if self.fleet is not None else [""]

    def for_arm(self, name: str | None) -> StackConfig:
        """The config as arm ``name``'s parts read it: its keys, its seeds (``ArmConfig.seed``); None: a
        stack of one arm, as it is (a fleet's part must say which arm: its keys depend on it)."""
        if name is None:
            if self.fleet is not None:
                raise ConfigError(f"the config has a fleet of arms {self.arm_names}: say which with --arm")
            return self
        if self.fleet is None:
            raise ConfigError(f"arm {name!r}: the config has no fleet section")
        try:
            arm = self.fleet.arm(name)
        except ValueError as exc:
            raise ConfigError(str(exc)) from None
        robot = self.robot.model_copy(update={"seed": arm.seed})
        learner = self.learner.model_copy(update={"seed": arm.seed})
        return self.model_copy(update={"arm": name, "robot": robot, "learner": learner})

    def view_limits(self) -> ViewLimits:
        """What the operator's views of this stack will plot (``monitor.view_limits``)."""
        return ViewLimits(self.learner.longest_segment)

    @model_validator(mode="after")
    def _fleet_learns_from_actors(self) -> StackConfig:
        if self.fleet is None:
            if self.arm is not None:
                raise ValueError(f"arm {self.arm!r}: the config has no fleet section")
            return self
        if self.learner.execution != Execution.ACTOR:
            raise ValueError("fleet: needs learner.execution actor (an actor beside each arm)")
        traced = [k for k in PER_EPISODE_TRACES if self.learner.agent.get(k, 0) > 0]
        if traced:
            raise ValueError(
                f"fleet: learner.agent.{traced[0]} > 0 keeps one trace across an episode's ticks, and pooled"
                " arms' ticks interleave; set it to 0"
            )
        if self.arm is not None:
            self.fleet.arm(self.arm)
        return self

    @model_validator(mode="after")
    def _plan_model_is_the_arms(self) -> StackConfig:
        """A Franka's plans are predicted with its own tracking: the mock's default lags nothing like it."""
        if self.robot.backend == "franka" and self.robot.tracking is None:
            raise ValueError(
                "robot.tracking: not set; a franka arm's plan model needs this arm's own tracking, not the"
                " PyBullet mock's: fit it with python bench/reach_model.py --recording RUN.mcap on a run of"
                " this arm (configs/franka_realsense.yaml ships franky-sim's at the same motion settings)"
            )
        return self

    @model_validator(mode="after")
    def _sim_camera_needs_sim_arm(self) -> StackConfig:
        if self.vision is not None and self.vision.camera == "sim" and not self.robot.simulated:
            raise ValueError(
                "vision camera sim renders a replica of the simulated world (the pybullet mock, or franky-sim"
                " with robot.franka.simulated_target), and this robot has none: use realsense"
            )
        return self


def _merge(data: dict[str, Any], overrides: dict[str, Any]) -> dict[str, Any]:
    """``data`` with ``overrides`` laid over it, key by key within a section; None means "not overridden"."""
    out = dict(data)
    for key, value in overrides.items():
        if isinstance(value, dict):
            given = {k: v for k, v in value.items() if v is not None}
            if given:
                out[key] = {**(out.get(key) or {}), **given}
        elif value is not None:
            out[key] = value
    return out


def compose_stack_yaml(path: str | Path) -> dict[str, Any]:
    """The stack config at ``path`` as one mapping, its overlays resolved: ``base: FILE`` (this file's
    sections laid over FILE's, key by key) and ``learner.agent_from: FILE`` (a task config, e.g.
    ``configs/reach.yaml``, whose ``agent:`` this file's ``learner.agent`` overrides key by key), so the
    stack learns with the task's tuned agent instead of a copy that drifts. Both paths are relative to
    the folder of the file that names them; a copy written elsewhere is written from this mapping.
    ``adaptiveh config show FILE`` prints it."""
    return compose_yaml(path, _agent_from)


def _agent_from(data: dict[str, Any], path: Path) -> dict[str, Any]:
    learner = data.get("learner")
    ref = learner.pop("agent_from", None) if isinstance(learner, dict) else None
    if ref is None:
        return data
    try:
        task = load_yaml(path.parent / ref)
    except ConfigError as exc:
        raise ConfigError(f"{path}: learner.agent_from: {exc}") from None
    if not isinstance(task.get("agent"), dict):
        raise ConfigError(f"{path}: learner.agent_from: {ref} has no agent: section")
    learner["agent"] = overlay(task["agent"], learner.get("agent") or {})
    return data


def load_stack_config(path: str | Path, **overrides: Any) -> StackConfig:
    """Read and check ``path`` (overlays resolved: ``compose_stack_yaml``); ``overrides`` (e.g.
    ``learner={"steps": 60}``) are checked as if in the file.

    A ConfigError names the file and every bad key path (``robot.watchdog_timeout_s``), with the
    allowed values or keys.
    """
    return parse(StackConfig, _merge(compose_stack_yaml(path), overrides), str(path))
