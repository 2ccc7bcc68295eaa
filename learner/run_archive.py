"""A run's segment and episode records on disk, so a learner that runs for days keeps only the newest
in memory.

Each segment carries its retreat-statistic trace (one float per step) and each episode its info: kept in
memory, the deployed learner grew by ~5 MB an hour (bench/soak.py) and its checkpoint with it. The
archive appends each record to a JSON-lines file as it is made (``segments.jsonl``, ``episodes.jsonl``)
and trims the in-memory log to the newest ``keep`` of each kind; the whole log is read back once, for
the run's result.
"""

from __future__ import annotations

import json
import logging
import os
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

from learner.protocol import EpisodeRecord, RunLog, SegmentRecord

logger = logging.getLogger(__name__)


@dataclass(frozen=True)
class RecordKind:
    """One list of a ``RunLog``: its name (also ``<name>_before`` and the file's stem), its record type,
    and the field that numbers a record from 0."""

    name: str
    record: type
    number: str


KINDS = (RecordKind("segments", SegmentRecord, "index"), RecordKind("episodes", EpisodeRecord, "episode"))


class RecordFile:
    """``<name>.jsonl``: every record of one kind, in order of number; memory keeps the newest ``keep``."""

    def __init__(self, path: Path, kind: RecordKind, log: RunLog, keep: int) -> None:
        """Resume the file for ``log`` (from its checkpoint, or new): records the file holds beyond the
        log's count were undone by the resume and are dropped."""
        self.path, self.kind, self.keep = path, kind, keep
        count, before = log.count(kind.name), log.before(kind.name)
        kept = [r for r in self.read() if self._number(r) < count]
        if [self._number(r) for r in kept] != list(range(len(kept))) or len(kept) < before:
            logger.error(
                "%s does not hold %s 0..%d in order (%d lines): the run's result will lack some",
                path,
                kind.name,
                before - 1,
                len(kept),
            )
        path.parent.mkdir(parents=True, exist_ok=True)
        tmp = path.with_suffix(".tmp")  # a kill while rewriting must not lose the archive
        tmp.write_text("".join(_line(r) for r in kept))
        os.replace(tmp, path)
        self.written = self._number(kept[-1]) + 1 if kept else 0  # the next number the file lacks
        self.add(log)

    def add(self, log: RunLog) -> None:
        """Append ``log``'s records not yet on file, then trim memory to the newest ``keep``."""
        new = log.since(self.kind.name, self.written)
        if new:
            with self.path.open("a") as fh:
                fh.write("".join(_line(r) for r in new))
            self.written = self._number(new[-1]) + 1
        extra = len(getattr(log, self.kind.name)) - self.keep
        if extra >= self.keep:  # trim in batches: a del at the front moves the whole list
            log.forget(self.kind.name, extra)

    def read(self) -> list[Any]:
        """Every whole record on file."""
        if not self.path.exists():
            return []
        out = []
        with self.path.open() as fh:
            for n, line in enumerate(fh, 1):
                try:
                    out.append(self.kind.record(**json.loads(line)))
                except (json.JSONDecodeError, TypeError):  # a line cut short by a kill: the rest is lost
                    logger.warning("%s: line %d is not a whole record; reading up to it", self.path, n)
                    break
        return out

    def _number(self, record: Any) -> int:
        return int(getattr(record, self.kind.number))


class RunArchive:
    """``segments.jsonl`` and ``episodes.jsonl`` in a checkpoint's directory."""

    def __init__(self, directory: str | Path, log: RunLog, keep: int = 100) -> None:
        self.keep = keep
        self.files = {k.name: RecordFile(Path(directory) / f"{k.name}.jsonl", k, log, keep) for k in KINDS}

    def add(self, log: RunLog) -> None:
        """Put ``log``'s new records on file and trim its lists in memory."""
        for f in self.files.values():
            f.add(log)

    def full(self, log: RunLog) -> RunLog:
        """``log`` with every record of the run (the files', after adding any not yet there)."""
        self.add(log)
        return RunLog(
            episodes=self.files["episodes"].read(),
            segments=self.files["segments"].read(),
            global_step=log.global_step,
        )


def _line(record: Any) -> str:
    return json.dumps(asdict(record)) + "\n"
