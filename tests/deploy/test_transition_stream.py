"""An actor's transitions reach its learner in order and once each, over real Zenoh, though the learner
restarts from a checkpoint in between (``deploy.transition_stream``); an outbox that overflows says how
many it dropped and the learner skips exactly those."""

from __future__ import annotations

import time
from collections.abc import Callable, Iterator

import pytest
from loopback import unique_name
from polling import wait_until

from bus import messages as m
from bus.signing import mac_key
from bus.transport import Bus, ZenohConfig, open_session
from deploy.transition_stream import RESEND_AFTER_S, Inbox, Outbox


@pytest.fixture
def arm(endpoint) -> Iterator[tuple[Bus, Callable[[], Bus]]]:
    """The actor's bus, and a maker of learner processes' buses beside it (closed at the end)."""
    name = unique_name("ts")
    actor = Bus(open_session(ZenohConfig(listen=(endpoint,))), name)
    learners: list[Bus] = []

    def learner() -> Bus:
        learners.append(Bus(open_session(ZenohConfig(connect=(endpoint,))), name))
        return learners[-1]

    yield actor, learner
    for bus in learners:
        bus.close()
    actor.close()


def _tick() -> m.Transition:
    return m.Transition(reward=-1.0, end=m.SegmentEnd.OPEN)


def _outbox(bus: Bus, limit: int = 1000) -> Outbox:
    outbox = Outbox(bus.publisher(m.TRANSITIONS), limit)
    bus.subscribe(m.TRANSITION_ACKS, outbox.on_ack)
    return outbox


def _learn(inbox: Inbox, outbox: Outbox, until: int, timeout: float = 15.0) -> list[int]:
    """The steps the learner takes until it has learned ``until`` of the stream (the actor sending again
    what it lacks, as its control loop does after each tick)."""
    steps: list[int] = []
    deadline = time.monotonic() + timeout
    while inbox.learned.get(outbox.stream, 0) < until:
        assert time.monotonic() < deadline, f"learned {inbox.learned}, steps {steps[-5:]}"
        inbox.ack()
        outbox.resend()
        t = inbox.get(timeout=0.05)
        if t is not None:
            steps.append(t.step)
            inbox.learned_one(t)
    return steps


def _wait_matched(bus: Bus, topic: m.Topic = m.TRANSITIONS) -> None:
    """Until what ``bus`` puts on ``topic`` reaches a subscriber (a put before that is lost)."""
    pub = bus.session.declare_publisher(bus.key(topic))
    try:
        wait_until(lambda: pub.matching_status.matching, 10, f"a subscription to {topic.name}")
    finally:
        pub.undeclare()


def test_a_learner_that_restarts_from_its_checkpoint_gets_every_transition_once_in_order(arm):
    actor, learner = arm
    outbox = _outbox(actor)
    dies = learner()
    first = Inbox(dies, {})
    _wait_matched(actor)
    for _ in range(40):
        outbox.send(_tick())
    assert _learn(first, outbox, 30) == list(range(30))  # it may have taken a few more
    first.checkpointed({outbox.stream: 20})  # the checkpoint holds 0..19: the actor forgets those
    wait_until(lambda: outbox.unsaved() == outbox.sent - 20, 10, "the actor to forget what is saved")
    dies.close()  # the learner dies; the actor plays on; a new learner process resumes from the checkpoint
    for _ in range(25):
        outbox.send(_tick())
    second = Inbox(learner(), {outbox.stream: 20})
    _wait_matched(actor)
    second.ack(force=True)  # a new learner says where it stands: the actor sends from there at once
    assert _learn(second, outbox, 65) == list(range(20, 65))  # no gap, no repeat
    assert second.lost == outbox.lost == 0 and outbox.resent >= 40 - 20


def test_an_outbox_that_overflows_counts_the_dropped_and_the_learner_skips_exactly_those(arm):
    actor, learner = arm
    outbox = _outbox(actor, limit=100)
    dropped = [outbox.send(_tick()) for _ in range(150)]  # no learner hears these
    assert dropped == [False] * 100 + [True] * 50 and outbox.lost == 50 and outbox.unsaved() == 100
    inbox = Inbox(learner(), {})
    _wait_matched(actor)
    assert _learn(inbox, outbox, 150) == list(range(50, 150))  # a new learner: sent again at once
    assert inbox.lost == 50


def test_a_transition_lost_on_the_way_is_sent_again_once_the_learner_waits_for_it(arm):
    actor, learner = arm
    publish = actor.publisher(m.TRANSITIONS)
    lost_once: list[int] = []

    def lossy(msg: m.Transition) -> None:
        if msg.step == 5 and not lost_once:
            lost_once.append(msg.step)  # the network ate it
            return
        publish(msg)

    outbox = Outbox(lossy, 1000)
    actor.subscribe(m.TRANSITION_ACKS, outbox.on_ack)
    inbox = Inbox(learner(), {})
    _wait_matched(actor)
    inbox.ack(force=True)
    wait_until(lambda: outbox.resend() == 0 and outbox._learner == inbox.learner, 10, "the first ack")
    for _ in range(10):
        outbox.send(_tick())
    started = time.monotonic()
    assert _learn(inbox, outbox, 10) == list(range(10))  # 6..9 refused until 5 came again
    assert time.monotonic() - started >= RESEND_AFTER_S and inbox.out_of_order >= 1
    assert outbox.resent >= 5 and lost_once == [5]


def test_a_forged_ack_does_not_make_the_actor_forget_what_the_learner_has_not_saved(endpoint):
    """With the stack's key an ack is signed: a stranger's (unsigned, or signed with another key) saying
    everything is saved is refused, and the actor keeps every transition until the learner's says so."""
    name, key = unique_name("ts"), mac_key("the stack's token")
    actor = Bus(open_session(ZenohConfig(listen=(endpoint,))), name, key)
    learner = Bus(open_session(ZenohConfig(connect=(endpoint,))), name, key)
    strangers = [Bus(open_session(ZenohConfig(connect=(endpoint,))), name, k) for k in (None, mac_key("x"))]
    try:
        outbox = _outbox(actor)
        inbox = Inbox(learner, {})
        _wait_matched(actor)
        for _ in range(10):
            outbox.send(_tick())
        assert _learn(inbox, outbox, 10) == list(range(10))
        for stranger in strangers:
            pub = stranger.publisher(m.TRANSITION_ACKS)
            _wait_matched(stranger, m.TRANSITION_ACKS)
            for _ in range(5):
                pub(m.TransitionAck(stream=outbox.stream, learned=10, saved=10, learner="stranger"))
        time.sleep(0.5)
        assert outbox.unsaved() == 10  # nothing forgotten on a stranger's word
        inbox.checkpointed({outbox.stream: 10})
        wait_until(lambda: outbox.unsaved() == 0, 10, "the learner's own ack")
    finally:
        for bus in (*strangers, learner, actor):
            bus.close()


def test_nothing_is_sent_again_to_a_learner_that_is_gone_until_one_speaks():
    """A dead or stopped learner acks nothing: the actor does not flood the bus with what it keeps; a
    learner that speaks again (a new process) gets it all at once."""
    now = [0.0]
    sent: list[int] = []
    outbox = Outbox(lambda msg: sent.append(msg.step), 1000, clock=lambda: now[0])
    outbox.on_ack(m.TransitionAck(stream=outbox.stream, learned=0, saved=0, learner="a"))
    for _ in range(20):
        outbox.send(_tick())
    outbox.on_ack(m.TransitionAck(stream=outbox.stream, learned=20, saved=5, learner="a"))
    for _ in range(10):
        outbox.send(_tick())
    for t in (0.5, 2.0, 10.0, 60.0):  # learner "a" died after its last ack
        now[0] = t
        assert outbox.resend() == 0
    assert sent == list(range(30)) and outbox.unsaved() == 25
    outbox.on_ack(m.TransitionAck(stream=outbox.stream, learned=5, saved=5, learner="b"))  # resumed
    assert outbox.resend() == 25 and sent[30:] == list(range(5, 30))
