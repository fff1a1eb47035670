"""How old a report from the node is, and whether it is too old to be shown as current.

The node reports on its own schedule: ``diagnostics`` every ``ros.diagnostics_period_ms``
(1 s by default), decoded process data every few cycles. A screen that shows the last report
must say when that report has aged: the node may be gone (its slaves are then *not* in OP, whatever
the last report said) or stalled. :class:`Arrivals` notes when each kind of report arrived and
how far apart they came (the median of the last :data:`INTERVALS` gaps, so one late report does
not change the period); a report is **stale** once it is older than :data:`STALE_PERIODS` of
those periods (never less than :data:`MIN_STALE_S`, so a fast stream is not called stale for the
reader's own scheduling jitter). Until two reports have arrived the period is taken as
:data:`DEFAULT_PERIOD_S`, the node's default diagnostics period.

Used by the console (``states``, ``stats``, ``get``) and ``ether-ros top``.
"""

from __future__ import annotations

import statistics
import time
from collections import deque
from dataclasses import dataclass, field

STALE_PERIODS = 2.0
MIN_STALE_S = 0.5
DEFAULT_PERIOD_S = 1.0
INTERVALS = 5


@dataclass
class Arrivals:
    """Arrival times (``time.monotonic()``) of the reports, by a key the caller chooses
    (``"diagnostics"``, ``"inputs/front_left_leg"``)."""

    last: dict[str, float] = field(default_factory=dict)
    intervals: dict[str, deque[float]] = field(default_factory=dict)

    def note(self, key: str, now: float | None = None) -> None:
        now = time.monotonic() if now is None else now
        previous = self.last.get(key)
        if previous is not None and now > previous:
            self.intervals.setdefault(key, deque(maxlen=INTERVALS)).append(now - previous)
        self.last[key] = now

    def age(self, key: str, now: float | None = None) -> float | None:
        """Seconds since the last report of ``key`` (None: none arrived yet)."""
        last = self.last.get(key)
        if last is None:
            return None
        return (time.monotonic() if now is None else now) - last

    def period(self, key: str) -> float:
        """How often ``key`` arrives: the median gap of the last reports (the default before
        there are two)."""
        gaps = self.intervals.get(key)
        return statistics.median(gaps) if gaps else DEFAULT_PERIOD_S

    def stale_after(self, key: str) -> float:
        return max(STALE_PERIODS * self.period(key), MIN_STALE_S)

    def fresh(self, key: str, now: float | None = None) -> bool:
        """A report of ``key`` arrived, and it is not older than two periods."""
        age = self.age(key, now)
        return age is not None and age <= self.stale_after(key)


def describe_age(seconds: float) -> str:
    """``0.4 s``, ``12 s``, ``3 min`` — for messages."""
    if seconds < 10:
        return f"{seconds:.1f} s"
    if seconds < 120:
        return f"{seconds:.0f} s"
    return f"{seconds / 60:.0f} min"
