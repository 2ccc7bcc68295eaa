import pytest

from common.config import ConfigError, parse
from robot_io.config import RobotConfig


@pytest.mark.parametrize(
    ("data", "needle"),
    [
        ({"backend": "ur5"}, "backend"),
        ({"max_step_m": 0.2}, "max_step_m"),
        ({"watchdog_timeout_s": 0}, "watchdog_timeout_s"),
        ({"target_motion": "warp"}, "target_motion"),
        ({"workspace": {"lo": [0, 0, 1], "hi": [1, 1, 0.5]}}, "workspace"),
        ({"franka": {"realtime": "sometimes"}}, "franka.realtime"),
        ({"home_q": [0, 0]}, "home_q"),
        ({"ik": {"iterations": 0}}, "ik.iterations"),
        ({"colour": "red"}, "unknown key"),
    ],
)
def test_bad_values_fail_with_the_key_named(data, needle):
    with pytest.raises(ConfigError, match=needle):
        parse(RobotConfig, data, "robot")


def test_defaults_and_nested_sections_build():
    cfg = parse(RobotConfig, {"workspace": {"lo": [0.3, -0.3, 0.1]}, "ik": {"posture_cost": 0.01}}, "robot")
    assert cfg.workspace.lo == (0.3, -0.3, 0.1) and cfg.ik.posture_cost == 0.01
    assert cfg.period == pytest.approx(0.05)
