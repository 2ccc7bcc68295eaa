import numpy as np

from robot_io.config import WorkspaceBox
from robot_io.safety import ESTOP, HELD, PAUSED, RUNNING, Safety


def make() -> Safety:
    return Safety(WorkspaceBox(lo=(0.2, -0.4, 0.05), hi=(0.8, 0.4, 0.7)), watchdog_timeout_s=0.5)


def kinds(s: Safety) -> list[str]:
    return [e.kind for e in s.drain()]


def test_watchdog_holds_only_after_timeout_with_empty_queue_and_fresh_command_clears():
    s = make()
    assert not s.check_watchdog(100.0, queue_empty=True)  # no command yet: nothing to watch
    s.command_received(100.0)
    assert not s.check_watchdog(100.4, queue_empty=True)
    assert not s.check_watchdog(101.0, queue_empty=False)  # still playing a chunk
    assert s.check_watchdog(100.6, queue_empty=True)
    assert s.mode == HELD and kinds(s) == ["watchdog"]
    s.command_received(101.0)
    assert s.mode == RUNNING and kinds(s) == ["release"]


def test_estop_needs_release_and_resume_does_not_clear_it():
    s = make()
    s.estop()
    s.pause()
    assert s.mode == ESTOP
    s.resume()
    assert s.mode == ESTOP and not s.may_move
    s.release()
    assert s.mode == RUNNING
    assert kinds(s) == ["estop", "pause", "release", "release"]


def test_liveliness_hold_survives_release_until_the_peer_is_back():
    s = make()
    s.hold("liveliness", "learner gone")
    s.pause()
    assert s.mode == PAUSED
    s.release()
    assert s.mode == HELD
    s.clear("liveliness", "learner back")
    assert s.mode == RUNNING


def test_workspace_clip_and_one_event_per_excursion():
    s = make()
    np.testing.assert_allclose(s.clip_goal(np.array([1.0, 0.0, 0.3])), [0.8, 0.0, 0.3])
    s.clip_goal(np.array([1.1, 0.0, 0.3]))
    s.clip_goal(np.array([0.5, 0.0, 0.3]))
    s.clip_goal(np.array([0.5, 0.0, 0.0]))
    assert kinds(s) == ["workspace", "workspace"]


def test_watchdog_does_not_stack_on_other_holds_and_restarts_after_release():
    s = make()
    s.command_received(10.0)
    s.hold("liveliness", "learner gone")
    assert not s.accepts_commands()
    assert not s.check_watchdog(20.0, queue_empty=True)
    s.clear("liveliness", "learner back")
    assert s.mode == RUNNING and not s.check_watchdog(20.1, queue_empty=True)
