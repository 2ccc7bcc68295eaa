"""The controller on the PyBullet mock: workspace box, command checks, holds, unreachable goals."""

import numpy as np
import pytest

from robot_io.config import RobotConfig
from robot_io.ik import BOX_INSET_M


def kinds(result) -> list[str]:
    return [e.kind for e in result.events]


def check(controller, q_cmd, q_now):
    """The controller's own command check, from ``q_now`` to ``q_cmd``."""
    cfg = controller.config
    return controller.kin.check(
        q_cmd, q_now, cfg.period, cfg.joint_margin_rad, cfg.velocity_scale, controller.box
    )


def test_end_effector_stays_in_the_workspace_box(controller):
    lo, hi = np.array(controller.config.workspace.lo), np.array(controller.config.workspace.hi)
    seen = []
    for _ in range(60):  # push down and out, hard
        r = controller.step_action(np.array([0.05, 0.05, -0.05]))
        seen += kinds(r)
        assert np.all(r.state.ee_pos > lo - 2e-3) and np.all(r.state.ee_pos < hi + 2e-3)
    assert "workspace" in seen
    assert abs(r.state.ee_pos[2] - lo[2]) < BOX_INSET_M + 2e-3  # as far as the IK allows, no further


def test_command_check_refuses_limits_and_speed(controller):
    q = np.array(controller.config.home_q)
    assert check(controller, q, q).ok
    beyond = q.copy()
    beyond[3] = controller.kin.upper[3] + 0.01
    assert check(controller, beyond, q).kind == "joint_limit"
    fast = q.copy()
    fast[0] += 0.5  # 10 rad/s at 20 Hz
    assert check(controller, fast, q).kind == "velocity_limit"
    edge, out, further = q.copy(), q.copy(), q.copy()
    edge[0], out[0], further[0] = 0.85, 0.9, 0.95  # the hand swings sideways past the box's x = 0.2 wall
    assert check(controller, out, edge).kind == "workspace"
    assert check(controller, further, out).kind == "workspace"
    # Already outside: coming back, or holding there, is allowed.
    assert check(controller, out, further).ok and check(controller, out, out).ok
    nan = q.copy()
    nan[2] = np.nan
    assert check(controller, nan, q).kind == "not_finite" and check(controller, q, nan).kind == "not_finite"


def test_a_joint_beyond_its_margin_may_come_back_but_not_go_further(controller):
    kin, cfg = controller.kin, controller.config
    q = np.array(cfg.home_q)
    q[3] = kin.lower[3] + cfg.joint_margin_rad - 1e-5  # an arm held at the limit sags this far past it
    back, further = q.copy(), q.copy()
    back[3] += 2e-5
    further[3] -= 1e-5
    assert check(controller, back, q).ok and check(controller, q, q).ok
    assert check(controller, further, q).kind == "joint_limit"


def test_an_arm_pushed_down_onto_a_joint_limit_comes_back_up(controller):
    """Straight down from home the elbow (joint 4) reaches its limit as the hand reaches the table: the
    arm stops there, and the first command up moves it (it once sagged 1e-5 rad past the margin, the IK
    only ever took 95 % of that back, and every command was refused until the next reset)."""
    for _ in range(50):
        r = controller.step_action(np.array([0.0, 0.0, -0.05]))
    low = r.state.ee_pos[2]
    events = []
    for _ in range(10):
        r = controller.step_action(np.array([0.0, 0.0, 0.05]))
        events += [e.detail for e in r.events]
    assert r.state.ee_pos[2] > low + 0.1, (low, r.state.ee_pos)
    assert not [d for d in events if "refused" in d], events


def test_an_arm_pushed_into_a_wall_slides_along_it(controller):
    """Pushed down, back and left at once, the hand reaches the x = 0.2 wall and slides down along it to
    the corner: no command is refused (the IK knows the box; it once left it by a millimetre at the
    wall, and the arm froze there as long as the push lasted)."""
    push = np.array([-1.0, -1.0, -1.0]) / np.sqrt(3) * 0.05
    events, path = [], []
    for _ in range(40):
        r = controller.step_action(push)
        events += [e.detail for e in r.events]
        path.append(r.state.ee_pos)
    assert not [d for d in events if "refused" in d], events
    lo = controller.box[0]
    assert np.all(np.array(path) > lo - 1e-4)
    assert path[-1][0] < lo[0] + 0.01 and path[-1][2] < 0.15, path[-1]  # at the wall, far down it


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
