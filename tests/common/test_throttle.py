"""Bad-input reporting is rate-limited per key and reason (common.throttle)."""

from __future__ import annotations

from common.throttle import ReportThrottle


def test_the_first_report_in_full_then_one_count_per_interval():
    now = [0.0]
    throttle = ReportThrottle(every_s=10.0, clock=lambda: now[0])
    lines = []
    for i in range(1000):
        now[0] = i * 0.03  # 30 s of a flood, about 33 a second
        lines.append(throttle.report("adaptiveh/r/target", "invalid", f"Target.position: bad {i}"))
    shown = [line for line in lines if line is not None]
    assert shown[0] == "Target.position: bad 0"
    assert len(shown) == 3  # at 0, 10 and 20 s (the third interval still open at 29.97 s)
    assert "and 333 more like it on adaptiveh/r/target" in shown[1]
    assert throttle.total[("adaptiveh/r/target", "invalid")] == 1000


def test_keys_and_reasons_are_limited_apart():
    throttle = ReportThrottle(every_s=60.0, clock=lambda: 0.0)
    assert throttle.report("k1", "forged", "a") == "a"
    assert throttle.report("k1", "invalid", "b") == "b"
    assert throttle.report("k2", "forged", "c") == "c"
    assert throttle.report("k1", "forged", "d") is None
