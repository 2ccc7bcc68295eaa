"""One way for a test to wait on something another thread or process does: poll a condition until it
holds or a deadline passes, then fail saying what was awaited. Imported by name (tests/ is not a
package)."""

from __future__ import annotations

import time
from collections.abc import Callable
from typing import Any


def wait_until(
    pred: Callable[[], Any],
    timeout: float = 5.0,
    what: str | Callable[[], str] = "the condition",
    every: float = 0.01,
) -> Any:
    """``pred()``'s first truthy value; AssertionError after ``timeout`` s naming ``what`` (a callable is
    asked then, so the message can show the state the test saw at the end)."""
    deadline = time.monotonic() + timeout
    while True:
        out = pred()
        if out:
            return out
        if time.monotonic() >= deadline:
            said = what() if callable(what) else what
            raise AssertionError(f"timed out after {timeout} s waiting for {said}")
        time.sleep(every)
