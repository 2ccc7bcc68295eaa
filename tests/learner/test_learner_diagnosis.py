"""``bench/learner_diagnosis.py``'s variants and its paired summaries (the measurements behind the
configs: a variant that does not validate, or a pairing across seeds, would mislead the README)."""

import json
import sys
from pathlib import Path

import pytest

sys.path.insert(0, str(Path(__file__).resolve().parents[2] / "bench"))
from learner_diagnosis import (  # noqa: E402
    PENDULUM_VARIANTS,
    REACH_BASELINE_VARIANTS,
    REACH_VARIANTS,
    _env_cost_summary,
    _reach_baselines_summary,
    _reach_summary,
    _timed,
    _variant_config,
)

from learner.config import AGENT_CONFIGS, AdaptiveHConfig  # noqa: E402


def test_every_variant_is_a_valid_config_of_its_learner():
    for env_key, variants in (("reach_slow", REACH_VARIANTS), ("pendulum_slow", PENDULUM_VARIANTS)):
        for overrides in variants.values():
            AdaptiveHConfig(**_variant_config(env_key, overrides))
    for algo, overrides in REACH_BASELINE_VARIANTS.values():
        AGENT_CONFIGS[algo](**overrides)
    # the variants pin what they change, so the config's own values cannot redefine them
    assert _variant_config("reach_slow", REACH_VARIANTS["scheduled"])["bandwidth"][-1] == 0.5
    assert _variant_config("reach_slow", REACH_VARIANTS["std_to_0.1_relative_bw_0.3"])["sigma_final"] == 0.1


def _paper(tmp_path: Path, finals: dict[str, dict[int, float]]) -> Path:
    runs = {
        f"reach_slow__{m}__s{s}__10000": {"final_return": r}
        for m, rs in finals.items()
        for s, r in rs.items()
    }
    path = tmp_path / "summary.json"
    path.write_text(json.dumps({"per_run": runs}))
    return path


def _run(variant: str, seed: int, final: float) -> dict:
    return {"variant": variant, "seed": seed, "final_return": final, "dictionary": {"policy": 9, "critic": 9}}


def test_reach_variants_pair_with_the_scheduled_learner_and_td3_seed_by_seed(tmp_path):
    # seed 1 is a harder world for everyone: paired, the variant is 0.5 ahead of TD3 on both seeds
    paper = _paper(tmp_path, {"td3": {0: -3.0, 1: -6.0}, "rkhs": {0: 0.0, 1: 0.0}})
    runs = [_run("scheduled", 0, -3.0), _run("scheduled", 1, -6.0)]
    runs += [_run("std_to_0.1", 1, -5.5), _run("std_to_0.1", 0, -2.5)]  # order must not matter
    summary = _reach_summary(runs, paper)
    entry = summary["reach_std_to_0.1"]
    assert entry["minus_td3_paired"]["diff"] == pytest.approx(0.5)
    assert entry["minus_td3_paired"]["lo"] == pytest.approx(0.5) and entry["minus_td3_paired"]["n_a"] == 2
    assert entry["minus_scheduled_paired"]["diff"] == pytest.approx(0.5)
    assert "minus_scheduled_paired" not in summary["reach_scheduled"]
    assert "reach_unscheduled" not in summary  # not run, not reported


def test_reach_baselines_pair_with_the_paper_td3_and_adaptiveh(tmp_path):
    paper = _paper(tmp_path, {"td3": {0: -3.0, 1: -6.0}, "adaptiveh": {0: -3.1, 1: -5.9}})
    runs = [_run("td3_noise_0.1", 0, -3.0), _run("td3_noise_0.1", 1, -6.0)]
    runs += [_run("td3_noise_0.05", 0, -3.2), _run("td3_noise_0.05", 1, -6.2)]
    summary = _reach_baselines_summary(runs, paper)
    assert summary["td3_noise_0.1"]["replays_paper_td3"] is True
    assert summary["td3_noise_0.05"]["replays_paper_td3"] is False
    assert summary["td3_noise_0.05"]["minus_paper_td3_paired"]["diff"] == pytest.approx(-0.2)
    assert summary["td3_noise_0.05"]["paper_adaptiveh_minus_this_paired"]["diff"] == pytest.approx(0.2)


def test_env_cost_names_the_arms_share_and_its_floor_against_td3(tmp_path):
    """The floor any learner faces on NS Reach: the env alone, and the arm's physics and IK inside it;
    a setting without an arm (CartPole) gets no arm entry, and a run recorded before the split none."""
    paper = tmp_path / "summary.json"
    by_env = {"reach_slow": {"wall_s_per_run": 200.0}, "cartpole_slow": {"wall_s_per_run": 300.0}}
    paper.write_text(json.dumps({"cost": {"td3": {"by_env": by_env}}}))
    runs = [
        {"env": "reach_slow", "wall_s": 20.0, "physics_s": 9.0, "ik_s": 4.0},
        {"env": "reach_slow", "wall_s": 22.0, "physics_s": 11.0, "ik_s": 4.0},
        {"env": "cartpole_slow", "wall_s": 1.0, "physics_s": 0.0, "ik_s": 0.0},
        {"env": "cartpole_fast", "wall_s": 1.5},
    ]
    out = _env_cost_summary(runs, paper)
    reach = out["reach_slow"]
    assert reach["env_only_wall_s_per_run"] == 21.0 and reach["arm_physics_ik_s_per_run"] == 14.0
    assert reach["floor_vs_td3"] == 0.105 and reach["arm_floor_vs_td3"] == 0.07
    assert "arm_floor_vs_td3" not in out["cartpole_slow"] and out["cartpole_slow"]["floor_vs_td3"] == 0.003
    assert "arm_physics_ik_s_per_run" not in out["cartpole_fast"]


def test_timed_adds_each_calls_time_keeps_its_result_and_errors_and_restores_it():
    class Owner:
        @staticmethod
        def work(x: int) -> int:
            if x < 0:
                raise ValueError("negative")
            return 2 * x

    original = Owner.work
    spent = {"work_s": 0.0}
    with _timed(Owner, "work", spent, "work_s"):
        assert Owner.work(3) == 6
        with pytest.raises(ValueError, match="negative"):
            Owner.work(-1)
    assert spent["work_s"] > 0.0
    assert Owner.work is original  # restored: a second measurement in the same process wraps it once
