"""The truth about each axis (issue 24, item 4), on config/arm6.yaml (lease on, ``restart:
manual``): the simulator and the node in their own processes on a veth pair, the test's own
client (the lease holder), the operator console in this process on that client.

An axis stopped by the command watchdog reports ``restart_blocked`` in its diagnostic status
(WARN, with why it will not move), ``top`` shows it, and a joint command or a console ``move``
to it answers that it was not executed and why; after an explicit enable it moves again.
"""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path

import pytest

from ether_ros.console.app import Console, run_lines
from ether_ros.ros.rig import RosRig
from ether_ros.tools.live import axes_text, snapshot_from_diagnostics

pytestmark = [pytest.mark.netns, pytest.mark.ros, pytest.mark.slow]

REPO = Path(__file__).resolve().parents[2]
JOINT = "wrist_3"


@pytest.fixture(scope="module")
def rig(veth_allowed: bool) -> Iterator[RosRig]:
    if not veth_allowed:
        pytest.fail("the ROS acceptance tests need root (veth pairs)")
    with RosRig(REPO / "config" / "arm6.yaml", netns=True) as rig:
        assert rig.client.wait_for_node() == "active"
        ok, message, _ = rig.client.axis_command("enable")
        assert ok, message
        yield rig


def test_an_axis_stopped_by_the_watchdog_says_so_and_refuses_commands(rig: RosRig) -> None:
    c = rig.client
    ok, message = c.set_parameter("diagnostics_period_ms", 200)
    assert ok, message
    ok, message = c.set_parameter("command_timeout_ms", 300)
    assert ok, message
    try:
        # A velocity command and then silence: the watchdog stops the axis.
        ok, message, _ = c.set_mode("csv", [JOINT])
        assert ok, message
        c.publish_joint_command([JOINT], velocity=[0.1])
        c.wait_for(lambda _l: c.axis_states().get(JOINT, {}).get("restart_blocked") == "true", 15)
    finally:
        assert c.set_parameter("command_timeout_ms", 0)[0]
    st = c.axis_states()[JOINT]
    assert st["state"] != "operation_enabled", st
    assert st["level"] == "WARN" and "restart blocked" in st["message"], st
    assert "restart blocked" in st["blocked"], st

    # top shows it (from the same diagnostics).
    snap = snapshot_from_diagnostics({}, {}, axes=c.axis_states())
    assert "NOT MOVING: restart blocked" in axes_text(snap)

    # A joint command to it is not executed, and the answer says why.
    seen = len(c.joint_results)
    c.publish_joint_command([JOINT], velocity=[0.2])
    result = c.wait_for(lambda _l: len(c.joint_results) > seen and c.joint_results[seen], 10)
    assert not result.success
    assert "not executed" in result.message and "restart blocked" in result.message, result

    # The console's move says the same (never "sent"), and its states screen shows the axis.
    printed: list[str] = []
    with Console(c, out=printed.append) as con:
        assert run_lines(con, [f"move {JOINT} 0.2"]) == 1
        assert run_lines(con, ["states"]) == 0
    text = "\n".join(printed)
    assert "not executed" in text and "restart blocked" in text, text
    assert "sent" not in text, text
    assert f"axis {JOINT}" in text, text

    # After an explicit enable it follows commands again, and says so.
    ok, message, _ = c.axis_command("enable", [JOINT])
    assert ok, message
    c.wait_for(lambda _l: c.axis_states().get(JOINT, {}).get("blocked") == "", 10)
    printed.clear()
    with Console(c, out=printed.append) as con:
        assert run_lines(con, [f"move {JOINT} 0.0"]) == 0, printed
    assert any(line.startswith("accepted") for line in printed), printed
    ok, message, _ = c.set_mode("csp", [JOINT])
    assert ok, message
