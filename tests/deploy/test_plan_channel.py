"""The plan channel's parts without a robot: late sending in order (and forgotten on reset), and the
account of what a preemption dropped (planned motion only, never a refusal or another learner's chunk)."""

from __future__ import annotations

import threading
import time

import numpy as np
from polling import wait_until

from bus import messages as m
from deploy.plan_channel import DelayedSender, PlanBook, played
from learner.plans import Plan


def plan(plan_id: int, actions, opened_by: str = "first") -> Plan:
    a = np.asarray(actions, float)
    return Plan(plan_id, a, a, np.zeros((len(a) + 1, 15)), segment=plan_id, opened_by=opened_by)


def send(book: PlanBook, seq: int, p: Plan) -> int:
    return book.send(lambda: (seq, 100.0 + seq), p, p.actions)  # stamp: a function of seq here


def test_delayed_sender_keeps_order_and_forgets_on_cancel():
    stop, out = threading.Event(), []
    sender = DelayedSender(lambda item: out.append((item, time.monotonic())), 0.15, stop)
    try:
        t0 = time.monotonic()
        for k in range(3):
            sender.submit(k)
        assert time.monotonic() - t0 < 0.05 and out == []  # submit never waits
        wait_until(lambda: len(out) >= 3, 3, "three plans sent")
        assert [k for k, _ in out] == [0, 1, 2] and out[0][1] - t0 >= 0.15
        sender.submit("last episode")
        assert sender.cancel() == 1
        time.sleep(0.3)
        assert len(out) == 3  # a plan of the last episode never goes out
    finally:
        stop.set()


def test_plan_book_counts_planned_motion_dropped_by_a_newer_plan():
    book = PlanBook()
    first = send(book, 10, plan(0, [[0.0, 0.01, 0.0]] * 4 + [[0.0, 0.0, 0.0]]))
    second = send(book, 11, plan(1, [[0.01, 0.0, 0.0]], "retreat"))
    assert book.on_status(m.ChunkStatus(chunk_seq=first, executed=1, dropped=0)) is None  # progress
    assert book.on_status(m.ChunkStatus(chunk_seq=99, executed=1, dropped=3, preempted_by=second)) is None
    assert book.on_status(m.ChunkStatus(chunk_seq=first, executed=1, dropped=4, preempted_by=-1)) is None
    forged = m.ChunkStatus(chunk_seq=first, executed=1, dropped=4, preempted_by=second, chunk_stamp=1.0)
    assert book.on_status(forged) is None  # our number, another chunk (not our stamp)
    drop = book.on_status(
        m.ChunkStatus(
            chunk_seq=first, executed=1, dropped=4, preempted_by=second, chunk_stamp=100.0 + first,
            preempted_by_opening=m.ActionChunk.RETREAT,
        )
    )  # fmt: skip
    assert (drop.plan_id, drop.by_plan_id, drop.by_opening) == (0, 1, "retreat")  # robot-io's echo
    assert (drop.dropped, drop.moving) == (4, 3) and abs(drop.path_m - 0.03) < 1e-12
    assert (book.dropped_planned, book.dropped_moving, book.preemptions) == (4, 3, 1)


def test_played_names_the_plan_action_and_holds_otherwise():
    book, me = PlanBook(), "0a1b2c3d4e5f6071"
    seq = send(book, 5, plan(7, [[0.0, 0.02, 0.0], [0.0, 0.0, 0.05]]))
    stamp = 100.0 + seq
    state = m.RobotState(tick=3, played_chunk=seq, played_index=1, session=me, played_stamp=stamp)
    pid, index, action = played(state, book, me)
    assert (pid, index) == (7, 1) and action.tolist() == [0.0, 0.0, 0.05]
    assert played(m.RobotState(tick=4, played_chunk=-1, played_index=-1, session=me), book, me)[:2] == (
        -1,
        -1,
    )
    assert played(m.RobotState(tick=5, played_chunk=6, played_index=0, session=me), book, me)[:2] == (-1, -1)
    # The same number of another session (the arm taken over, or a restarted learner's) is not our plan.
    other = m.RobotState(tick=6, played_chunk=seq, played_index=0, session="f" * 16, played_stamp=stamp)
    assert played(other, book, me)[:2] == (-1, -1)
    forged = m.RobotState(tick=7, played_chunk=seq, played_index=0, session=me, played_stamp=stamp + 1)
    assert played(forged, book, me)[:2] == (-1, -1)
    assert book.foreign_ticks == 3
