"""The pylibfranka adapter against a fake at pylibfranka's own API boundary."""

import time

import numpy as np
import pytest

from robot_io.backends.franka_backend import FrankaBackend, interpolate
from robot_io.config import FrankaConfig, RobotConfig

CFG = RobotConfig(backend="franka", franka=FrankaConfig(ip="10.0.0.2", recover_attempts=2))


@pytest.fixture
def backend(fake_franka):
    b = FrankaBackend(CFG, lib=fake_franka)
    yield b
    b.close()


def wait_until(pred, timeout=5.0):
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        if pred():
            return True
        time.sleep(0.005)
    return False


def test_connect_sets_collision_behaviour_and_impedance(backend):
    robot = backend.robot
    assert robot.ip == "10.0.0.2"
    assert robot.realtime_config.name == "kIgnore"
    assert robot.collision_behavior == ([20.0] * 7, [40.0] * 7, [10.0] * 6, [20.0] * 6)
    assert robot.joint_impedance == list(CFG.franka.joint_impedance)
    assert "start_joint_position_control:JointImpedance" in robot.calls
    assert wait_until(lambda: robot.writes > 20)  # the 1 kHz loop is running


def test_tracks_a_joint_target_without_tripping_libfranka_limits(backend):
    q0 = backend.read_state().q
    target = q0 + np.array([0.1, -0.1, 0.05, 0.1, -0.05, 0.1, 0.2])
    backend.send_joint_command(target)
    assert wait_until(lambda: np.max(np.abs(backend.read_state().q - target)) < 1e-4, timeout=10)
    assert backend.fault() is None and backend.robot.errors == []


def test_hold_decelerates_to_rest_within_limits(backend):
    q0 = backend.read_state().q
    backend.send_joint_command(q0 + 1.0)
    assert wait_until(lambda: np.max(np.abs(backend.read_state().dq)) > 0.3)
    backend.hold()
    assert wait_until(lambda: np.max(np.abs(backend.read_state().dq)) < 1e-6, timeout=3)
    q_stop = backend.read_state().q
    assert np.max(np.abs(q_stop - (q0 + 1.0))) > 0.1  # it stopped short of the old target
    time.sleep(0.05)
    np.testing.assert_allclose(backend.read_state().q, q_stop, atol=1e-9)
    assert backend.fault() is None


def test_reflex_is_reported_and_recovered(backend):
    backend.robot.inject_reflex()
    assert wait_until(lambda: backend.fault() is not None)
    assert "cartesian_reflex" in backend.fault()
    assert backend.recover()
    assert "automatic_error_recovery" in backend.robot.calls
    assert backend.fault() is None
    target = backend.read_state().q + 0.05
    backend.send_joint_command(target)
    assert wait_until(lambda: np.max(np.abs(backend.read_state().q - target)) < 1e-4)


def test_reset_goes_home(backend):
    home = np.array(CFG.home_q)
    backend.send_joint_command(home + 0.2)
    backend.reset(home, seed=None)
    np.testing.assert_allclose(backend.read_state().q, home, atol=1e-3)


def test_close_stops_the_loop_and_the_robot(fake_franka):
    b = FrankaBackend(CFG, lib=fake_franka)
    wait_until(lambda: b.robot.writes > 5)
    b.close()
    assert "stop" in b.robot.calls and not b.robot.control_active
    n = b.robot.writes
    time.sleep(0.02)
    assert b.robot.writes == n


def test_interpolator_respects_velocity_and_acceleration():
    vmax, amax = np.full(7, 1.0), np.full(7, 4.0)
    q, v = np.zeros(7), np.zeros(7)
    qs = []
    for _ in range(3000):
        q, v = interpolate(q, v, np.full(7, 1.0), 0.001, vmax, amax)
        qs.append(q.copy())
    qs = np.array(qs)
    vel = np.diff(qs, axis=0) / 0.001
    acc = np.diff(vel, axis=0) / 0.001
    assert np.abs(vel).max() <= 1.0 + 1e-9 and np.abs(acc).max() <= 4.0 + 1e-6
    np.testing.assert_allclose(qs[-1], 1.0, atol=1e-6)
