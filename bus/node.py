"""The lifecycle every part of the stack shares: a bus, a liveliness token, worker threads, one stop.

robot-io, vision, the learner and the monitor each used to carry their own copy of this (open the
session, declare the token, start threads, stop/wait/join, close, context manager). A part now says
only what differs: its topics (in ``__init__``), its worker loops (``workers``), what wakes them
(``wake``) and what it must release (``close``). ``run_until_stopped`` is the one main loop of the
``adaptiveh <part>`` commands.
"""

from __future__ import annotations

import faulthandler
import logging
import signal
import threading
import time
from collections.abc import Callable
from typing import ClassVar, Self

from bus.signing import mac_key
from bus.transport import Bus, ZenohConfig

log = logging.getLogger(__name__)


class Node:
    """One part of the stack on its own Zenoh session (or a given ``bus``, e.g. a replay's)."""

    #: The liveliness token this part declares (``adaptiveh/<robot>/alive/<alive_as>``); "" for none.
    alive_as: ClassVar[str] = ""

    def __init__(
        self,
        robot: str,
        zenoh: ZenohConfig | None = None,
        bus: Bus | None = None,
        token: str = "",
        fleet: str | None = None,
    ) -> None:
        """``token``: the stack's operator token; the part's bus signs and verifies with its key.
        ``robot``: this part's keys (``<name>/<arm>`` for an arm of a fleet ``fleet``)."""
        if bus is None and zenoh is None:
            raise ValueError("a node needs a Zenoh config or a bus")
        self.bus = bus if bus is not None else Bus.open(zenoh, robot, mac_key(token), fleet=fleet)
        self._stop = threading.Event()
        self._threads: list[threading.Thread] = []

    def declare_alive(self) -> None:
        """Declare the token last in ``__init__``: peers that watch it may act as soon as it appears."""
        if self.alive_as:
            self.bus.declare_alive(self.alive_as)

    # -- what a part defines ---------------------------------------------------------------------------
    def workers(self) -> dict[str, Callable[[], None]]:
        """Thread name -> loop; each loop returns once ``stopping`` is true."""
        return {}

    def wake(self) -> None:
        """Wake the worker loops so they see ``stopping`` at once (an Event or Condition they wait on)."""

    def close(self) -> None:
        """Release what the part holds; the base closes the bus (and with it the Zenoh session)."""
        self.bus.close()

    # -- the same for every part -----------------------------------------------------------------------
    @property
    def stopping(self) -> bool:
        return self._stop.is_set()

    def start(self) -> Self:
        for name, loop in self.workers().items():
            thread = threading.Thread(target=loop, name=name, daemon=True)
            thread.start()
            self._threads.append(thread)
        return self

    def request_stop(self) -> None:
        """Ask the loops to end (safe from any thread, never blocks)."""
        self._stop.set()
        self.wake()

    def wait(self, timeout: float | None = None) -> bool:
        """True once a stop was requested (within ``timeout`` s)."""
        return self._stop.wait(timeout)

    def stop(self) -> None:
        self.request_stop()
        for thread in self._threads:
            thread.join(timeout=5.0)
            if thread.is_alive():
                log.warning("%s did not stop within 5 s", thread.name)
        self._threads.clear()
        self.close()

    def __enter__(self) -> Self:
        return self.start()

    def __exit__(self, *exc: object) -> None:
        self.stop()


STOP_DEADLINE_S = 10.0
"""A part told to stop exits within this many seconds, or dumps every thread's stack to its log and exits
with status 1 (``faulthandler``: a C watchdog, it fires even while Python is stuck). Each worker gets 5 s
to end, then the bus and the driver are closed; a close that never returns (a Zenoh session, a driver's
disconnect) must not leave an orphan on the bus beside the arm with nobody left to stop it."""


def exit_within(deadline_s: float | None) -> None:
    """From now on, the process ends within ``deadline_s`` s whatever it is doing (None: no limit).

    Armed once: a second signal does not move the deadline."""
    if deadline_s is None or _exit_armed.is_set():
        return
    _exit_armed.set()
    faulthandler.dump_traceback_later(deadline_s, exit=True)


_exit_armed = threading.Event()


def on_stop_signal(action: Callable[[], None], *signums: int, deadline_s: float | None = None) -> None:
    """Run ``action`` (e.g. ``node.request_stop``) when one of ``signums`` arrives, on its own thread;
    with ``deadline_s``, the process exits that long after the signal whether or not it has stopped.

    A handler runs in the main thread between two bytecodes, possibly while that thread holds a lock
    inside ``Event.wait``; setting an Event from the handler itself can then deadlock (seen: robot-io
    hung for good on SIGTERM after its supervisor was killed). The handler only starts a thread.
    """

    def stop() -> None:
        exit_within(deadline_s)
        action()

    def handler(signum: int, frame: object) -> None:
        threading.Thread(target=stop, name=f"on-signal-{signum}", daemon=True).start()

    for signum in signums:
        signal.signal(signum, handler)


def run_until_stopped(
    node: Node,
    duration: float = 0.0,
    signums: tuple[int, ...] = (signal.SIGTERM, signal.SIGINT),
    deadline_s: float = STOP_DEADLINE_S,
) -> None:
    """Start ``node``, run until a signal, ``request_stop`` or ``duration`` s (0: no limit), then stop it
    and exit within ``deadline_s``."""
    on_stop_signal(node.request_stop, *signums, deadline_s=deadline_s)
    node.start()
    deadline = time.monotonic() + duration if duration > 0 else float("inf")
    try:
        while not node.wait(min(0.5, max(0.0, deadline - time.monotonic()))):  # short waits: signals run
            if time.monotonic() >= deadline:
                break
    finally:
        exit_within(deadline_s)
        node.stop()
