"""The run archive: a long run keeps only its newest segments and episodes in memory, the files have
every one, and a resume from a checkpoint drops what the resume undid."""

from __future__ import annotations

import gymnasium as gym

import sim  # noqa: F401  (registers the environments)
from learner.adaptiveh import AdaptiveH
from learner.config import AdaptiveHConfig
from learner.protocol import EpisodeRecord, RunLog, SegmentRecord
from learner.run_archive import RunArchive


def _close(log: RunLog, reason: str = "retreat") -> None:
    """What an RKHS learner does when a segment ends."""
    log.global_step += 3
    log.segments.append(
        SegmentRecord(log.segment_count, log.global_step, 3, reason, [0.1, 0.2, 0.3], threshold=0.5)
    )


def test_memory_keeps_the_newest_and_the_file_every_segment(tmp_path):
    log = RunLog()
    archive = RunArchive(tmp_path, log, keep=50)
    for _ in range(1000):
        _close(log)
        archive.add(log)
        assert len(log.segments) < 2 * archive.keep
    assert log.segment_count == 1000 and log.segments[-1].index == 999
    full = archive.full(log)
    assert [s.index for s in full.segments] == list(range(1000))
    assert full.segments[500].statistic == [0.1, 0.2, 0.3] and full.global_step == 3000


def _archived_run(directory, segments: int) -> RunLog:
    """A run of ``segments`` segments, each archived as it closes (as the learner node does)."""
    log = RunLog()
    archive = RunArchive(directory, log, keep=50)
    for _ in range(segments):
        _close(log)
        archive.add(log)
    return log


def test_a_resume_drops_the_segments_it_undid(tmp_path):
    log = _archived_run(tmp_path, 200)
    restored = RunLog.from_dict(log.to_dict())  # what the checkpoint holds
    went_on = RunArchive(tmp_path, log, keep=50)  # the learner went on to segment 299, then died
    for _ in range(100):
        _close(log)
        went_on.add(log)
    assert len(went_on.full(log).segments) == 300  # on file before the restart from the checkpoint
    archive = RunArchive(tmp_path, restored, keep=50)
    for _ in range(20):
        _close(restored, "h_max")
        archive.add(restored)
    full = archive.full(restored)
    assert [s.index for s in full.segments] == list(range(220))
    assert {s.reason for s in full.segments[200:]} == {"h_max"}  # the redone ones, not the undone


def test_adaptiveh_numbers_segments_on_past_the_trimmed_ones(tmp_path):
    env = gym.make("NSCartPoleContinuous-v0")
    agent = AdaptiveH(env, AdaptiveHConfig(h_max=5), seed=0)
    archive = RunArchive(tmp_path, agent.log, keep=20)
    agent.learn(600, callback=lambda step, lg: archive.add(lg))
    full = archive.full(agent.log)
    assert agent.log.segments_before > 0 and len(agent.log.segments) < 40
    assert [s.index for s in full.segments] == list(range(agent.log.segment_count))
    assert sum(s.H for s in full.segments) <= 600
    assert agent.log.episodes_before > 0 and len(agent.log.episodes) < 40
    assert [e.episode for e in full.episodes] == list(range(agent.log.episode_count))
    assert sum(e.length for e in full.episodes) <= 600 and full.episodes[-1].global_step <= 600


def test_a_line_cut_short_by_a_kill_is_dropped_and_the_run_goes_on(tmp_path):
    path = tmp_path / "segments.jsonl"
    log = _archived_run(tmp_path, 10)
    path.write_text(path.read_text() + '{"index": 10, "global_st')  # the kill, mid-line
    restored = RunLog.from_dict(log.to_dict())
    archive = RunArchive(tmp_path, restored, keep=50)
    _close(restored)
    assert [s.index for s in archive.full(restored).segments] == list(range(11))
    assert not path.with_suffix(".tmp").exists()


def test_episodes_are_archived_and_numbered_on_past_the_trimmed_ones(tmp_path):
    log = RunLog()
    archive = RunArchive(tmp_path, log, keep=30)
    for _ in range(500):
        log.global_step += 50
        log.episodes.append(EpisodeRecord(log.episode_count, log.global_step, -1.0, 50, True, {"d": 0.1}))
        archive.add(log)
        assert len(log.episodes) < 60
    restored = RunLog.from_dict(log.to_dict())  # a checkpoint keeps the count, not the trimmed records
    assert restored.episodes_before == log.episodes_before > 0 and restored.episode_count == 500
    full = RunArchive(tmp_path, restored, keep=30).full(restored)
    assert [e.episode for e in full.episodes] == list(range(500))
    assert full.episodes[7].info == {"d": 0.1} and full.episodes[-1].global_step == 25000
