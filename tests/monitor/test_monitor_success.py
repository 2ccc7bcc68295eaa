"""The monitor's success rate: the last 20 finished episodes, from the learner's telemetry alone, and
the episode count."""

from __future__ import annotations

from bus_probe import BusProbe
from loopback import unique_name

from bus import messages as m
from bus.transport import Bus, ZenohConfig, open_session
from monitor.server import SUCCESS_WINDOW, MonitorState


def test_success_rate_over_the_last_20_episodes_and_the_episode_count(endpoint):
    bus = Bus(open_session(ZenohConfig(listen=(endpoint,))), unique_name("mon"))
    try:
        mon = MonitorState(bus)
        probe = BusProbe(bus)
        assert mon.snapshot()["success"] == {"rate": None, "of": 0, "window": 20, "episodes": 0}
        put = bus.publisher(m.TELEMETRY_LEARNER)
        succeeded = [episode > 12 for episode in range(1, 31)]  # the last 18 of 30 succeed
        for episode, success in enumerate(succeeded, 1):
            put(
                m.LearnerTelemetry(
                    global_step=50 * episode, episode=episode, success=success, algo="adaptiveh"
                )
            )
            put(
                m.LearnerTelemetry(
                    global_step=50 * episode + 20, episode=episode, success=success, algo="adaptiveh"
                )
            )
        probe.wait(lambda: mon.snapshot()["success"]["episodes"] == 30, 5, "the 30th episode")
        assert mon.snapshot()["success"] == {
            "rate": 18 / SUCCESS_WINDOW,
            "of": 20,
            "window": 20,
            "episodes": 30,
        }
    finally:
        bus.close()
