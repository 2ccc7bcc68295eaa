"""The small version of ``bench/learn_check.py``: the default AdaptiveH learns stationary continuous
CartPole (10-episode mean-action evaluation >= 400) within 10k steps and still holds it at 10k."""

import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[2] / "bench"))
from learn_check import BAR, check_seed  # noqa: E402


def test_default_adaptiveh_learns_and_keeps_cartpole():
    result = check_seed((0, 10_000, 5_000))
    assert result["reached"] and result["steps_to_400"] <= 10_000, result["curve"]
    assert result["final_evaluation"] >= BAR, result["curve"]
