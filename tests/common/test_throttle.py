"""Repeated complaints are rate-limited per group, and a held-back burst is still reported
(common.throttle: the bus's log, the safety events of robot-io, the actor and vision, the monitor's API)."""

from __future__ import annotations

from common.throttle import Throttle


def test_the_first_report_in_full_then_one_count_per_interval():
    now = [0.0]
    throttle = Throttle("like it", every_s=10.0, clock=lambda: now[0])
    lines = []
    group = ("adaptiveh/r/target", "invalid")
    for i in range(1000):
        now[0] = i * 0.03  # 30 s of a flood, about 33 a second
        lines.append(throttle.report(f"Target.position: bad {i}", group))
    shown = [line for line in lines if line is not None]
    assert shown[0] == "Target.position: bad 0"
    assert len(shown) == 3  # at 0, 10 and 20 s (the third interval still open at 29.97 s)
    assert shown[1] == "Target.position: bad 334 (and 333 more like it since the last report)"
    assert throttle.total[group] == 1000


def test_groups_are_limited_apart():
    throttle = Throttle("like it", every_s=60.0, clock=lambda: 0.0)
    assert throttle.report("a", ("k1", "forged")) == "a"
    assert throttle.report("b", ("k1", "invalid")) == "b"
    assert throttle.report("c", ("k2", "forged")) == "c"
    assert throttle.report("d", ("k1", "forged")) is None


def test_a_burst_held_back_is_reported_once_its_window_ends():
    throttle = Throttle("refused", every_s=1.0)
    assert throttle.report("first", now=10.0) == "first"
    assert throttle.report("second", now=10.2) is None
    assert throttle.report("third", now=10.4) is None
    assert throttle.overdue(10.9) == []  # the window is still open
    assert throttle.overdue(11.1) == ["2 more refused since the last report"]
    assert throttle.overdue(13.0) == []  # said once
    assert throttle.report("fourth", now=13.5) == "fourth"  # nothing held back since
