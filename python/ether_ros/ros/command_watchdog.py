"""When the node's commanders go quiet (``command_timeout_ms``), does anything on the bus need a
live commander? The engine's command watchdog stops the bus when the node stops feeding it
(docs/ros.md, "Safety"); the node stops feeding it only when that silence could leave something
moving or driven that nobody commands any more.
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping
from typing import Any


def quiet_is_safe(axis_statuses: Iterable[Mapping[str, Any]], variables_written: bool) -> bool:
    """True when a silence of the commanders needs no stop: no output variable has been written
    since the node went active (a bus whose process data someone commands through
    ``pdo_listener``/``write_variables`` keeps the watchdog's meaning: no writes, safe outputs),
    and every CiA 402 axis either runs a trajectory (a command the engine carries out to its end:
    a controller that waits for it, or topic_based_ros2_control that stops publishing once the
    joints reached their targets, are not stopped) or is idle (not enabled, or holding still:
    no trajectory, its last setpoint reached, zero velocity or torque)."""
    if variables_written:
        return False
    statuses = list(axis_statuses)
    return bool(statuses) and all(
        bool(st["trajectory_active"]) or bool(st["idle"]) for st in statuses
    )
