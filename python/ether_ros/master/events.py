"""What the master reports about the bus while it runs (supervision events), for listeners
such as the ROS node's diagnostics. Its own module so that the bus (which delivers events) and
the supervisor (which finds them) both depend on it and not on each other."""

from __future__ import annotations

import time
from dataclasses import dataclass, field


@dataclass(frozen=True)
class BusEvent:
    """Something the supervisor noticed. ``kind``: slave_lost, slave_recovered,
    recovery_failed, wkc_error, link_lost, link_restored, branch_lost, branch_restored,
    emergency."""

    kind: str
    slave: str | None
    message: str
    time: float = field(default_factory=time.time)
