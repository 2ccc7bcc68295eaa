"""The mock arm's own dynamics for the reality-gap overlays (``robot.mock``): a delayed actuation and a
softer servo, each on the real controller and PyBullet scene."""

from __future__ import annotations

import numpy as np

from robot_io.backends.pybullet_config import MockArmConfig
from robot_io.config import RobotConfig
from tasks.sim_world import robot_controller


def _moved_per_tick(mock: MockArmConfig, ticks: int = 6) -> tuple[list[float], list]:
    """How far the hand moves along y each tick under a constant 2 cm step; the states' ee_cmd gaps."""
    ctl = robot_controller(RobotConfig(mock=mock))
    ctl.obey("test")
    state = ctl.reset(seed=0)
    moved, leads = [], []
    for _ in range(ticks):
        tick = ctl.step_action(np.array([0.0, 0.02, 0.0]))
        moved.append(float(tick.state.ee_pos[1] - state.ee_pos[1]))
        leads.append(float(tick.state.ee_cmd[1] - tick.state.ee_pos[1]))
        state = tick.state
    ctl.close()
    return moved, leads


def test_a_delayed_command_moves_the_arm_later_and_the_arm_says_where_it_is_commanded():
    prompt, prompt_leads = _moved_per_tick(MockArmConfig())
    late, late_leads = _moved_per_tick(MockArmConfig(actuation_delay_ms=60.0))
    assert prompt[0] > 0.015 and late[0] < 0.002  # 60 ms: nothing moves in the first 50 ms period
    assert sum(late) < sum(prompt) - 0.005  # still behind after six
    assert max(abs(x) for x in prompt_leads) == 0.0  # no delay: the command is the measured hand
    assert min(late_leads) > 0.01  # with one, the commanded hand leads the measured one


def test_a_softer_servo_tracks_slower():
    stiff, _ = _moved_per_tick(MockArmConfig())
    soft, _ = _moved_per_tick(MockArmConfig(position_gain=0.1))
    assert soft[0] < 0.8 * stiff[0]
