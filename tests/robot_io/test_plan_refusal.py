"""A bad plan is refused whole: nothing of it plays, the arm holds where it is, the chunk number, the
safety mode and the watchdog do not change, and the next valid plan plays at once."""

import numpy as np
import pytest

from robot_io.action_queue import ChunkReport
from robot_io.config import RobotConfig
from robot_io.controller import RobotController
from robot_io.step_cap import cap_step_length

UP_Y = [0.0, 0.01, 0.0]
SESSION = "the-learner"  # the one session the controller obeys here (robot_io.command_gate)


def run(controller: RobotController, n: int, t0: float = 10.0):
    """``n`` ticks, 1 ms apart (the watchdog never fires); the results."""
    return [controller.tick(t0 + 0.001 * k) for k in range(n)]


def bad_plans(cfg: RobotConfig) -> dict[str, np.ndarray]:
    big = np.tile(UP_Y, (5, 1))
    big[3] = [0.04, 0.04, 0.0]  # 5.7 cm: inside the per-axis box, above max_step_m in norm
    nan = np.tile(UP_Y, (5, 1))
    nan[2, 0] = np.nan
    return {
        "step 3 moves 0.0566 m, above robot.max_step_m": big,
        "no actions": np.zeros((0, 3)),
        "more than robot.max_plan_actions": np.tile(UP_Y, (cfg.max_plan_actions + 1, 1)),
        "NaN or inf": nan,
    }


@pytest.mark.parametrize("why", list(bad_plans(RobotConfig())))
def test_bad_plan_is_refused_whole_and_the_arm_holds(controller, why):
    controller.obey(SESSION)
    controller.reset()
    assert controller.push_chunk(SESSION, 1, np.tile(UP_Y, (20, 1)), 10.0) == "accepted"
    run(controller, 4)
    controller.queue.reports()
    plan = bad_plans(controller.config)[why]
    assert controller.push_chunk(SESSION, 2, plan, 10.01) == "bad_plan"
    after = run(controller, 12, 10.02)
    events = [e for r in after for e in r.events]
    assert [e.kind for e in events] == ["bad_plan"]
    detail = events[0].detail
    assert "chunk 2" in detail and why in detail, detail
    # Nothing of it played and the rest of the old plan was dropped, not replaced: the arm holds.
    assert [r.reports for r in after][0] == [
        ChunkReport(1, 4, 16, preempted_by=-1, done=True, session=SESSION)
    ]
    assert all(r.state.played_chunk == -1 and r.applied is None for r in after)
    assert all(r.state.mode == "running" and r.state.chunk_seq == 1 for r in after)  # nothing else changed
    ee = np.array([r.state.ee_pos for r in after[4:]])
    assert np.ptp(ee, axis=0).max() < 1e-3  # m: stands where it stopped
    # The refused chunk's number was not consumed: a valid plan with it plays at once, from index 0.
    assert controller.push_chunk(SESSION, 2, np.tile([0.0, -0.01, 0.0], (3, 1)), 10.05) == "accepted"
    r = controller.tick(10.06)
    assert (r.state.played_chunk, r.state.played_index) == (2, 0)
    np.testing.assert_allclose(r.applied, [0.0, -0.01, 0.0])


def test_a_step_capped_by_the_sender_is_accepted(controller):
    controller.obey(SESSION)
    controller.reset()
    plan = cap_step_length(np.array([[0.05, 0.05, 0.05], [0.0, 0.0, -0.05]]), controller.config.max_step_m)
    assert np.linalg.norm(plan, axis=1).max() == pytest.approx(controller.config.max_step_m)
    assert controller.push_chunk(SESSION, 1, plan, 10.0) == "accepted"
    played = [(r.state.played_chunk, r.state.played_index) for r in run(controller, 3)]
    assert played == [(1, 0), (1, 1), (-1, -1)]


def test_ticks_are_numbered_and_name_what_they_played(controller):
    controller.obey(SESSION)
    controller.reset()
    t0 = controller.state().tick
    controller.push_chunk(SESSION, 7, np.tile(UP_Y, (2, 1)), 10.0)
    states = [r.state for r in run(controller, 3)]
    assert [s.tick for s in states] == [t0 + 1, t0 + 2, t0 + 3]
    played = [(s.played_chunk, s.played_index, s.queue_len) for s in states]
    assert played == [(7, 0, 1), (7, 1, 0), (-1, -1, 0)]
    assert controller.react(10.1).state.tick == t0 + 3  # a state between ticks repeats the tick


def test_a_reset_counts_as_a_command_so_a_quiet_commander_leaves_the_arm_held(controller):
    """After homing, no chunk within the watchdog timeout holds the arm (the commander may be waiting
    for a target it lost); the first chunk releases it. Without the control clock, nothing is armed."""
    controller.obey(SESSION)
    now = [50.0]
    controller.reset(clock=lambda: now[0])
    timeout = controller.safety.watchdog_timeout_s
    assert controller.tick(50.0 + 0.5 * timeout).state.mode == "running"
    assert controller.tick(50.0 + 1.5 * timeout).state.mode == "held"
    assert controller.push_chunk(SESSION, 1, np.tile(UP_Y, (3, 1)), 60.0) == "accepted"
    assert controller.tick(60.01).state.mode == "running"
    controller.reset()
    assert controller.tick(70.0).state.mode == "running"  # no clock: the watchdog waits for a chunk
