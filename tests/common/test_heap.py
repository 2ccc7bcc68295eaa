"""common.heap: the allocator settings reach a process, and ``release_free_heap`` returns freed pages."""

from __future__ import annotations

import os
import subprocess
import sys

import pytest

from common.heap import ALLOCATOR_ENV

# 60 MB of 1 KB blocks (malloc, not Python's small-object pools), all freed but the newest one, which
# pins the top of the heap so that free() alone cannot shrink it: the pages stay resident until trimmed.
PROGRAM = """
from common.heap import release_free_heap
def rss():
    return int(open("/proc/self/statm").read().split()[1]) * 4096 / 1e6
blocks = [bytearray(1024) for _ in range(60_000)]
last = blocks[-1]
del blocks
before = rss()
assert release_free_heap()
print(before - rss())
"""


@pytest.mark.skipif(
    not sys.platform.startswith("linux") or os.confstr("CS_GNU_LIBC_VERSION") is None,
    reason="glibc's malloc_trim",
)
def test_freed_heap_pages_go_back_to_the_os_under_the_parts_allocator_settings():
    env = {**os.environ, **ALLOCATOR_ENV, "PYTHONPATH": os.getcwd()}
    out = subprocess.run([sys.executable, "-c", PROGRAM], env=env, capture_output=True, text=True, check=True)
    assert float(out.stdout) > 40.0, out.stdout  # MB given back of the ~60 freed
