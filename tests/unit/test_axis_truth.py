"""The truth about each axis (issue 24, item 4), from an ``Axis.status()``: why it cannot move
(``bridge.axis_blocker``), its diagnostic status (restart blocked is WARN, not OK) and top's
line. The end-to-end check on the simulated arm is tests/acceptance/test_ros_axis_truth.py."""

from __future__ import annotations

from typing import Any

import pytest

from ether_ros.ros import bridge, diagnostics
from ether_ros.tools.live import axes_text, axis_row, snapshot_from_diagnostics


def status(**changes: Any) -> dict[str, Any]:
    st: dict[str, Any] = {
        "state": "operation_enabled", "mode_display": "csp", "mode_display_code": 8,
        "statusword": 0x1237, "error_code": 0, "last_fault_code": 0, "position": 0.1,
        "velocity": 0.0, "torque": 0.0, "following_error": 0.0, "target_position": 0.1,
        "position_clamps": 0, "velocity_clamps": 0, "torque_clamps": 0, "faults": 0,
        "fault_resets": 0, "following_error_exceeded": False, "retries_exhausted": False,
        "halted": False, "restart_blocked": False, "enable_wanted": True, "mode_reached": True,
        "limit_active": False, "outside_limits": False,
    }  # fmt: skip
    st.update(changes)
    return st


@pytest.mark.parametrize(
    ("changes", "panic", "why"),
    [
        ({}, False, ""),
        ({"halted": True}, False, ""),  # the watchdog's halt alone: the next command ends it
        ({"limit_active": True}, False, ""),  # clamped, but it follows setpoints
        ({"state": "switch_on_disabled", "restart_blocked": True}, False, "restart blocked"),
        ({"state": "switch_on_disabled"}, False, "not enabled (switch_on_disabled)"),
        ({"state": "fault", "error_code": 0x2310}, False, "in fault (0x2310 "),
        ({}, True, "the bus is in panic"),
        ({"mode_reached": False, "mode_display": "csv"}, False, "mode csp not reached"),
    ],
)
def test_why_an_axis_cannot_move(changes: dict[str, Any], panic: bool, why: str) -> None:
    found = bridge.axis_blocker(status(**changes), "csp", panic)
    assert (why in found) if why else found == "", found


def test_a_restart_blocked_axis_is_not_ok_in_the_diagnostics() -> None:
    st = status(state="switch_on_disabled", restart_blocked=True, enable_wanted=True)
    (d,) = diagnostics.axis_statuses("ether_comm", [("elbow", "csp", st)])
    values = diagnostics.values_of(d)
    assert d.level == diagnostics.WARN
    assert d.message.startswith("restart blocked"), d.message
    assert values["restart_blocked"] == "true"
    assert "waiting for an explicit enable" in values["blocked"]
    # Enabled and following: OK, nothing blocks it.
    (d,) = diagnostics.axis_statuses("ether_comm", [("elbow", "csp", status())])
    assert d.level == diagnostics.OK and diagnostics.values_of(d)["blocked"] == ""
    # At a limit: WARN, it says so.
    (d,) = diagnostics.axis_statuses("ether_comm", [("elbow", "csp", status(limit_active=True))])
    assert d.level == diagnostics.WARN and "at a limit" in d.message
    # In panic every axis says so.
    (d,) = diagnostics.axis_statuses("ether_comm", [("elbow", "csp", status())], panic=True)
    assert d.level == diagnostics.WARN and "panic" in d.message


def test_top_says_which_axes_will_not_move() -> None:
    blocked = status(state="switch_on_disabled", restart_blocked=True)
    (d,) = diagnostics.axis_statuses("ether_comm", [("elbow", "csp", blocked)])
    (ok,) = diagnostics.axis_statuses("ether_comm", [("wrist", "csp", status(limit_active=True))])
    snap = snapshot_from_diagnostics(
        {}, {}, axes={"elbow": diagnostics.values_of(d), "wrist": diagnostics.values_of(ok)}
    )
    lines = axes_text(snap).splitlines()
    assert "NOT MOVING: restart blocked" in lines[1], lines
    assert lines[2].rstrip().endswith("at a limit"), lines
    # The same from a bus top opened itself.
    assert axis_row("elbow", "csp", blocked).note.startswith("NOT MOVING: restart blocked")
    assert axis_row("elbow", "csp", status()).note == ""
