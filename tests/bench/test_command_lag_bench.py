"""The command-lag bench counts a miss whose command reached the target apart from one that did not, and
reads the gap only in ticks that played an action."""

from __future__ import annotations

import numpy as np
from repo_scripts import load_script

from bus import messages as m
from tasks.reach import reach_observation


def state_record(ee_pos: list[float], ee_cmd: list[float], played_index: int) -> tuple:
    state = m.RobotState(ee_pos=ee_pos, ee_vel=[0.0] * 3, ee_cmd=ee_cmd, played_index=played_index)
    return ("adaptiveh/r/" + m.STATE.name, "", 0, state.SerializeToString())


def episode_end(step: int, episode: int, commanded: list[float], hand: list[float]) -> tuple:
    """The last transition of an episode whose target is at the origin."""
    target = np.zeros(3)
    obs = reach_observation(np.asarray(commanded), np.zeros(3), target, np.zeros(3))
    distance = float(np.linalg.norm(hand))
    t = m.Transition(stream="a", step=step, episode=episode, next_obs=obs.tolist(), distance=distance)
    return ("adaptiveh/r/" + m.TRANSITIONS.name, "", 0, t.SerializeToString())


def test_misses_with_the_command_on_target_are_told_apart_and_only_played_ticks_count():
    bench = load_script("bench/command_lag.py")
    records = [
        state_record([0.0, 0.0, 0.3], [0.05, 0.0, 0.3], played_index=3),  # at the 5 cm cap
        state_record([0.0, 0.0, 0.3], [0.01, 0.0, 0.3], played_index=4),
        state_record([0.0, 0.0, 0.3], [0.30, 0.0, 0.3], played_index=-1),  # held: not read
        episode_end(1, 0, [0.3, 0.0, 0.0], [0.3, 0.0, 0.0]),  # before the last 3 episodes: not read
        episode_end(2, 1, [0.01, 0.0, 0.0], [0.06, 0.0, 0.0]),  # the command there, the hand 6 cm behind
        episode_end(2, 1, [0.01, 0.0, 0.0], [0.06, 0.0, 0.0]),  # sent again: counted once
        episode_end(3, 2, [0.2, 0.0, 0.0], [0.2, 0.0, 0.0]),  # both far
        episode_end(4, 3, [0.0, 0.0, 0.0], [0.02, 0.0, 0.0]),  # a success
    ]
    out = bench.command_lag(records, lead_m=0.05, last=0.75)
    assert out["played_ticks"] == 2
    assert out["gap_at_cap_share"] == 0.5
    assert out["gap_median_m"] == 0.03
    assert (out["episodes"], out["episodes_read"]) == (4, 3)
    assert (out["misses"], out["misses_with_command_on_target"]) == (2, 1)
