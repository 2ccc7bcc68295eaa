"""One vocabulary of segment ends and one set of close rules (learner.segments), spelled the same in the
schema, used by the learner in-process and the actor beside the arm."""

from __future__ import annotations

import typing

import pytest
from hypothesis import given
from hypothesis import strategies as st

from bus import messages as m
from common.config import ConfigError, parse
from deploy.config import LearnerConfig
from learner.config import AdaptiveHConfig
from learner.segments import CLOSED, Execution, Opening, SegmentEnd, opening, segment_end


def _names(enum_type) -> set[str]:
    return {v.name for v in enum_type.values if v.number != 0}


def test_the_schema_spells_the_same_names_with_one_enum():
    assert _names(m.SegmentEnd.DESCRIPTOR) == {e.name for e in SegmentEnd}
    # a transition's end and a retreat event's reason are the one enum (a retreat is said one way)
    ends = {m.Transition.DESCRIPTOR.fields_by_name["end"], m.RetreatEvent.DESCRIPTOR.fields_by_name["reason"]}
    assert {fd.enum_type.full_name for fd in ends} == {m.SegmentEnd.DESCRIPTOR.full_name}
    assert set(CLOSED) < set(SegmentEnd)
    # NONE: a chunk nothing preempted (ChunkStatus.preempted_by_opening), not a reason to plan
    assert _names(m.ActionChunk.DESCRIPTOR.enum_types_by_name["Opening"]) - {"NONE"} == {
        e.name for e in Opening
    }
    for end in SegmentEnd:  # the code's value is the wire's name
        assert m.label(m.Transition(end=m.enum(m.Transition, "end", end)), "end") == end
    for end in CLOSED:
        assert m.label(m.RetreatEvent(reason=m.enum(m.RetreatEvent, "reason", end)), "reason") == end


@given(st.booleans(), st.integers(1, 60), st.integers(1, 50), st.booleans(), st.booleans())
def test_the_close_rules_in_their_order(retreat, length, limit, episode_over, plan_gone):
    end = segment_end(retreat, length, limit, episode_over, plan_gone)
    if retreat:
        assert end == SegmentEnd.RETREAT
    elif length >= limit:
        assert end == SegmentEnd.H_MAX
    elif episode_over:
        assert end == SegmentEnd.EPISODE_END
    else:
        assert end == (SegmentEnd.H_MAX if plan_gone else SegmentEnd.OPEN)


def test_the_next_plan_says_how_the_segment_before_ended():
    assert opening(SegmentEnd.EPISODE_END) == Opening.FIRST
    assert opening(SegmentEnd.RETREAT) == Opening.RETREAT
    assert opening("h_max") == Opening.H_MAX


def test_both_configs_take_their_execution_modes_from_one_enum():
    """The agent's modes (closed loop, plan) and the stack's (closed loop, actor) are members of one
    ``Execution``; a mode of the other config is refused in YAML's words, naming the key."""
    agent_modes = typing.get_args(AdaptiveHConfig.model_fields["execution"].annotation)
    stack_modes = typing.get_args(LearnerConfig.model_fields["execution"].annotation)
    assert set(agent_modes) | set(stack_modes) == set(Execution)
    assert parse(AdaptiveHConfig, {"execution": "plan"}, "agent").execution == Execution.PLAN
    with pytest.raises(
        ConfigError, match=r"agent: execution: Input should be 'closed_loop' or 'plan' \(got 'actor'\)"
    ):
        parse(AdaptiveHConfig, {"execution": "actor"}, "agent")
    stack = LearnerConfig(algo="adaptiveh", execution="actor")
    assert stack.execution == Execution.ACTOR
    assert stack.agent_config()["execution"] == Execution.PLAN  # an actor's agent plans
