"""A policy handed from one run to another: loaded when trained on the same task, refused naming the field
otherwise (``learner.provenance``, ``AdaptiveH.start_from``)."""

from __future__ import annotations

import dataclasses
import pickle

import numpy as np
import pytest

from deploy.config import load_stack_config
from deploy.zenoh_env import ReachSpec, env_settings
from learner.adaptiveh import AdaptiveH
from learner.config import AdaptiveHConfig
from learner.provenance import ArmRecord, HandoffMismatch, TrainedOn
from robot_io.description import MODELS, RobotDescription
from robot_io.kinematics import Kinematics
from tasks.reach_env import NSReachEnv

AGENT = AdaptiveHConfig(policy_budget=40, critic_budget=40, execution="plan")


@pytest.fixture(scope="module")
def trained(tmp_path_factory):
    """A checkpoint of AdaptiveH after 150 steps of in-process NS Reach (the PyBullet mock)."""
    env = NSReachEnv(motion="slow", max_episode_steps=50)
    agent = AdaptiveH(env, AGENT, seed=3)
    agent.learn(150)
    path = tmp_path_factory.mktemp("handoff") / "checkpoint.pkl"
    agent.save(path)
    obs = [env.reset(seed=s)[0] for s in range(5)]
    env.close()
    return path, agent, obs


def stack_spec(config: str = "configs/franka_sim.yaml") -> ReachSpec:
    """The reach task as the stack's learner sees it (no robot behind it)."""
    return ReachSpec(env_settings(load_stack_config(config)))


def rewrite(path, tmp_path, **changes):
    """A copy of the checkpoint at ``path`` whose trained_on record has ``changes``."""
    with open(path, "rb") as fh:
        state = pickle.load(fh)
    record = TrainedOn.from_dict(state["trained_on"])
    state["trained_on"] = dataclasses.replace(record, **changes).to_dict()
    out = tmp_path / "changed.pkl"
    with open(out, "wb") as fh:
        pickle.dump(state, fh)
    return out


def test_the_stack_on_franky_sim_starts_from_the_mock_policy(trained):
    path, source, observations = trained
    agent = AdaptiveH(stack_spec(), AGENT, seed=0)
    came = agent.start_from(path.parent)  # the run folder works as well as the file
    assert came["arm"] == "panda" and came["steps"] == 150 and "in-process" in came["trained_on"]
    assert agent.trained_on.arm.model == "fr3"
    for obs in observations:
        np.testing.assert_array_equal(agent.predict(obs), source.predict(obs))
    assert agent.log.global_step == 0  # this run's own clock
    assert agent.schedule_offset == 150  # the exploration anneals on from where the source left it
    np.testing.assert_allclose(agent.policy.sigma, source.policy.sigma)


def test_the_real_arm_starts_from_the_simulators_policy(trained):
    """configs/franka_realsense.yaml keeps the simulator's scales (``learner.state_workspace``,
    ``action_step_m``), so the policy trained in simulation and rehearsed on franky-sim runs on the arm."""
    path, source, observations = trained
    agent = AdaptiveH(stack_spec("configs/franka_realsense.yaml"), AGENT, seed=0)
    assert agent.start_from(path)["steps"] == 150
    for obs in observations:
        np.testing.assert_array_equal(agent.predict(obs), source.predict(obs))


@pytest.mark.parametrize(
    ("field", "change"),
    [
        ("task", {"task": "NSCartPoleContinuous-v0"}),
        ("observation", {"observation": tuple(f"s{i}" for i in range(15))}),
        ("observation_high", {"observation_high": (1.0,) * 15}),
        ("action_low", {"action_low": (-0.1,) * 3}),
        ("arm.family", {"arm": ArmRecord("ur5e", "universal_robots", 0.0)}),
        ("arm.tcp_offset_m", {"arm": ArmRecord("panda", "franka", 0.0)}),
    ],
)
def test_a_checkpoint_of_something_else_is_refused_naming_the_field(trained, tmp_path, field, change):
    agent = AdaptiveH(stack_spec(), AGENT, seed=0)
    before = agent.policy.f.weights.copy()
    with pytest.raises(HandoffMismatch) as err:
        agent.start_from(rewrite(trained[0], tmp_path, **change))
    assert err.value.field == field and f"{field} differs" in str(err.value)
    np.testing.assert_array_equal(agent.policy.f.weights, before)  # nothing was taken


def test_a_checkpoint_without_a_record_is_refused(trained, tmp_path):
    with open(trained[0], "rb") as fh:
        state = pickle.load(fh)
    del state["trained_on"]
    old = tmp_path / "old.pkl"
    old.write_bytes(pickle.dumps(state))
    with pytest.raises(ValueError, match="records no trained_on"):
        AdaptiveH(stack_spec(), AGENT, seed=0).start_from(old)


@pytest.mark.parametrize("model", sorted(MODELS))
def test_each_arm_records_the_tcp_its_urdf_has(model):
    """``RobotModel.tcp_offset_m``, which the handoff compares, is the URDF's flange-to-TCP distance."""
    kin = Kinematics(RobotDescription(model))
    q = np.asarray(MODELS[model].home_q)
    flange = kin.model.getFrameId(MODELS[model].flange_link)
    import pinocchio as pin

    pin.framesForwardKinematics(kin.model, kin.data, q)
    distance = np.linalg.norm(kin.data.oMf[flange].translation - kin.ee_position(q))
    assert distance == pytest.approx(MODELS[model].tcp_offset_m, abs=1e-4)


def test_a_handed_off_policy_is_fine_tuned_at_a_fraction_of_the_step(trained):
    """``handoff_step_scale``: after a handoff the policy's step is that fraction of its schedule's (the
    source's steps carry the schedule on); a run that started from nothing keeps the schedule's step."""
    path, _, _ = trained
    quarter = AGENT.model_copy(update={"handoff_step_scale": 0.25})
    spec = stack_spec("configs/sim.yaml")
    scaled, plain, fresh = (AdaptiveH(spec, c, seed=0) for c in (quarter, AGENT, quarter))
    scaled.start_from(path)
    plain.start_from(path)
    assert scaled.alpha == pytest.approx(0.25 * plain.alpha) and plain.alpha > 0
    assert fresh.alpha == pytest.approx(AGENT.alpha)  # no handoff: the schedule's own step
