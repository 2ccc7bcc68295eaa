"""Trace the deployed learner's Python allocations (a diagnostic for bench/soak.py's memory slope).

On ``PYTHONPATH`` this file runs in every Python process the stack starts; it acts only in the
``adaptiveh learn`` process: it starts tracemalloc, takes a base snapshot 3 minutes in, then every 5
minutes appends the 15 allocation sites that grew most since the base (and the process's RSS and traced
total) to ``$MEMTRACE_DIR/learn-<pid>.txt`` (default /tmp). If RSS grows while the traced total does
not, the growth is native (Zenoh, glibc arenas), not Python objects.

    PYTHONPATH=bench/memtrace python bench/soak.py --duration 1500
"""

import os
import sys
import threading
import time


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
        rss = int(open("/proc/self/statm").read().split()[1]) * os.sysconf("SC_PAGE_SIZE") / 1e6
        traced = tracemalloc.get_traced_memory()[0] / 1e6
        lines = [f"== {n * 5} min after the base: RSS {rss:.1f} MB, traced {traced:.1f} MB"]
        for stat in snap.compare_to(base, "traceback")[:15]:
            lines.append(f"{stat.size_diff / 1e3:9.1f} KB {stat.count_diff:7d} blocks")
            lines += ["      " + line for line in stat.traceback.format()[-6:]]
        with open(path, "a") as fh:
            fh.write("\n".join(lines) + "\n")


if "learn" in sys.argv and "--config" in sys.argv:
    threading.Thread(target=_trace, args=(os.environ.get("MEMTRACE_DIR", "/tmp"),), daemon=True).start()
