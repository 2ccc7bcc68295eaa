"""``adaptiveh train``: result.json and curve.png, resume equality, and config errors that name the key."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

from common.config import ConfigError
from deploy.cli import main
from experiments.training import TrainSpec, build_agent, load_spec, make_env, train

REPO = Path(__file__).resolve().parents[2]
PNG_MAGIC = b"\x89PNG\r\n\x1a\n"
SMALL_AGENT = {"policy_budget": 150, "critic_budget": 150}


def _write(path: Path, text: str) -> Path:
    path.write_text(text)
    return path


def test_train_command_writes_result_json_and_curve(tmp_path, capsys):
    out = tmp_path / "run"
    rc = main(
        [
            "train",
            "--env",
            "NSCartPoleContinuous-v0",
            "--algo",
            "adaptiveh",
            "--steps",
            "1500",
            "--seed",
            "0",
            "--out",
            str(out),
        ]
    )
    assert rc == 0
    printed = capsys.readouterr().out
    assert "result.json" in printed and "curve.png" in printed
    result = json.loads((out / "result.json").read_text())
    assert result["global_step"] == 1500
    assert result["spec"]["env"] == "NSCartPoleContinuous-v0" and result["spec"]["algo"] == "adaptiveh"
    # Per-episode returns with the global step at which each ended.
    episodes = result["episodes"]
    assert len(episodes) >= 3
    steps = [e["global_step"] for e in episodes]
    assert steps == sorted(steps) and 0 < steps[0] and steps[-1] <= 1500
    assert all(isinstance(e["ret"], float) and e["length"] >= 1 for e in episodes)
    assert sum(e["length"] for e in episodes) == steps[-1]
    # Every segment's H and why it ended.
    segments = result["segments"]
    assert segments
    assert {s["reason"] for s in segments} <= {"retreat", "h_max", "episode_end"}
    h_max = result["agent_config"]["h_max"]
    assert all(1 <= s["H"] <= h_max for s in segments)
    assert sum(s["H"] for s in segments) <= 1500
    # The inner-product trace summary, timing and throughput.
    stat = result["summary"]["statistic"]
    assert stat["count"] > 0 and {"mean", "p10", "p50", "p90", "threshold"} <= set(stat)
    assert stat["p10"] <= stat["p50"] <= stat["p90"]
    assert result["summary"]["segments"] == len(segments)
    assert result["summary"]["episodes"] == len(episodes)
    assert sum(result["summary"]["reasons"].values()) == len(segments)
    assert result["wall_clock_s"] > 0
    assert result["steps_per_s"] == pytest.approx(1500 / result["wall_clock_s"], rel=1e-6)
    # The learning curve is a real PNG, and a checkpoint was left for a resume.
    png = (out / "curve.png").read_bytes()
    assert png.startswith(PNG_MAGIC) and len(png) > 5000
    assert (out / "checkpoint.pkl").is_file()


def test_train_resume_continues_identically(tmp_path):
    """Train 500 steps, then resume to 900 == train 900 steps in one go (a fresh env and agent load it)."""
    spec = TrainSpec(
        env="NSCartPoleContinuous-v0",
        env_kwargs={"preset": "fast"},
        algo="adaptiveh",
        steps=500,
        seed=2,
        agent=SMALL_AGENT,
        checkpoint_every=10_000,
    )
    first = train(spec, tmp_path / "split", progress=False)
    assert first["global_step"] == 500
    spec = spec.model_copy(update={"steps": 900})
    resumed = train(spec, tmp_path / "split", progress=False)
    assert resumed["steps_this_session"] == 400
    straight = train(spec, tmp_path / "straight", resume=False, progress=False)
    assert straight["steps_this_session"] == 900
    assert resumed["global_step"] == straight["global_step"] == 900
    assert len(straight["episodes"]) > 5
    assert resumed["episodes"] == straight["episodes"]
    assert resumed["segments"] == straight["segments"]
    assert resumed["summary"] == straight["summary"]


def test_unknown_yaml_key_is_a_config_error_naming_it(tmp_path):
    cfg = _write(tmp_path / "c.yaml", "env: NSCartPoleContinuous-v0\nstepz: 100\n")
    with pytest.raises(ConfigError, match="stepz"):
        load_spec(cfg, {})


@pytest.mark.parametrize(
    "text, key",
    [
        ("steps: 0\n", "steps"),
        ("algo: a2c\n", "algo"),
        ("env: NoSuchEnv-v0\n", "env"),
        ("checkpoint_every: 0\n", "checkpoint_every"),
    ],
)
def test_out_of_range_top_level_value_names_its_key(tmp_path, text, key):
    with pytest.raises(ConfigError, match=key):
        load_spec(_write(tmp_path / "c.yaml", text), {})


@pytest.mark.parametrize(
    "text, key",
    [
        ("agent:\n  alpha: -1\n", "alpha"),
        ("agent:\n  gamma: 1.5\n", "gamma"),
        ("agent:\n  h_max: 0\n", "h_max"),
        ("agent:\n  retreat: sometimes\n", "retreat"),
        ("agent:\n  alpah: 0.01\n", "alpah"),  # an unknown key inside the agent section
    ],
)
def test_bad_agent_section_names_its_key(tmp_path, text, key):
    spec = load_spec(_write(tmp_path / "c.yaml", text), {"steps": 10})
    env = make_env(spec)
    with pytest.raises(ConfigError, match=key):
        build_agent(spec, env)


def test_yaml_exponent_without_dot_is_accepted_or_named(tmp_path):
    """PyYAML reads ``1e-3`` (no dot) as the string '1e-3'. Either accept it as 0.001 or name the key;
    a message about comparing 'str' and 'int' does not say which key is wrong."""
    spec = load_spec(_write(tmp_path / "c.yaml", "agent:\n  alpha: 1e-3\n"), {"steps": 10})
    try:
        agent = build_agent(spec, make_env(spec))
    except ConfigError as exc:
        assert "alpha" in str(exc), str(exc)
    else:
        assert agent.config.alpha == pytest.approx(1e-3)


@pytest.mark.parametrize(
    "text, key",
    [
        ("agent:\n  alpha: fast\n", "alpha"),  # a wrong type
        ("agent:\n  bandwidth: [0.4, 0.4]\n", "bandwidth"),  # CartPole has 4 state dimensions
    ],
)
def test_wrong_type_or_shape_in_agent_section_names_its_key(tmp_path, text, key):
    spec = load_spec(_write(tmp_path / "c.yaml", text), {"steps": 10})
    with pytest.raises(ConfigError) as info:
        build_agent(spec, make_env(spec))
    assert key in str(info.value), str(info.value)


def test_cli_config_error_exits_2_in_process(tmp_path, capsys):
    cfg = _write(tmp_path / "c.yaml", "agent:\n  alpha: -1\n")
    rc = main(["train", "--config", str(cfg), "--steps", "10", "--out", str(tmp_path / "o")])
    assert rc == 2
    err = capsys.readouterr().err
    assert "config error" in err and "alpha" in err
    assert not (tmp_path / "o" / "result.json").exists()


def test_cli_config_error_exit_status_of_the_installed_command(tmp_path):
    cfg = _write(tmp_path / "c.yaml", "env: NSCartPoleContinuous-v0\nbogus_key: 1\n")
    proc = subprocess.run(
        [sys.executable, "-m", "deploy.cli", "train", "--config", str(cfg), "--out", str(tmp_path / "o")],
        cwd=REPO,
        capture_output=True,
        text=True,
        timeout=120,
        env={**os.environ, "PYTHONPATH": str(REPO)},
    )
    assert proc.returncode == 2, proc.stderr
    assert "config error" in proc.stderr and "bogus_key" in proc.stderr


@pytest.mark.parametrize("algo", ["sac", "ppo"])
def test_train_runs_sac_and_ppo_with_their_zoo_settings(tmp_path, algo):
    """SAC and PPO are registered like every other learner: ``adaptiveh train --algo sac|ppo`` runs them,
    and their ``agent:`` section is checked against their own settings."""
    out = tmp_path / algo
    assert main(["train", "--env", "NSPendulum-v0", "--algo", algo, "--steps", "300", "--out", str(out)]) == 0
    result = json.loads((out / "result.json").read_text())
    assert result["global_step"] == 300 and result["spec"]["algo"] == algo
    bad = _write(tmp_path / "bad.yaml", f"algo: {algo}\nenv: NSPendulum-v0\nagent: {{noise_std: 0.1}}\n")
    if algo == "ppo":  # a TD3 key is not PPO's: a config error (exit 2), before any training
        assert main(["train", "--config", str(bad), "--steps", "10", "--out", str(tmp_path / "b")]) == 2
