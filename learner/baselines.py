"""TD3, DDPG, SAC and PPO from stable-baselines3 behind the common agent protocol.

Why an adapter: the paper compares AdaptiveH with TD3 and DDPG on the same environments, seeds and
step budgets, so the baselines must run through the same ``learn(total_steps, callback)`` and record
the same ``RunLog`` as the RKHS learners; the benchmark then treats all four alike.

Hyperparameters are the rl-baselines3-zoo's for ``Pendulum-v1`` (identical for TD3 and DDPG there):
20k steps, gamma 0.98, buffer 2e5, normal action noise sigma 0.1, lr 1e-3, net [400, 300],
``train_freq=(1, "episode")``, ``gradient_steps=-1`` and SB3's defaults for the rest (batch 256,
tau 0.005; TD3: policy delay 2, target noise 0.2 clipped at 0.5). One change for non-stationarity
and equal budgets, applied to both algorithms and every environment:

* ``learning_starts`` 10 000 -> 1 000. The zoo spends the first 10k steps of its 20k-step Pendulum
  run on uniformly random actions; with learning curves compared from step 0 on worlds that drift
  during the run, that would hand half of every budget to a random policy. 1 000 is the zoo's own
  value for TD3 on Pendulum-v0.

Unchanged on purpose (same tuning effort as the RKHS learners, i.e. none per environment): the
replay buffer (2e5) is larger than every run, so TD3/DDPG replay transitions from all past worlds;
the observation carries no hint of the hidden drift (gravity, noise bound, target speed).

SAC and PPO (``SACConfig``, ``PPOConfig`` below) follow the same rule: the zoo's ``Pendulum-v1``
values on every environment, SB3's defaults for what the zoo leaves out, and only what the protocol
forces changed.

* SAC: the zoo sets only lr 1e-3 (20k steps); the rest is SB3's: buffer 1e6, ``learning_starts``
  100 (already below the 1 000 the TD3/DDPG rule caps it at, so kept), batch 256, tau 0.005,
  gamma 0.99, one gradient step per env step (``train_freq=1``), entropy coefficient "auto"
  (target -dim(A)), net [256, 256], no gSDE.
* PPO: the zoo's tuned values: n_steps 1024, gae_lambda 0.95, gamma 0.9, n_epochs 10, ent_coef 0,
  lr 1e-3, clip 0.2, gSDE with ``sde_sample_freq`` 4; SB3's batch 64, vf_coef 0.5, max_grad_norm 0.5,
  net 64x64 (policy and value). Protocol change: ``n_envs`` 4 -> 1. Every method of the bench plays
  one env whose seeded drift advances with its own steps; four copies would each see a quarter of
  the drift per global step. n_steps stays 1024 per env, so the gradient steps per env sample
  (n_epochs / batch) are the zoo's; a rollout cut by the step budget is not trained on (PPO trains
  on whole rollouts only), and the zoo's 1e5-step budget is the bench's 20k like every method's.

Plan execution (``learner.baselines_plan``): ``plan_h`` (TD3, DDPG, SAC; default 1, the
closed loop above, bit for bit) > 1 plays committed plans of ``plan_h`` actions sampled over the env's
nominal model, re-planned every ``plan_h`` steps and at each episode start, as the fixed-H RKHS learner
does in ``execution: plan``; segments go to the ``RunLog``, the plan counters are ``agent.channel``.
"""

from __future__ import annotations

import io
import json
import pickle
import random
import zipfile
from pathlib import Path
from typing import Any

import gymnasium as gym
import numpy as np
import torch
from stable_baselines3 import DDPG, PPO, SAC, TD3
from stable_baselines3.common.base_class import BaseAlgorithm
from stable_baselines3.common.callbacks import BaseCallback
from stable_baselines3.common.noise import NormalActionNoise

from learner.baselines_plan import PLAN_CLASSES, PlanQueue, world_model
from learner.config import PPOConfig, SACConfig, SB3Config
from learner.protocol import EpisodeRecord, RunLog, SegmentRecord, StepCallback

BaselineConfig = SB3Config | SACConfig | PPOConfig
SB3_CLASSES: dict[str, type[BaseAlgorithm]] = {"td3": TD3, "ddpg": DDPG, "sac": SAC, "ppo": PPO}
SB3_CONFIGS: dict[str, type[SB3Config] | type[SACConfig] | type[PPOConfig]] = {
    "td3": SB3Config,
    "ddpg": SB3Config,
    "sac": SACConfig,
    "ppo": PPOConfig,
}
ON_POLICY = frozenset({"ppo"})  # trains on its own rollouts: no replay buffer
_INFO_SKIP = {"episode", "terminal_observation", "TimeLimit.truncated", "final_observation", "final_info"}
_FORMAT = 1


def _scalar_info(info: dict[str, Any]) -> dict[str, float]:
    """The numeric scalars of an env's ``info`` (gravity, noise bound, success...), as floats."""
    out: dict[str, float] = {}
    for key, value in info.items():
        if key in _INFO_SKIP:
            continue
        if isinstance(value, bool | int | float | np.integer | np.floating | np.bool_):
            out[key] = float(value)
        elif isinstance(value, np.ndarray) and value.size == 1:
            out[key] = float(value.reshape(-1)[0])
    return out


def _success(info: dict[str, Any]) -> bool | None:
    for key in ("is_success", "success"):
        if key in info:
            return bool(info[key])
    return None


class _RecordCallback(BaseCallback):
    """Turns SB3's per-step view into EpisodeRecords and the protocol's step callback.

    It also stops SB3 exactly at the step budget: with ``train_freq=(1, "episode")`` SB3 would
    otherwise finish the running episode past ``total_timesteps``, breaking equal budgets.
    """

    def __init__(self, agent: SB3Agent, stop_at: int, user: StepCallback | None) -> None:
        super().__init__(verbose=0)
        self.agent = agent
        self.stop_at = stop_at
        self.user = user
        self.pending_train_steps = 0

    def _on_step(self) -> bool:
        agent = self.agent
        step = int(self.num_timesteps)
        agent.log.global_step = step
        agent._ep_return += float(np.asarray(self.locals["rewards"]).reshape(-1)[0])
        agent._ep_length += 1
        if bool(np.asarray(self.locals["dones"]).reshape(-1)[0]):
            info = dict(self.locals["infos"][0])
            agent.log.episodes.append(
                EpisodeRecord(
                    episode=agent.log.episode_count,
                    global_step=step,
                    ret=agent._ep_return,
                    length=agent._ep_length,
                    success=_success(info),
                    info=_scalar_info(info),
                )
            )
            agent._ep_return, agent._ep_length = 0.0, 0
        keep_going = not (self.user is not None and self.user(step, agent.log) is False)
        if keep_going and step < self.stop_at:
            return True
        self._finish_step()
        return False

    def _finish_step(self) -> None:
        """Do SB3's post-step bookkeeping that returning False would skip.

        SB3 checks the callback before it stores the transition and advances ``_last_obs``; without
        this the last transition of every ``learn`` call would be lost and the next call would act on
        a stale observation.
        """
        loc, model = self.locals, self.model
        dones = loc["dones"]
        model._update_info_buffer(loc["infos"], dones)
        if self.agent.algo in ON_POLICY:
            # The cut rollout is dropped (PPO trains on whole rollouts); the next learn() acts on the
            # env's real current observation, as it would have had the rollout gone on.
            model._last_obs = loc["new_obs"]
            model._last_episode_starts = dones
            return
        model._store_transition(
            loc["replay_buffer"], loc["buffer_actions"], loc["new_obs"], loc["rewards"], dones, loc["infos"]
        )
        if bool(np.asarray(dones).reshape(-1)[0]):
            model._episode_num += 1
            if model.action_noise is not None:
                model.action_noise.reset()
        self.pending_train_steps = int(loc["num_collected_steps"])


class SB3Agent:
    """TD3, DDPG, SAC or PPO (stable-baselines3) on one gymnasium env, honouring the ``Agent`` protocol."""

    def __init__(
        self, algo: str, env: gym.Env, config: BaselineConfig | dict[str, Any] | None = None, seed: int = 0
    ) -> None:
        if algo not in SB3_CLASSES:
            raise ValueError(f"algo must be one of {sorted(SB3_CLASSES)}, got {algo!r}")
        if not isinstance(env.action_space, gym.spaces.Box):
            raise ValueError("the SB3 baselines need a continuous (Box) action space")
        self.name = algo
        self.algo = algo
        self.env = env
        self.seed = int(seed)
        cls = SB3_CONFIGS[algo]
        self.config = config if isinstance(config, cls) else cls(**(dict(config or {})))
        self.log = RunLog()
        self._ep_return = 0.0
        self._ep_length = 0
        # Plan execution (plan_h > 1): the plan queue's counters, read by the benches like the RKHS
        # learners' plan channel; None in the closed loop.
        self.channel: PlanQueue | None = None
        torch.set_num_threads(self.config.torch_threads)
        self.model = self._build()
        self._attach_planner()

    @property
    def plan_h(self) -> int:
        return int(getattr(self.config, "plan_h", 1))

    def _model_class(self) -> type[BaseAlgorithm]:
        """SB3's own class in the closed loop; its plan-execution subclass when ``plan_h`` > 1."""
        return PLAN_CLASSES[self.algo] if self.plan_h > 1 else SB3_CLASSES[self.algo]

    def _attach_planner(self) -> None:
        self.channel = None
        if self.plan_h > 1:
            self.channel = PlanQueue(self.plan_h, world_model(self.env), self._record_segment)
        if hasattr(self.model, "plan_queue"):
            self.model.plan_queue = self.channel  # type: ignore[union-attr]

    def _record_segment(self, H: int, reason: str, global_step: int) -> None:
        self.log.segments.append(
            SegmentRecord(index=self.log.segment_count, global_step=global_step, H=H, reason=reason)
        )

    def _build(self) -> BaseAlgorithm:
        cfg = self.config
        common = {
            "seed": self.seed,
            "device": "cpu",
            "verbose": 0,
            "learning_rate": cfg.learning_rate,
            "gamma": cfg.gamma,
            "batch_size": cfg.batch_size,
            "policy_kwargs": {"net_arch": list(cfg.net_arch)},
        }
        if isinstance(cfg, PPOConfig):
            return PPO(
                "MlpPolicy",
                self.env,
                n_steps=cfg.n_steps,
                n_epochs=cfg.n_epochs,
                gae_lambda=cfg.gae_lambda,
                clip_range=cfg.clip_range,
                ent_coef=cfg.ent_coef,
                vf_coef=cfg.vf_coef,
                max_grad_norm=cfg.max_grad_norm,
                use_sde=cfg.use_sde,
                sde_sample_freq=cfg.sde_sample_freq,
                **common,
            )
        # What the off-policy learners share: a replay buffer, Polyak targets, gradient steps per update.
        common |= {
            "buffer_size": cfg.buffer_size,
            "learning_starts": cfg.learning_starts,
            "tau": cfg.tau,
            "gradient_steps": cfg.gradient_steps,
        }
        if isinstance(cfg, SACConfig):
            return self._model_class()(
                "MlpPolicy",
                self.env,
                train_freq=cfg.train_freq,
                ent_coef=cfg.ent_coef,
                use_sde=cfg.use_sde,
                **common,
            )
        n_act = int(np.prod(self.env.action_space.shape))
        noise = NormalActionNoise(mean=np.zeros(n_act), sigma=cfg.noise_std * np.ones(n_act))
        return self._model_class()(
            "MlpPolicy",
            self.env,
            train_freq=(cfg.train_freq_episodes, "episode"),
            action_noise=noise,
            **common,
        )

    def learn(self, total_steps: int, callback: StepCallback | None = None) -> RunLog:
        """Run exactly ``total_steps`` more env steps (fewer if ``callback`` returns False)."""
        if total_steps < 0:
            raise ValueError(f"total_steps must be >= 0, got {total_steps}")
        if total_steps == 0:
            return self.log
        torch.set_num_threads(self.config.torch_threads)
        stop_at = int(self.model.num_timesteps) + int(total_steps)
        recorder = _RecordCallback(self, stop_at, callback)
        self.model.learn(
            total_timesteps=int(total_steps), callback=recorder, reset_num_timesteps=False, progress_bar=False
        )
        # The rollout cut at the budget was never trained on; give it its gradient steps now so that
        # an agent that learned N steps has trained on N steps whether or not it was split.
        model = self.model
        off_policy = self.algo not in ON_POLICY
        if off_policy and recorder.pending_train_steps and model.num_timesteps > model.learning_starts:
            gradient_steps = self.config.gradient_steps  # type: ignore[union-attr]
            steps = recorder.pending_train_steps if gradient_steps < 0 else gradient_steps
            model.train(gradient_steps=steps, batch_size=self.config.batch_size)
        self.log.global_step = int(self.model.num_timesteps)
        return self.log

    def predict(self, obs: np.ndarray, deterministic: bool = True) -> np.ndarray:
        action, _ = self.model.predict(np.asarray(obs, dtype=np.float32), deterministic=deterministic)
        return np.asarray(action)

    def save(self, path: str | Path) -> None:
        """One zip: SB3 model (networks, optimisers, counters), replay buffer (off-policy), RNGs, RunLog."""
        path = Path(path)
        path.parent.mkdir(parents=True, exist_ok=True)
        model_bytes, buffer_bytes = io.BytesIO(), io.BytesIO()
        self.model.save(model_bytes)
        if self.algo not in ON_POLICY:
            self.model.save_replay_buffer(buffer_bytes)
        rng = {"numpy": np.random.get_state(), "python": random.getstate(), "torch": torch.get_rng_state()}
        get_state = getattr(self.env.unwrapped, "get_state", None)
        rng["env"] = get_state() if callable(get_state) else None
        meta = {"format": _FORMAT, "algo": self.algo, "seed": self.seed, "config": self.config.model_dump()}
        tmp = path.with_name(path.name + ".tmp")
        with zipfile.ZipFile(tmp, "w", compression=zipfile.ZIP_DEFLATED) as zf:
            zf.writestr("meta.json", json.dumps(meta))
            zf.writestr("log.json", json.dumps(self.log.to_dict()))
            zf.writestr("model.zip", model_bytes.getvalue())
            zf.writestr("replay_buffer.pkl", buffer_bytes.getvalue())
            zf.writestr("rng.pkl", pickle.dumps(rng))
        tmp.replace(path)

    def load(self, path: str | Path) -> None:
        """Restore a ``save``d agent onto this agent's env.

        SB3's wrappers (Monitor, OrderEnforcing) cannot be resumed mid-episode, so an episode running
        at save time is abandoned and learning resumes with a fresh episode; global step, buffer, log,
        RNGs and, for envs with ``get_state``/``set_state`` (ours), the drift clock all continue.
        """
        with zipfile.ZipFile(Path(path)) as zf:
            meta = json.loads(zf.read("meta.json"))
            if meta.get("format") != _FORMAT or meta.get("algo") != self.algo:
                raise ValueError(f"{path}: not a saved {self.algo} agent (meta {meta})")
            log = RunLog.from_dict(json.loads(zf.read("log.json")))
            model_bytes = zf.read("model.zip")
            buffer_bytes = zf.read("replay_buffer.pkl")
            rng = pickle.loads(zf.read("rng.pkl"))  # noqa: S301 - our own file format
        self.config = SB3_CONFIGS[self.algo](**meta["config"])
        self.seed = int(meta["seed"])
        torch.set_num_threads(self.config.torch_threads)
        self.model = self._model_class().load(io.BytesIO(model_bytes), env=self.env, device="cpu")
        if self.algo not in ON_POLICY:
            self.model.load_replay_buffer(io.BytesIO(buffer_bytes))
        self.model._last_obs = None  # force a fresh episode on this env at the next learn()
        np.random.set_state(rng["numpy"])
        random.setstate(rng["python"])
        torch.set_rng_state(rng["torch"])
        set_state = getattr(self.env.unwrapped, "set_state", None)
        if rng.get("env") is not None and callable(set_state):
            set_state(rng["env"])
        self.log = log
        self._ep_return, self._ep_length = 0.0, 0
        self._attach_planner()  # the running episode is abandoned, and with it any open plan
