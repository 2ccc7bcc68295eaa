"""The monitor's account of plans, from the messages alone: the planned path next to the executed one,
the tick where a retreat's plan cut it short, and executed / dropped-at-retreat / queued counts."""

from __future__ import annotations

from bus_probe import BusProbe
from loopback import unique_name

from bus import messages as m
from bus.transport import Bus, ZenohConfig, open_session
from monitor.server import MonitorState


def test_monitor_keeps_planned_and_executed_paths_and_the_retreat_cut(endpoint):
    bus = Bus(open_session(ZenohConfig(listen=(endpoint,))), unique_name("mon"))
    try:
        mon = MonitorState(bus)
        put = {t: bus.publisher(t) for t in (m.STATE, m.CMD_CHUNK, m.CHUNK_STATUS, m.EVENTS_RETREAT)}
        probe = BusProbe(bus)
        zero3 = [0.0, 0.0, 0.0]
        me, stranger = "0a1b2c3d4e5f6071", "ffffffffffffffff"

        def state(tick: int, y: float, chunk: int = -1, index: int = -1) -> None:
            put[m.STATE](
                m.RobotState(
                    ee_pos=[0.5, y, 0.3], ee_vel=zero3, ee_cmd=[0.5, y, 0.3], mode=m.RobotState.RUNNING,
                    tick=tick,
                    played_chunk=chunk, played_index=index, chunk_seq=max(chunk, 0), session=me,
                )
            )  # fmt: skip

        state(100, 0.0)
        probe.wait(lambda: mon.robot.get("ee") == [0.5, 0.0, 0.3], 5, "the first state")
        path = [v for i in range(1, 6) for v in (0.5, 0.01 * i, 0.3)]
        first = put[m.CMD_CHUNK](
            m.ActionChunk(
                actions=[0.0, 0.01, 0.0] * 5,
                segment=3,
                predicted_ee=path,
                session=me,
                opened_by=m.ActionChunk.FIRST,
            )
        )
        probe.wait(lambda: (me, first) in mon.plans, 5, "the plan")
        # A stranger's chunk is not a plan of the arm's; its refusal is counted, not drawn.
        forged = m.ActionChunk(
            seq=first + 1,
            actions=[0.05, 0, 0],
            predicted_ee=[1, 1, 1],
            session=stranger,
            opened_by=m.ActionChunk.FIRST,
        )
        bus.session.put(bus.key(m.CMD_CHUNK), forged.SerializeToString())
        put[m.CHUNK_STATUS](
            m.ChunkStatus(
                chunk_seq=first + 1,
                dropped=1,
                done=True,
                session=stranger,
                verdict=m.ChunkStatus.FOREIGN,
                opened_by=m.ActionChunk.FIRST,
                preempted_by_opening=m.ActionChunk.NONE,
            )
        )
        probe.wait(lambda: mon.counts["refused"] == 1, 5, "the refusal")
        for i in range(2):
            state(101 + i, 0.01 * (i + 1), first, i)
        state(102, 0.02, first, 1)  # a state between ticks repeats its tick: not a second step
        put[m.EVENTS_RETREAT](m.RetreatEvent(segment=3, H=2, reason=m.SegmentEnd.RETREAT))
        probe.wait(lambda: mon.counts["retreats"] == 1, 5, "the retreat")
        second = put[m.CMD_CHUNK](
            m.ActionChunk(
                actions=[0.0, 0.0, -0.01] * 4,
                segment=4,
                predicted_ee=[0.0] * 12,
                session=me,
                opened_by=m.ActionChunk.RETREAT,
            )
        )
        probe.wait(lambda: (me, second) in mon.plans, 5, "the retreat's plan")
        put[m.CHUNK_STATUS](
            m.ChunkStatus(
                chunk_seq=first, executed=2, dropped=3, preempted_by=second, done=True, session=me,
                verdict=m.ChunkStatus.ACCEPTED, segment=3, opened_by=m.ActionChunk.FIRST,
                preempted_by_opening=m.ActionChunk.RETREAT,
            )
        )  # fmt: skip
        state(103, 0.02, second, 0)
        arrived = lambda: len(mon.plans[me, second]["path"]) == 2 and mon.plans[me, first]["done"]  # noqa: E731
        probe.wait(arrived, 5, "the new plan's tick and the old one's status")
        snap = mon.snapshot()
        old, new = snap["plans"]  # the forged chunk is not among them
        assert old["path"] == [[0.5, 0.0, 0.3], [0.5, 0.01, 0.3], [0.5, 0.02, 0.3]]
        assert old["planned"] == [[0.5, 0.0, 0.3]] + [[0.5, round(0.01 * i, 4), 0.3] for i in range(1, 6)]
        assert (old["executed"], old["dropped"], old["queued"]) == (2, 3, 0)
        assert old["parted_tick"] == 102 and old["by_retreat"]
        assert (new["executed"], new["queued"], new["parted_tick"]) == (1, 3, None)
        assert snap["counts"]["dropped_at_retreat"] == 3
    finally:
        bus.close()
