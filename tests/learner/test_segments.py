"""One vocabulary of segment ends and one set of close rules (learner.segments), spelled the same in the
schema, used by the learner in-process and the actor beside the arm."""

from __future__ import annotations

from hypothesis import given
from hypothesis import strategies as st

from bus import messages as m
from learner.segments import CLOSED, Opening, SegmentEnd, opening, segment_end


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
