"""How the long-running parts keep their resident memory equal to what they use (glibc's allocator).

Measured on the deployed learner (bench/soak.py; ``heaptrack -p`` on it for 11 minutes): its live heap
grew 0.34 MB (the agent's arrays at exit) while its RSS crept ~3 MB an hour. The rest was glibc keeping
freed memory: per-thread arenas and caches (Zenoh's callback threads, the checkpoint writer each touch
their own) and freed chunks between live ones that are never handed back. Two settings bound that:
fewer arenas and no per-thread cache (``ALLOCATOR_ENV``, set by the supervisor for every part unless the
user set them), and ``release_free_heap()`` after each periodic burst of allocation (a checkpoint).
Neither changes what the program computes; on a libc without ``malloc_trim`` the call does nothing.
"""

from __future__ import annotations

import ctypes
import ctypes.util
import functools

ALLOCATOR_ENV = {
    "MALLOC_ARENA_MAX": "2",  # glibc's default is 8 per core; each keeps its own free memory
    "GLIBC_TUNABLES": "glibc.malloc.tcache_count=0",  # no per-thread cache of freed chunks
}


@functools.cache
def _malloc_trim() -> ctypes._CFuncPtr | None:
    name = ctypes.util.find_library("c")
    trim = getattr(ctypes.CDLL(name), "malloc_trim", None) if name else None
    if trim is not None:
        trim.argtypes, trim.restype = [ctypes.c_size_t], ctypes.c_int
    return trim


def release_free_heap() -> bool:
    """Give the heap's free pages back to the OS (glibc ``malloc_trim(0)``); False where there is none."""
    trim = _malloc_trim()
    return bool(trim is not None and trim(0) >= 0)
