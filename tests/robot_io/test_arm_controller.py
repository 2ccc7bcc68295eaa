"""The controller on the PyBullet mock: workspace box, command checks, holds, unreachable goals."""

import numpy as np
import pytest

from robot_io.config import RobotConfig


def kinds(result) -> list[str]:
    return [e.kind for e in result.events]


def test_end_effector_stays_in_the_workspace_box(controller):
    lo, hi = np.array(controller.config.workspace.lo), np.array(controller.config.workspace.hi)
    seen = []
    for _ in range(60):  # push down and out, hard
        r = controller.step_action(np.array([0.05, 0.05, -0.05]))
        seen += kinds(r)
        assert np.all(r.state.ee_pos > lo - 2e-3) and np.all(r.state.ee_pos < hi + 2e-3)
    assert "workspace" in seen
    assert abs(r.state.ee_pos[2] - lo[2]) < 5e-3  # it went as far as allowed, no further


def test_command_check_refuses_limits_and_speed(controller):
    kin, cfg = controller.kin, controller.config
    q = np.array(cfg.home_q)
    box = controller.box
    ok = kin.check(q, q, cfg.period, cfg.joint_margin_rad, cfg.velocity_scale, box)
    assert ok.ok
    beyond = q.copy()
    beyond[3] = kin.upper[3] + 0.01
    assert (
        kin.check(beyond, q, cfg.period, cfg.joint_margin_rad, cfg.velocity_scale, box).kind == "joint_limit"
    )
    fast = q.copy()
    fast[0] += 0.5  # 10 rad/s at 20 Hz
    assert (
        kin.check(fast, q, cfg.period, cfg.joint_margin_rad, cfg.velocity_scale, box).kind == "velocity_limit"
    )
    behind = q.copy()
    behind[0] = 2.5  # swings the hand behind the base, out of the box
    assert (
        kin.check(behind, behind, cfg.period, cfg.joint_margin_rad, cfg.velocity_scale, box).kind
        == "workspace"
    )


def test_estop_brakes_within_two_control_periods(controller):
    for _ in range(5):
        r = controller.step_action(np.array([0.05, 0.0, -0.03]))
    assert np.abs(r.state.dq).max() > 0.2
    controller.queue.push(1, np.tile([0.05, 0.0, -0.03], (20, 1)))
    controller.operator("estop")
    speeds = [np.abs(controller.tick(100.0 + k * controller.config.period).state.dq).max() for k in range(2)]
    assert speeds[-1] < 0.01, speeds
    q = controller.state().q
    for k in range(10):
        r = controller.tick(101.0 + k)
    assert r.state.mode == "estop" and len(controller.queue) == 0
    np.testing.assert_allclose(r.state.q, q, atol=2e-3)


def test_unreachable_goal_is_an_event_not_an_exception():
    from robot_io.config import WorkspaceBox
    from tasks.sim_world import robot_controller

    c = robot_controller(
        RobotConfig(target_motion="static", workspace=WorkspaceBox(lo=(-2, -2, -1), hi=(2, 2, 2)))
    )
    try:
        events = []
        for _ in range(80):
            r = c.step_action(np.array([0.05, 0.0, 0.0]))  # keep pushing along +x, beyond reach
            events += kinds(r)
        assert events.count("ik_unreachable") >= 1
        kin = c.kin
        q = r.state.q
        assert np.all(q >= kin.lower) and np.all(q <= kin.upper)
        assert r.state.ee_pos[0] > 0.75  # stretched out towards the goal
    finally:
        c.close()


def test_an_estop_during_a_tick_brakes_that_tick(controller):
    """The operator's e-stop lands while a tick computes its command (after it took the action, before
    physics): that tick brakes and counts the action as not played."""
    controller.obey("s")
    controller.reset()
    controller.push_chunk("s", 0, np.tile([0.0, -0.04, 0.0], (40, 1)), 10.0)
    for k in range(4):
        r = controller.tick(10.0 + k * controller.config.period)
    assert np.abs(r.state.dq).max() > 0.2
    send = controller.backend.send_joint_command

    def estop_then_send(q):  # the Zenoh thread's e-stop, between the take and the command
        controller.operator("estop")
        send(q)

    controller.backend.send_joint_command = estop_then_send
    r = controller.tick(11.0)
    assert r.state.mode == "estop" and r.state.played_chunk == -1 and r.applied is None
    assert np.abs(controller.tick(11.05).state.dq).max() < 0.01


def test_a_reset_waits_for_the_operator_to_release(controller):
    """Homing is a motion: refused while e-stopped (on a real arm it drives the arm home), done after."""
    from robot_io.controller import ArmHeld

    controller.operator("estop")
    controller.tick(1.0)
    q = controller.state().q
    with pytest.raises(ArmHeld, match="estop"):
        controller.reset()
    np.testing.assert_allclose(controller.state().q, q)
    controller.operator("release")
    controller.tick(1.05)
    controller.reset()
    np.testing.assert_allclose(controller.state().q, controller.home, atol=1e-3)
