import numpy as np

from robot_io.action_queue import ActionQueue, ChunkLabel, ChunkReport


def chunk(n: int, value: float = 0.01) -> np.ndarray:
    return np.full((n, 3), value)


def test_plays_in_order_and_reports_progress():
    q = ActionQueue()
    assert q.push(1, np.arange(9, dtype=float).reshape(3, 3))
    assert [q.pop()[0] for _ in range(3)] == [0.0, 3.0, 6.0]
    assert q.pop() is None
    reports = q.reports()
    assert [r.executed for r in reports] == [1, 2, 3]
    assert reports[-1] == ChunkReport(1, 3, 0, -1, True)


def test_newer_chunk_preempts_and_reports_dropped():
    q = ActionQueue()
    old, new = ChunkLabel(segment=3, opening=2), ChunkLabel(segment=4, opening=3)
    q.push(1, chunk(10), label=old)
    for _ in range(4):
        q.pop()
    q.reports()
    assert q.push(2, chunk(5, 0.02), label=new)
    # The report echoes both chunks' labels: which segment was cut, and why the one that cut it was made.
    assert q.reports() == [ChunkReport(1, 4, 6, preempted_by=2, done=True, label=old, preempted_by_label=new)]
    assert len(q) == 5 and q.chunk_seq == 2
    np.testing.assert_allclose(q.pop(), [0.02] * 3)
    q.clear()
    assert q.reports()[-1].preempted_by_label is None  # cleared (an e-stop): no chunk preempted it


def test_stale_chunk_is_ignored():
    q = ActionQueue()
    q.push(5, chunk(3))
    assert not q.push(4, chunk(3))
    assert not q.push(5, chunk(3))
    assert q.chunk_seq == 5 and len(q) == 3


def test_clear_reports_dropped():
    q = ActionQueue()
    q.push(1, chunk(3))
    q.pop()
    q.reports()
    assert q.clear() == 2
    assert q.reports() == [ChunkReport(1, 1, 2, preempted_by=-1, done=True)]
    assert q.clear() == 0 and q.reports() == []
