"""The node's diagnostics for a cable pulled on a branch: the master's status is an error naming
the location (slaves are cut off now), the slaves cut off carry it as their problem (messages
built by the real module)."""

from __future__ import annotations

from ether_ros.master.bus import SlaveState
from ether_ros.ros import diagnostics

MESSAGE = "link lost behind slave 'coupler' port 2: slaves junction, io_3 unreachable"


def test_a_broken_branch_is_reported_on_the_master_and_its_slaves() -> None:
    master = diagnostics.master_status("n", "active", {"cycles": 10}, {}, False, 0.0, [MESSAGE])
    assert master.level == diagnostics.ERROR and master.message == MESSAGE
    assert diagnostics.values_of(master)["link_problem_0"] == MESSAGE
    healthy = diagnostics.master_status("n", "active", {"cycles": 10}, {}, False, 0.0)
    assert healthy.level == diagnostics.OK
    states = [
        SlaveState("coupler", 0, 0x1001, "OP", False, 0, ""),
        SlaveState("junction", 1, 0x1002, "NO ANSWER", False, 0, "", MESSAGE),
    ]
    ok, cut = diagnostics.slave_statuses("n", states)
    assert ok.level == diagnostics.OK and "problem" not in diagnostics.values_of(ok)
    assert cut.level == diagnostics.ERROR and cut.message == MESSAGE
    assert diagnostics.values_of(cut)["problem"] == MESSAGE
