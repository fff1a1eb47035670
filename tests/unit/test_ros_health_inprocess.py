"""The node tells the truth about a bus that goes down (issue 19, item 5), on the in-process
simulator: while the master's cable is pulled the master's diagnostics are ERROR ("the bus is
down"), ``pdo_in`` flags its values as stale and ``joint_states`` stops; once the cable is back
the data is fresh again and, after the diagnostics window, the level is no longer ERROR (OK, or
WARN when the loaded machine itself loses frames) while the totals keep counting what was
lost."""

from __future__ import annotations

from typing import Any

import pytest
from test_ros_node_inprocess import running_node

from ether_ros._native import Link

# netns: the bus runs with its configuration's realtime section (SCHED_FIFO, locked memory).
pytestmark = [pytest.mark.ros, pytest.mark.netns]


def master(latest: Any) -> Any:
    diag = latest.diagnostics
    for st in diag.status if diag is not None else []:
        if st.name.endswith(": master"):
            return st
    return None


def test_a_bus_going_down_shows_as_stale_data_and_an_error() -> None:
    from diagnostic_msgs.msg import DiagnosticStatus

    inputs: list[Any] = []
    with running_node(11, client_options={"on_inputs": inputs.append}) as (_node, client, net):
        assert client.set_parameter("diagnostics_window_ms", 2000)[0]
        assert client.command("start")[0]
        client.wait_for(lambda latest: latest.counts.get("joint_states", 0) > 5, timeout=20)
        client.wait_for(
            lambda latest: (m := master(latest)) and m.level != DiagnosticStatus.ERROR, timeout=20
        )
        assert inputs and not any(m.stale for m in inputs)
        net.inject(Link(up=False))  # type: ignore[attr-defined]
        down = client.wait_for(
            lambda latest: (m := master(latest)) and m.level == DiagnosticStatus.ERROR and m,
            timeout=15,
        )
        assert down.message.startswith("the bus is down"), down.message
        client.wait_for(lambda _l: inputs and inputs[-1].stale, timeout=15)
        # joint_states stops: no message while every joint's inputs are stale.
        seen = client.latest.counts.get("joint_states", 0)
        stale_from = len(inputs)
        client.wait_for(lambda _l: len(inputs) > stale_from + 40, timeout=20)
        assert all(m.stale for m in inputs[stale_from:])
        assert client.latest.counts.get("joint_states", 0) <= seen + 1
        net.inject(Link(up=True))  # type: ignore[attr-defined]
        client.wait_for(lambda _l: not inputs[-1].stale, timeout=15)
        client.wait_for(lambda latest: latest.counts.get("joint_states", 0) > seen + 5, timeout=15)
        back = client.wait_for(
            lambda latest: (m := master(latest)) and m.level != DiagnosticStatus.ERROR and m,
            timeout=30,
        )
        values = {kv.key: kv.value for kv in back.values}
        assert int(values["lost_frames"]) > 0  # the totals remember
        assert values["stale_frames"] == ""
