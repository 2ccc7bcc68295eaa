"""A run's segment records on disk, so a learner that runs for days keeps only the newest in memory.

Each segment carries its retreat-statistic trace (one float per step): kept in memory, the deployed
learner grew by ~5 MB an hour (bench/soak.py) and its checkpoint with it. The archive appends each
segment to a JSON-lines file as it closes and trims the in-memory log to the newest ``keep``; the whole
log is read back once, for the run's result.
"""

from __future__ import annotations

import json
import logging
import os
from dataclasses import asdict
from pathlib import Path

from learner.protocol import RunLog, SegmentRecord

logger = logging.getLogger(__name__)


class SegmentArchive:
    """``segments.jsonl`` beside a checkpoint: every segment of the run, in order of index."""

    def __init__(self, path: str | Path, log: RunLog, keep: int = 500) -> None:
        """Resume the archive for ``log`` (from its checkpoint, or new): segments the file holds beyond
        the log's count were undone by the resume and are dropped."""
        self.path = Path(path)
        self.keep = keep
        kept = [s for s in self._read() if s.index < log.segment_count]
        if [s.index for s in kept] != list(range(len(kept))) or len(kept) < log.segments_before:
            logger.error(
                "%s does not hold segments 0..%d in order (%d lines): the run's result will lack some",
                self.path,
                log.segments_before - 1,
                len(kept),
            )
        self.path.parent.mkdir(parents=True, exist_ok=True)
        tmp = self.path.with_suffix(".tmp")  # a kill while rewriting must not lose the archive
        tmp.write_text("".join(_line(s) for s in kept))
        os.replace(tmp, self.path)
        self.written = kept[-1].index + 1 if kept else 0  # the next index the file lacks
        self.add(log)

    def add(self, log: RunLog) -> None:
        """Append ``log``'s segments not yet on file, then trim memory to the newest ``keep``."""
        new = log.segments_since(self.written)
        if new:
            with self.path.open("a") as fh:
                fh.write("".join(_line(s) for s in new))
            self.written = new[-1].index + 1
        extra = len(log.segments) - self.keep
        if extra >= self.keep:  # trim in batches: a del at the front moves the whole list
            del log.segments[:extra]
            log.segments_before += extra

    def full(self, log: RunLog) -> RunLog:
        """``log`` with every segment of the run (the file's, then any in memory not yet added)."""
        self.add(log)
        return RunLog(episodes=log.episodes, segments=self._read(), global_step=log.global_step)

    def _read(self) -> list[SegmentRecord]:
        if not self.path.exists():
            return []
        out = []
        with self.path.open() as fh:
            for n, line in enumerate(fh, 1):
                try:
                    out.append(SegmentRecord(**json.loads(line)))
                except (json.JSONDecodeError, TypeError):  # a line cut short by a kill: the rest is lost
                    logger.warning("%s: line %d is not a whole segment; reading up to it", self.path, n)
                    break
        return out


def _line(s: SegmentRecord) -> str:
    return json.dumps(asdict(s)) + "\n"
