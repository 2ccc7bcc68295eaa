"""The Zenoh reach env sees the task as NSReach-v0 does: same observation layout and the same state
scaling for the learner (a mismatch here once kept the stack from learning what NS Reach learns)."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
import yaml
from loopback import unique_name

from bus.transport import Bus, ZenohConfig, open_session
from deploy.config import compose_stack_yaml, load_stack_config
from deploy.zenoh_env import ZenohReachEnv, env_settings
from tasks.reach_env import NSReachEnv


def test_sim_yaml_env_scales_states_like_the_in_process_env(endpoint):
    cfg = compose_stack_yaml("configs/sim.yaml")
    settings = load_stack_config("configs/sim.yaml")
    bus = Bus(open_session(ZenohConfig(listen=(endpoint,))), unique_name("z"))
    inproc = NSReachEnv(motion=cfg["robot"]["target_motion"], seed=0)
    try:
        env = ZenohReachEnv(bus, env_settings(settings))
        for ours, theirs in zip(env.obs_bounds, inproc.obs_bounds, strict=True):
            np.testing.assert_allclose(ours, theirs)
        np.testing.assert_allclose(env.observation_space.low, inproc.observation_space.low)
        np.testing.assert_allclose(env.observation_space.high, inproc.observation_space.high)
        assert env.action_space == inproc.action_space
    finally:
        inproc.close()
        bus.close()


@pytest.mark.parametrize("chunk_len", [1, 10])
def test_a_diagonal_action_is_sent_no_longer_than_robot_io_accepts(endpoint, chunk_len):
    """The action is clipped per axis; robot-io refuses a step longer than robot.max_step_m, so every step
    of the chunk, the first too, is capped in length (a chunk of one once went out uncapped)."""
    settings = env_settings(load_stack_config("configs/sim.yaml"))
    settings = dataclasses.replace(settings, chunk_len=chunk_len)
    bus = Bus(open_session(ZenohConfig(listen=(endpoint,))), unique_name("z"))
    try:
        env = ZenohReachEnv(bus, settings)
        step = settings.max_step_m
        chunk = env._chunk(np.zeros(env.observation_space.shape), np.full(3, step))
        assert chunk.shape == (chunk_len, 3)
        assert np.linalg.norm(chunk, axis=1).max() <= step * (1 + 1e-12)
        np.testing.assert_allclose(chunk[0], np.full(3, step / np.sqrt(3)))
    finally:
        bus.close()


def test_target_box_is_validated(tmp_path):
    cfg = compose_stack_yaml("configs/sim.yaml")
    cfg["learner"]["target_box"] = [[0.6, 0.0, 0.1], [0.4, 0.3, 0.5]]
    path = tmp_path / "c.yaml"
    path.write_text(yaml.safe_dump(cfg))
    with pytest.raises(Exception, match="learner.target_box: .*must be below hi"):
        load_stack_config(path)


def test_a_lost_target_is_waited_for_not_guessed(endpoint):
    """The closed loop acts only on a fresh valid fix: a 'lost' report (or silence past
    ``target_timeout_s``) blocks the next step until vision reports the target again."""
    import threading
    import time

    from bus import messages as m

    name = unique_name("tw")
    bus = Bus(open_session(ZenohConfig(listen=(endpoint,))), name)
    vision = Bus(open_session(ZenohConfig(connect=(endpoint,))), name)
    try:
        env = ZenohReachEnv(bus, env_settings(load_stack_config("configs/sim.yaml")))
        pub = vision.publisher(m.TARGET)
        time.sleep(0.5)

        def report(valid: bool) -> None:
            status = m.Target.TRACKING if valid else m.Target.LOST
            pub.put(
                m.Target(
                    position=[0.5, 0.0, 0.3],
                    velocity=[0.0] * 3,
                    covariance=[0.0] * 9,
                    valid=valid,
                    frame_stamp=time.time(),
                    status=status,
                )
            )

        report(True)
        assert env.link.wait(env.link.target_fresh, 3.0)
        env.link.await_target()  # fresh: returns at once
        assert env.link.target_waits == 0
        report(False)
        assert env.link.wait(lambda: env.link.target_lost, 3.0)
        done = threading.Event()
        waiter = threading.Thread(target=lambda: (env.link.await_target(), done.set()), daemon=True)
        waiter.start()
        assert not done.wait(1.5)  # lost: the learner waits
        report(True)
        assert done.wait(5.0) and env.link.target_waits == 1
        time.sleep(0.6)  # no report for longer than target_timeout_s: stale, not guessed
        assert not env.link.target_fresh()
    finally:
        vision.close()
        bus.close()
