"""Whose chunks the arm obeys (robot_io.command_gate through the controller): one live learner session,
numbered chunks; stale, foreign and implausibly numbered ones are refused with a safety event, and none
of them can stop the genuine learner's next chunks from playing (the wedge of issue #13)."""

import numpy as np
import pytest

from robot_io.action_queue import ChunkReport
from robot_io.command_gate import CommandGate, TakeoverRefused

LEARNER, STRANGER = "a1b2c3d4e5f60718", "ffffffffffffffff"
UP = np.tile([0.0, 0.0, 0.002], (4, 1))


def events(controller, kind: str) -> list[str]:
    return [e.detail for e in controller.tick(10.0).events if e.kind == kind]


def test_no_session_no_motion(controller):
    controller.reset()
    assert controller.push_chunk("", 0, UP, 10.0) == "foreign"
    assert controller.push_chunk(LEARNER, 0, UP, 10.0) == "foreign"  # not taken over yet
    assert controller.tick(10.0).state.played_chunk == -1


def test_takeover_needs_a_live_token(controller):
    with pytest.raises(TakeoverRefused, match="no liveliness token"):
        controller.take_over(LEARNER)  # a replayed reset of a learner that is gone
    with pytest.raises(TakeoverRefused, match="must name its learner session"):
        controller.take_over("")
    refused = events(controller, "foreign_command")
    assert len(refused) == 2 and all(d.startswith("reset refused") for d in refused)
    controller.learner_alive(LEARNER, True)
    controller.take_over(LEARNER)
    assert "took over" in events(controller, "takeover")[0]
    assert controller.state().session == LEARNER


def test_stale_foreign_and_jumping_chunks_are_refused_and_the_learner_goes_on(controller):
    controller.obey(LEARNER)
    controller.reset()
    assert controller.push_chunk(LEARNER, 0, UP, 10.0) == "accepted"
    controller.tick(10.0)
    verdicts = {
        "replayed": controller.push_chunk(LEARNER, 0, UP, 10.0),
        "stranger": controller.push_chunk(STRANGER, 1, UP, 10.0),
        "forged jump": controller.push_chunk(LEARNER, 2**40, UP, 10.0),
        "just past the gap": controller.push_chunk(
            LEARNER, 1 + controller.config.max_chunk_seq_gap, UP, 10.0
        ),
    }
    assert verdicts == {
        "replayed": "stale",
        "stranger": "foreign",
        "forged jump": "seq_jump",
        "just past the gap": "seq_jump",
    }
    detail = events(controller, "foreign_command")
    assert len(detail) == 1 and "not newer than its last chunk 0" in detail[0]
    # None of them touched the queue: the genuine chunk plays on, and the genuine next number is taken.
    r = controller.tick(10.01)
    assert (r.state.played_chunk, r.state.played_index, r.state.session) == (0, 2, LEARNER)
    assert controller.push_chunk(LEARNER, 1, UP, 10.02) == "accepted"


def test_a_forged_number_inside_the_gap_costs_the_learner_only_that_many_chunks(controller):
    """The worst a copier of the session id can do without breaking the gap: its chunk plays (inside every
    plan and workspace rule) and the learner's numbers below it are stale until the learner passes it."""
    controller.obey(LEARNER)
    controller.reset()
    assert controller.push_chunk(LEARNER, 0, UP, 10.0) == "accepted"
    assert controller.push_chunk(LEARNER, 5, UP, 10.0) == "accepted"  # the forgery
    assert [controller.push_chunk(LEARNER, s, UP, 10.0) for s in (1, 2, 3, 4, 5)] == ["stale"] * 5
    assert controller.push_chunk(LEARNER, 6, UP, 10.0) == "accepted"


def test_a_session_whose_token_is_gone_is_obeyed_no_more(controller):
    controller.obey(LEARNER)
    controller.reset()
    controller.learner_alive(LEARNER, False)
    assert controller.push_chunk(LEARNER, 0, UP, 10.0) == "foreign"
    assert "liveliness token is gone" in events(controller, "foreign_command")[0]


def test_takeover_drops_the_old_sessions_rest_and_numbering_restarts(controller):
    controller.obey(LEARNER)
    controller.reset()
    controller.push_chunk(LEARNER, 7, np.tile([0.0, 0.0, 0.002], (10, 1)), 10.0)
    controller.tick(10.0)
    controller.queue.reports()
    controller.obey(STRANGER)  # a second learner, alive, explicitly taking over
    assert controller.queue.reports() == [ChunkReport(7, 1, 9, preempted_by=-1, done=True, session=LEARNER)]
    assert controller.push_chunk(LEARNER, 8, UP, 10.0) == "foreign"
    assert controller.push_chunk(STRANGER, 0, UP, 10.0) == "accepted"
    assert controller.tick(10.0).state.session == STRANGER


def test_a_flood_of_refusals_is_one_event_per_second_with_the_count(controller):
    controller.obey(LEARNER)
    for k in range(1000):
        controller.push_chunk(STRANGER, k, UP, 10.0 + k * 1e-4)  # 0.1 s
    assert len(events(controller, "foreign_command")) == 1
    controller.push_chunk(STRANGER, 0, UP, 11.5)
    assert "and 999 more refused" in events(controller, "foreign_command")[0]


def test_refusals_held_back_are_reported_when_their_window_ends_though_none_follow(controller):
    """A short burst of forgeries right after another refusal: the operator still hears of it."""
    controller.obey(LEARNER)
    for k in range(3):
        controller.push_chunk(STRANGER, k, UP, 10.0 + k * 0.1)
    assert len(events(controller, "foreign_command")) == 1  # the first; two held back
    assert not [e for e in controller.tick(10.9).events if e.kind == "foreign_command"]
    late = [e for e in controller.tick(11.1).events if e.kind == "foreign_command"]
    assert [e.detail for e in late] == ["commands ignored: 2 more refused since the last report"]
    assert not late[0].held and not [e for e in controller.tick(13.0).events if e.kind == "foreign_command"]


def test_gate_alone():
    gate = CommandGate(max_seq_gap=3)
    gate.alive("s", True)
    assert gate.take_over("s") == ""
    assert [gate.check("s", k) for k in (0, 2, 3)] == [None, None, "seq_jump"]
    gate.admitted(3)
    assert gate.check("s", 3) == "stale" and gate.check("s", 6) is None


def test_a_confirmation_from_the_network_admits_a_session_but_never_revives_a_gone_one():
    """robot-io's reset asks the network for a token the subscriber has not announced yet
    (deploy.robot_io_node); that answer can land after the subscriber has seen the token go."""
    gate = CommandGate(max_seq_gap=3)
    gate.confirmed_alive("early")  # the reset outran the announcement
    assert gate.is_alive("early") and gate.take_over("early") == ""
    gate.alive("late", True)
    gate.alive("late", False)  # its learner died within the query's second
    gate.confirmed_alive("late")
    assert not gate.is_alive("late")
    with pytest.raises(TakeoverRefused, match="no liveliness token"):
        gate.take_over("late")
    gate.alive("late", True)  # the subscriber's own account still counts (a renewed session)
    assert gate.is_alive("late")


def test_a_takeover_counts_from_the_learners_next_chunk():
    """A learner that outlived its robot-io takes the new one over and goes on numbering where it was:
    its next chunk is not a jump past max_seq_gap (it was: the restarted robot-io refused every chunk)."""
    gate = CommandGate(max_seq_gap=32)
    gate.alive("s", True)
    gate.take_over("s", next_seq=39)
    assert gate.check("s", 39) is None and gate.check("s", 38) == "stale"
