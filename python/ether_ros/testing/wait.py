"""Waiting for an outcome in tests: poll with a generous deadline, fail naming what did not
happen. Tests assert behaviour, never speed, so the deadline is only a guard against hangs."""

from __future__ import annotations

import time
from collections.abc import Callable


def wait_for(what: str, check: Callable[[], object], timeout: float = 15.0) -> None:
    """Return once ``check()`` is true; AssertionError naming ``what`` after ``timeout`` s."""
    deadline = time.monotonic() + timeout
    while not check():
        if time.monotonic() > deadline:
            raise AssertionError(f"timed out waiting for {what}")
        time.sleep(0.003)
