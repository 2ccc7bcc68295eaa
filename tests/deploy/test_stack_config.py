"""The stack config schema: every error names the key path and what is allowed; shipped configs load."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import yaml

from common.config import ConfigError
from deploy.config import StackConfig, compose_stack_yaml, load_stack_config
from deploy.zenoh_env import env_settings
from learner.config import AGENT_CONFIGS
from learner.registry import ALGOS

CONFIGS = Path(__file__).parents[2] / "configs"
SIM = CONFIGS / "sim.yaml"


def _write(tmp_path: Path, text: str) -> Path:
    path = tmp_path / "c.yaml"
    path.write_text(text)
    return path


def _with(tmp_path: Path, section: str, key: str, value: object) -> Path:
    """configs/sim.yaml with ``section.key`` set to ``value`` (``section`` empty: a top-level key)."""
    data = compose_stack_yaml(SIM)
    (data[section] if section else data)[key] = value
    return _write(tmp_path, yaml.safe_dump(data))


@pytest.mark.parametrize(
    ("section", "key", "value", "needles"),
    [
        # an unknown key: named with its path, and the keys allowed there
        ("robot", "colour", "red", ["robot.colour: unknown key; allowed: [", "'watchdog_timeout_s'"]),
        ("", "colour", "red", ["colour: unknown key; allowed: [", "'learner', 'monitor', 'name'"]),
        # a wrong type
        ("robot", "watchdog_timeout_s", "soon", ["robot.watchdog_timeout_s: Input should be a valid number"]),
        ("robot", "physics_substeps", 12.5, ["robot.physics_substeps: Input should be a valid integer"]),
        # out of range: the bound is in the message
        ("robot", "max_step_m", 0.2, ["robot.max_step_m: Input should be less than or equal to 0.05"]),
        ("learner", "steps", 0, ["learner.steps: Input should be greater than or equal to 1 (got 0)"]),
        # a value outside a closed set: the allowed values are listed
        ("robot", "backend", "ur5", ["robot.backend: Input should be 'pybullet' or 'franka' (got 'ur5')"]),
        ("learner", "algo", "a2c", ["learner.algo: Input should be", "'adaptiveh'", "'ppo'", "(got 'a2c')"]),
        ("zenoh", "mode", "mesh", ["zenoh.mode: Input should be 'peer', 'client' or 'router' (got 'mesh')"]),
        # nested sections and invariants keep their full path
        ("learner", "target_box", [[0.6, 0, 0.1], [0.4, 0.3, 0.5]], ["learner.target_box:", "below hi"]),
        ("learner", "agent", {"gamma": 2.0}, ["learner.agent:", "for algo adaptiveh: gamma:", "less than 1"]),
        ("learner", "agent", {"gama": 0.5}, ["learner.agent:", "gama: unknown key; allowed: [", "'gamma'"]),
        ("", "name", "a/b", ["name: String should match pattern"]),
    ],
)
def test_a_bad_value_names_its_key_path_and_what_is_allowed(tmp_path, section, key, value, needles):
    path = _with(tmp_path, section, key, value)
    with pytest.raises(ConfigError) as err:
        load_stack_config(path)
    message = str(err.value)
    assert message.startswith(f"{path}: ")
    for needle in needles:
        assert needle in message, (needle, message)


def test_nested_keys_and_every_error_are_reported(tmp_path):
    data = compose_stack_yaml(SIM)
    data["vision"]["detection"]["target_shape"] = "cone"
    data["robot"]["ik"]["iterations"] = 0
    message = str(pytest.raises(ConfigError, load_stack_config, _write(tmp_path, yaml.safe_dump(data))).value)
    assert "vision.detection.target_shape: Input should be 'box', 'sphere' or 'point' (got 'cone')" in message
    assert "robot.ik.iterations: Input should be greater than or equal to 1 (got 0)" in message


def test_numbers_yaml_reads_as_text_are_coerced(tmp_path):
    text = SIM.read_text().replace("watchdog_timeout_s: 0.5", "watchdog_timeout_s: 5e-1")
    path = _write(tmp_path, text.replace("agent_from: reach.yaml", f"agent_from: {CONFIGS / 'reach.yaml'}"))
    assert yaml.safe_load(text)["robot"]["watchdog_timeout_s"] == "5e-1"  # YAML 1.1 wants a dot in a float
    assert load_stack_config(path).robot.watchdog_timeout_s == 0.5


def test_overrides_are_checked_like_the_file():
    assert load_stack_config(SIM, learner={"steps": 60, "algo": None}).learner.steps == 60
    assert load_stack_config(SIM, learner={"steps": None}).learner.steps == 6000  # None: not overridden
    with pytest.raises(ConfigError, match=r"learner\.steps: Input should be greater than or equal to 1"):
        load_stack_config(SIM, learner={"steps": 0})


def test_absent_parts_are_none_and_other_sections_default(tmp_path):
    cfg = load_stack_config(_write(tmp_path, "name: lone\nrobot: {max_step_m: 0.03}\n"))
    assert cfg.vision is None and cfg.monitor is None
    assert cfg.robot.max_step_m == 0.03 and cfg == StackConfig(name="lone", robot={"max_step_m": 0.03})


def test_the_learner_env_takes_the_robots_workspace_rate_and_step(tmp_path):
    data = compose_stack_yaml(SIM)
    data["robot"].update(workspace={"lo": [0.3, -0.3, 0.1], "hi": [0.7, 0.3, 0.6]}, max_step_m=0.02)
    data["robot"]["control_rate_hz"] = 10.0
    env = env_settings(load_stack_config(_write(tmp_path, yaml.safe_dump(data))))
    assert (env.workspace_lo, env.workspace_hi) == ((0.3, -0.3, 0.1), (0.7, 0.3, 0.6))
    assert (env.max_step_m, env.control_rate_hz) == (0.02, 10.0)


def test_the_policys_scales_can_be_the_simulators_on_a_tighter_arm(tmp_path):
    """``learner.state_workspace`` and ``learner.action_step_m`` scale the policy's state and action as the
    simulator's did (configs/franka_realsense.yaml: its policy runs there); robot-io's box and step still
    bound what the plan model predicts and what is sent. Unset, the scales are the robot's."""
    from deploy.zenoh_env import ReachSpec

    sim = ReachSpec(env_settings(load_stack_config(SIM)))
    data = compose_stack_yaml(SIM)
    data["robot"].update(workspace={"lo": [0.3, -0.3, 0.1], "hi": [0.7, 0.3, 0.6]}, max_step_m=0.03)
    tight = ReachSpec(env_settings(load_stack_config(_write(tmp_path, yaml.safe_dump(data)))))
    data["learner"].update(state_workspace=[[0.2, -0.45, 0.05], [0.8, 0.45, 0.7]], action_step_m=0.05)
    scaled = ReachSpec(env_settings(load_stack_config(_write(tmp_path, yaml.safe_dump(data)))))
    assert tight.action_space.high[0] == np.float32(0.03)
    assert tight.observation_space != sim.observation_space
    assert scaled.observation_space == sim.observation_space and scaled.action_space == sim.action_space
    np.testing.assert_allclose(scaled.workspace, ((0.3, -0.3, 0.1), (0.7, 0.3, 0.6)))
    obs = np.zeros(15)
    obs[0:3] = (0.5, 0.0, 0.4)
    step = scaled.predict_next(obs, np.array([0.05, 0.0, 0.0]))[0] - 0.5
    assert 0.0 < step <= 0.03 + 1e-12  # the arm moves at most robot.max_step_m


def _stack_configs() -> list[Path]:
    """Every YAML in configs/ that describes a stack (the training-run files have ``env:`` instead)."""
    return sorted(p for p in CONFIGS.glob("*.yaml") if "env" not in yaml.safe_load(p.read_text()))


def test_every_shipped_stack_config_loads(tmp_path, monkeypatch):
    paths = _stack_configs()
    assert {"sim.yaml", "franka_sim.yaml", "franka_realsense.yaml", "multi_machine_tls.yaml"} <= {
        p.name for p in paths
    }
    # multi_machine_tls.yaml names its certificates (certs/test, gitignored): load it where they exist
    script = CONFIGS.parent / "scripts" / "make_test_certs.sh"
    subprocess.run([str(script), str(tmp_path / "certs" / "test")], check=True, capture_output=True)
    for path in paths:
        with monkeypatch.context() as patch:
            if "tls" in (compose_stack_yaml(path)["zenoh"] or {}):
                patch.chdir(tmp_path)
            cfg = load_stack_config(path)
        assert cfg.monitor is not None, path
        if cfg.fleet is not None:  # simulated arms without cameras (a rendered camera each is too much CPU)
            assert cfg.vision is None and cfg.robot.simulated, path
            continue
        # every shipped stack, the rehearsal on franky-sim included, sees its target through vision
        assert cfg.vision is not None and cfg.learner.target_topic == "target", path


def test_every_algo_has_its_agent_section():
    assert sorted(AGENT_CONFIGS) == sorted(ALGOS)


def test_the_stack_learns_with_the_task_agent_it_names(tmp_path):
    """``learner.agent_from``: the task config's agent, with this file's ``learner.agent`` laid over it key
    by key; ``base``: a whole config laid over another. A key tuned in the task file reaches the stack."""
    (tmp_path / "task.yaml").write_text(
        yaml.safe_dump({"env": "NSReach-v0", "agent": {"gamma": 0.7, "h_max": 30}})
    )
    (tmp_path / "base.yaml").write_text(
        yaml.safe_dump({"name": "basebot", "learner": {"agent_from": "task.yaml", "agent": {"h_max": 40}}})
    )
    (tmp_path / "site.yaml").write_text(yaml.safe_dump({"base": "base.yaml", "name": "sitebot"}))
    cfg = load_stack_config(tmp_path / "site.yaml")
    assert cfg.name == "sitebot" and cfg.learner.agent == {"gamma": 0.7, "h_max": 40}
    shipped = compose_stack_yaml(SIM)["learner"]["agent"]
    reach = yaml.safe_load((CONFIGS / "reach.yaml").read_text())["agent"]
    assert shipped["gamma"] == reach["gamma"] and shipped["policy_budget"] == reach["policy_budget"]
    tls = compose_stack_yaml(CONFIGS / "multi_machine_tls.yaml")
    assert tls["learner"] == compose_stack_yaml(SIM)["learner"] and tls["zenoh"]["mode"] == "client"


@pytest.mark.parametrize(
    "files, complaint",
    [
        ({"c.yaml": {"base": "gone.yaml"}}, r"c.yaml: base: .*gone.yaml: no such config file"),
        ({"c.yaml": {"base": "d.yaml"}, "d.yaml": {"base": "c.yaml"}}, r"base: c.yaml includes itself"),
        ({"c.yaml": {"learner": {"agent_from": "gone.yaml"}}}, r"learner.agent_from: .*no such config file"),
        ({"c.yaml": {"learner": {"agent_from": "t.yaml"}}, "t.yaml": {"env": "x"}}, r"t.yaml has no agent"),
        ({"c.yaml": {"learner": {"agent_from": "t.yaml"}}, "t.yaml": {"agent": {"gama": 1}}}, r"gama"),
    ],
)
def test_a_broken_overlay_names_its_key(tmp_path, files, complaint):
    for name, data in files.items():
        (tmp_path / name).write_text(yaml.safe_dump(data))
    with pytest.raises(ConfigError, match=complaint):
        load_stack_config(tmp_path / "c.yaml")


def test_config_show_prints_the_merged_config_or_names_the_bad_key(tmp_path):
    show = [sys.executable, "-m", "deploy.cli", "config", "show"]
    out = subprocess.run([*show, str(SIM)], capture_output=True, text=True, timeout=60)
    assert out.returncode == 0, out.stderr
    assert yaml.safe_load(out.stdout) == compose_stack_yaml(SIM)
    bad = _with(tmp_path, "robot", "watchdog_timeout_s", -1)
    out = subprocess.run([*show, str(bad)], capture_output=True, text=True, timeout=60)
    assert out.returncode == 2 and "robot.watchdog_timeout_s" in out.stderr


def test_the_plan_model_tracks_as_the_configured_arm_does():
    """``robot.tracking`` (an arm's measured tracking) is what the stack's plan model predicts with; the
    mock's constants where none is given."""
    from deploy.zenoh_env import ReachSpec, env_settings
    from tasks.reach import TRACKING, ArmTracking, predict_reach

    obs, step = np.zeros(15), np.array([0.0, 0.04, 0.0])
    obs[0:3] = (0.4, 0.0, 0.4)
    franky = ReachSpec(env_settings(load_stack_config("configs/franka_sim.yaml")))
    mock = ReachSpec(env_settings(load_stack_config("configs/sim.yaml")))
    measured = ArmTracking(1.5, 0.0075, 0.535)
    assert franky.settings.tracking == measured and mock.settings.tracking == TRACKING
    np.testing.assert_allclose(
        franky.predict_next(obs, step), predict_reach(obs, step, 0.05, tracking=measured)
    )
    assert franky.predict_next(obs, step)[1] < mock.predict_next(obs, step)[1]  # franky-sim's command lags


@pytest.mark.parametrize("config", ["configs/franka_sim.yaml", "configs/franka_realsense.yaml"])
def test_a_franka_without_its_own_tracking_is_refused_naming_the_key(tmp_path, config):
    """The plan model would otherwise predict a Franka with the mock's tracking (it lags nothing alike)."""
    data = compose_stack_yaml(config)
    data["robot"].pop("tracking")
    with pytest.raises(ConfigError, match=r"robot\.tracking: not set.*bench/reach_model\.py"):
        load_stack_config(_write(tmp_path, yaml.safe_dump(data)))


@pytest.mark.parametrize(
    "change, complaint",
    [
        (
            lambda c: c["fleet"]["arms"].append({"name": "arm0", "seed": 5}),
            r"must differ: \['arm0'\]",
        ),
        (lambda c: c["fleet"]["arms"].append({"name": "state", "seed": 5}), "'state' is a topic's key part"),
        (lambda c: c["fleet"]["arms"].append({"name": "a/b", "seed": 5}), r"fleet\.arms\.2\.name"),
        (lambda c: c["fleet"].update(arms=[]), "at least 1 item"),
        (lambda c: c["learner"].update(execution="closed_loop"), "needs learner.execution actor"),
        (lambda c: c["learner"]["agent"].update(critic_lambda=0.5), r"learner\.agent\.critic_lambda > 0"),
    ],
)
def test_a_fleet_that_cannot_run_is_refused_naming_why(tmp_path, change, complaint):
    """Two arms of one name would share keys, an arm named like a topic would make keys read two ways, a
    learner that drives one arm cannot pool, and one eligibility trace cannot span interleaved arms."""
    data = compose_stack_yaml("configs/fleet.yaml")
    data.pop("base", None)
    change(data)
    with pytest.raises(ConfigError, match=complaint):
        load_stack_config(_write(tmp_path, yaml.safe_dump(data)))


def test_a_fleet_part_names_its_arm_and_takes_its_seed():
    cfg = load_stack_config("configs/fleet.yaml")
    arm = cfg.for_arm("arm1")
    assert (arm.bus_key, arm.robot.seed, arm.learner.seed) == (f"{cfg.name}/arm1", 1, 1)
    with pytest.raises(ConfigError, match="say which with --arm"):
        cfg.for_arm(None)
    with pytest.raises(ConfigError, match="no arm 'arm9'"):
        cfg.for_arm("arm9")
    with pytest.raises(ConfigError, match="no fleet section"):
        load_stack_config("configs/sim.yaml").for_arm("arm0")
