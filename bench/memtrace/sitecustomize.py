"""Where the deployed learner's memory goes (a diagnostic for bench/soak.py's memory slope).

On ``PYTHONPATH`` this file runs in every Python process the stack starts; it acts only in the
``adaptiveh learn`` process. ``MEMTRACE_MODE=heap`` (default) appends a line a minute to
``$MEMTRACE_DIR/heap-<pid>.txt`` (default /tmp): RSS, glibc's heap (``mallinfo2``: arena, in use, free,
mmapped) and Python's object allocator (pymalloc arenas of 1 MiB, from ``sys._debugmallocstats``), so a
growth shows as heap in use (allocations), heap free (glibc keeping freed memory), or arenas (pymalloc
pools pinned by a few live objects). ``MEMTRACE_MODE=tracemalloc``: the 15 Python allocation sites that
grew most every 5 minutes since a base snapshot 3 minutes in (``learn-<pid>.txt``). For native
allocations with backtraces: ``heaptrack -p <pid of the learn process>``.

    PYTHONPATH=bench/memtrace python bench/soak.py --duration 1500

Measured at 91ad0b8's parent (heap mode, 25 min): RSS +5.7 MB, glibc arena +4.6 (in use +2.1, free +2.6),
Python objects flat; heaptrack over 11 min: 342 KB of new allocations still live at exit.
"""

import ctypes
import os
import sys
import threading
import time


class _MallInfo2(ctypes.Structure):
    _fields_ = [
        (name, ctypes.c_size_t)
        for name in (
            "arena",
            "ordblks",
            "smblks",
            "hblks",
            "hblkhd",
            "usmblks",
            "fsmblks",
            "uordblks",
            "fordblks",
            "keepcost",
        )
    ]


def _rss_mb() -> float:
    return int(open("/proc/self/statm").read().split()[1]) * os.sysconf("SC_PAGE_SIZE") / 1e6


def _pymalloc_arenas() -> int:
    """Python's allocated object arenas (``_debugmallocstats`` writes to fd 2: read it through a pipe)."""
    r, w = os.pipe()
    saved = os.dup(2)
    try:
        os.dup2(w, 2)
        sys._debugmallocstats()
    finally:
        os.dup2(saved, 2)
        os.close(saved)
        os.close(w)
    with os.fdopen(r) as fh:
        for line in fh:
            if line.startswith("# arenas allocated current"):
                return int(line.split("=")[1].replace(",", ""))
    return -1


def _heap(out_dir: str) -> None:
    libc = ctypes.CDLL("libc.so.6")
    libc.mallinfo2.restype = _MallInfo2
    path = os.path.join(out_dir, f"heap-{os.getpid()}.txt")
    t0 = time.monotonic()
    while True:
        time.sleep(60)
        mi = libc.mallinfo2()
        line = (
            f"{time.monotonic() - t0:7.0f} s  rss {_rss_mb():7.2f}  heap {mi.arena / 1e6:6.2f} "
            f"in-use {mi.uordblks / 1e6:6.2f} free {mi.fordblks / 1e6:6.2f} mmap {mi.hblkhd / 1e6:6.2f} MB  "
            f"pymalloc arenas {_pymalloc_arenas()}"
        )
        with open(path, "a") as fh:
            fh.write(line + "\n")


def _trace(out_dir: str) -> None:
    import tracemalloc

    tracemalloc.start(12)
    time.sleep(180)
    base = tracemalloc.take_snapshot()
    path = os.path.join(out_dir, f"learn-{os.getpid()}.txt")
    n = 0
    while True:
        time.sleep(300)
        n += 1
        snap = tracemalloc.take_snapshot()
        traced = tracemalloc.get_traced_memory()[0] / 1e6
        lines = [f"== {n * 5} min after the base: RSS {_rss_mb():.1f} MB, traced {traced:.1f} MB"]
        for stat in snap.compare_to(base, "traceback")[:15]:
            lines.append(f"{stat.size_diff / 1e3:9.1f} KB {stat.count_diff:7d} blocks")
            lines += ["      " + line for line in stat.traceback.format()[-6:]]
        with open(path, "a") as fh:
            fh.write("\n".join(lines) + "\n")


if "learn" in sys.argv and "--config" in sys.argv:
    watch = _trace if os.environ.get("MEMTRACE_MODE") == "tracemalloc" else _heap
    threading.Thread(target=watch, args=(os.environ.get("MEMTRACE_DIR", "/tmp"),), daemon=True).start()
