"""Waiting for an outcome in tests: poll with a generous deadline, fail naming what did not
happen. Tests assert behaviour, never speed, so the deadline is only a guard against hangs."""

from __future__ import annotations

import time
from collections.abc import Callable


def wait_for(what: str, check: Callable[[], object], timeout: float = 15.0) -> None:
    """Return once ``check()`` is true; AssertionError naming ``what`` after ``timeout`` s.
    A check that reads inputs while they are stale (``StaleInputs``: on a loaded machine the
    bus may miss cycles, or a test pulls a cable) is not true yet."""
    from ether_ros.master.bus import StaleInputs

    deadline = time.monotonic() + timeout
    stale = ""
    while True:
        try:
            if check():
                return
        except StaleInputs as exc:
            stale = f" (last: {exc})"
        if time.monotonic() > deadline:
            raise AssertionError(f"timed out waiting for {what}{stale}")
        time.sleep(0.003)
