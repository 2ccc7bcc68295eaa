"""How a segment stands after a tick, and why the next plan is made: the one vocabulary of segment ends
and the paper's close rules in one function, for the learner in-process and the actor beside the arm.

The schema's enums (``Transition.end``, ``RetreatEvent.reason``, ``ActionChunk.opened_by``) spell the
same names in capitals (``tests/learner/test_segments.py`` holds them equal)."""

from __future__ import annotations

from enum import StrEnum


class SegmentEnd(StrEnum):
    """How a segment stands after a tick: open, or closed by one of the paper's three rules."""

    OPEN = "open"
    RETREAT = "retreat"  # the retreat test failed
    H_MAX = "h_max"  # its longest length (h_max; fixed H), or its plan is gone
    EPISODE_END = "episode_end"


CLOSED = (SegmentEnd.RETREAT, SegmentEnd.H_MAX, SegmentEnd.EPISODE_END)


class Execution(StrEnum):
    """How the product acts, for both configs: the agent's (``learner.agent.execution``: closed loop or
    plan) and the stack's (``learner.execution``: closed loop or actor, whose agent plans)."""

    CLOSED_LOOP = "closed_loop"  # every action sampled at the state it acts in
    PLAN = "plan"  # segments are committed plans, run by the segment loop in-process (a local channel)
    ACTOR = "actor"  # the same loop in an actor beside the arm, on robot-io's channel (the stack)


class Opening(StrEnum):
    """Why a plan is made: how the segment before it ended (``opening``), or a hold of robot-io's sender."""

    FIRST = "first"  # an episode's first plan
    RETREAT = "retreat"
    H_MAX = "h_max"
    TARGET_LOST = "target_lost"  # stay put: the target is lost or its fix too old
    CONTINUE = "continue"  # closed loop: the same segment's next chunk


def segment_end(
    retreat: bool, length: int, limit: int, episode_over: bool, plan_gone: bool = False
) -> SegmentEnd:
    """The close rules, in their order: a failed retreat test, the segment's ``limit`` reached, the
    episode's end; with plans, a plan that is gone (played out, or dropped by an e-stop or a refusal)
    while the arm holds ends the segment as its ``limit`` would, rather than idling to it."""
    if retreat:
        return SegmentEnd.RETREAT
    if length >= limit:
        return SegmentEnd.H_MAX
    if episode_over:
        return SegmentEnd.EPISODE_END
    if plan_gone:
        return SegmentEnd.H_MAX
    return SegmentEnd.OPEN


def opening(end: str) -> Opening:
    """Why the next plan is made, from how the segment before it ended (an episode's end: a first plan)."""
    return Opening.FIRST if end == SegmentEnd.EPISODE_END else Opening(end)
