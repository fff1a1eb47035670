"""The truth about each axis (issue 24, item 4), on config/arm6.yaml (lease on, ``restart:
manual``): the simulator and the node in their own processes on a veth pair, the test's own
client (the lease holder), the operator console in this process on that client.

An axis stopped by the command watchdog reports ``restart_blocked`` in its diagnostic status
(WARN, with why it will not move) while the stop lasts and "disabled by the command watchdog"
after it, ``top`` shows it, and a joint command or a console ``move`` to it answers that it was
not executed and why; after an explicit enable it moves again.
"""

from __future__ import annotations

from collections.abc import Callable, Iterator
from typing import Any

import pytest

from arm_ros import enabled_arm_rig
from ether_ros.console.app import Console, run_lines
from ether_ros.ros.rig import RosRig
from ether_ros.tools.live import axes_text, snapshot_from_diagnostics

pytestmark = [pytest.mark.netns, pytest.mark.ros, pytest.mark.slow]

JOINT = "wrist_3"


@pytest.fixture(scope="module")
def rig(veth_allowed: bool) -> Iterator[RosRig]:
    yield from enabled_arm_rig(veth_allowed)


def refusal(c: Any, publish: Callable[[], None]) -> str:
    seen = len(c.joint_results)
    publish()
    result = c.wait_for(lambda _l: len(c.joint_results) > seen and c.joint_results[seen], 10)
    assert not result.success, result
    return str(result.message)


def extras_state(c: Any, joint: str, condition: Callable[[dict[str, Any]], bool]) -> dict[str, Any]:
    """The per-axis state of ``joint`` from the next ``joint_extras`` (issue 24: each axis's
    state beside its extras) that satisfies ``condition``; the arrays are parallel and name
    every axis of the bus."""

    def entry(latest: Any) -> dict[str, Any] | None:
        msg = latest.joint_extras
        if msg is None or joint not in msg.axes:
            return None
        fields = ("states", "enable_wanted", "mode_reached", "restart_blocked", "limit_active",
                  "outside_limits", "stopped_by", "blocked")  # fmt: skip
        assert all(len(getattr(msg, f)) == len(msg.axes) for f in fields), msg
        i = list(msg.axes).index(joint)
        e = {f: getattr(msg, f)[i] for f in fields}
        e["axes"] = list(msg.axes)
        return e if condition(e) else None

    return dict(c.wait_for(entry, 15))


def console_says(c: Any, *lines: str) -> str:
    printed: list[str] = []
    with Console(c, out=printed.append) as con:
        for line in lines:
            run_lines(con, [line])
    return "\n".join(printed)


def test_an_axis_stopped_by_the_watchdog_says_so_and_refuses_commands(rig: RosRig) -> None:
    c = rig.client
    ok, message = c.set_parameter("diagnostics_period_ms", 200)
    assert ok, message
    ok, message = c.set_parameter("command_timeout_ms", 300)
    assert ok, message
    try:
        # A velocity command and then silence: the watchdog stops the axis, and it waits for
        # an explicit enable (restart: manual) while the stop lasts.
        ok, message, _ = c.set_mode("csv", [JOINT])
        assert ok, message
        c.publish_joint_command([JOINT], velocity=[0.1])
        c.wait_for(lambda _l: c.axis_states().get(JOINT, {}).get("restart_blocked") == "true", 15)
        st = c.axis_states()[JOINT]
        assert st["state"] != "operation_enabled", st
        assert st["level"] == "WARN" and "restart blocked" in st["message"], st
        assert "restart blocked: stopped by the command watchdog" in st["blocked"], st
        assert st["stopped_by"] == "the command watchdog", st
        # joint_extras carries the same state (a separate rclpy client: this process).
        e = extras_state(c, JOINT, lambda e: e["restart_blocked"])
        assert e["stopped_by"] == "the command watchdog", e
        assert "restart blocked: stopped by the command watchdog" in e["blocked"], e
        assert e["enable_wanted"] and e["states"] != "operation_enabled", e
        assert e["axes"][-1] == JOINT and len(e["axes"]) == 6, e

        # top shows it (from the same diagnostics).
        snap = snapshot_from_diagnostics({}, {}, axes=c.axis_states())
        assert "NOT MOVING: restart blocked" in axes_text(snap)

        # A joint command to it is not executed, and the answer says why.
        why = refusal(c, lambda: c.publish_joint_command([JOINT], velocity=[0.2]))
        assert "not executed" in why and "restart blocked" in why, why
        # The console's move says the same (never "sent"); its states screen shows the axis.
        text = console_says(c, f"move {JOINT} 0.2", "states")
        assert "not executed" in text and "restart blocked" in text, text
        assert "sent" not in text, text
        assert f"axis {JOINT}" in text, text
    finally:
        assert c.set_parameter("command_timeout_ms", 0)[0]

    # Once the stop is over the axis is still disabled (restart blocked, or its enable voided
    # by the engine at the next command), and still says by what.
    c.wait_for(lambda _l: c.axis_states().get(JOINT, {}).get("halted") == "false", 15)
    st = c.axis_states()[JOINT]
    assert "by the command watchdog" in st["blocked"], st
    assert st["level"] == "WARN", st
    why = refusal(c, lambda: c.publish_joint_command([JOINT], velocity=[0.2]))
    assert "not executed" in why and "by the command watchdog" in why, why
    text = console_says(c, f"move {JOINT} 0.2")
    assert "not executed" in text and "by the command watchdog" in text, text

    # After an explicit enable it follows commands again, and says so.
    ok, message, _ = c.axis_command("enable")
    assert ok, message
    c.wait_for(lambda _l: c.axis_states().get(JOINT, {}).get("blocked") == "", 10)
    text = console_says(c, f"move {JOINT} 0.0")
    assert text.startswith("accepted"), text
    ok, message, _ = c.set_mode("csp", [JOINT])
    assert ok, message


def test_a_native_joint_command_to_a_blocked_axis_is_refused_and_never_applied(
    rig: RosRig,
) -> None:
    """The native path (crates/commands) refuses a joint command for an axis that cannot move
    by itself, from the state the RT thread published last cycle — not after the node's
    20 ms axis watch — answering "not executed" with the reason; nothing of it reaches the
    axis, not even after the axis is enabled again."""
    c = rig.client
    ok, message = c.set_parameter("diagnostics_period_ms", 200)
    assert ok, message
    ok, message, _ = c.set_mode("csp", [JOINT])
    assert ok, message
    ok, message, _ = c.axis_command("disable", [JOINT])
    assert ok, message
    c.wait_for(lambda _l: c.axis_states().get(JOINT, {}).get("state") == "switch_on_disabled", 15)
    c.wait_for(lambda _l: "ros_joint_commands_refused_blocked" in c.master_status(), 15)
    e = extras_state(c, JOINT, lambda e: e["states"] == "switch_on_disabled")
    assert not e["enable_wanted"] and not e["restart_blocked"] and e["stopped_by"] == "", e
    assert e["blocked"] == "not enabled (switch_on_disabled): enable it first", e
    before = c.master_status()
    here = float(c.axis_states()[JOINT]["position"])
    why = refusal(c, lambda: c.publish_joint_command([JOINT], position=[here + 0.3]))
    assert why == (
        f"joint_commands refused: joint '{JOINT}' not executed: not enabled "
        "(switch_on_disabled): enable it first"
    ), why
    # Refused by the native receiver itself (its counter), not handed to Python.
    c.wait_for(
        lambda _l: (
            int(float(c.master_status()["ros_joint_commands_refused_blocked"]))
            > int(float(before["ros_joint_commands_refused_blocked"]))
        ),
        10,
    )
    after = c.master_status()
    assert after["ros_joint_commands_deferred"] == before["ros_joint_commands_deferred"], after
    assert after["ros_joint_commands_native"] == before["ros_joint_commands_native"], after
    # Enabled again, the axis holds where it is: the refused setpoint was never applied.
    ok, message, _ = c.axis_command("enable", [JOINT])
    assert ok, message
    c.wait_for(lambda _l: c.axis_states().get(JOINT, {}).get("blocked") == "", 10)
    c.wait_for(lambda _l: c.axis_states()[JOINT]["state"] == "operation_enabled", 10)
    e = extras_state(c, JOINT, lambda e: e["states"] == "operation_enabled")
    assert e["enable_wanted"] and e["mode_reached"] and e["blocked"] == "", e
    assert not e["limit_active"] and not e["outside_limits"], e
    st = c.axis_states()[JOINT]
    assert abs(float(st["target_position"]) - here) < 0.01, (st, here)
    assert abs(float(st["position"]) - here) < 0.01, (st, here)
