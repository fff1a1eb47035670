"""Killing the node (SIGKILL: no deactivation, no safe image sent) must still leave the slaves
safe: their process-data watchdog expires, they drop out of OP and their firmware stops driving
the motors. Checked in the simulated slaves, which run in their own process and namespace."""

from __future__ import annotations

import time
from pathlib import Path

import pytest

from ether_ros.ros.client import make_write
from ether_ros.ros.rig import RosRig

pytestmark = [pytest.mark.netns, pytest.mark.ros, pytest.mark.slow]

REPO = Path(__file__).resolve().parents[2]
LEGS = range(4)
OP, SAFEOP = 0x08, 0x04


def _wait(predicate: object, timeout: float, what: str) -> None:
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        if predicate():  # type: ignore[operator]
            return
        time.sleep(0.05)
    raise AssertionError(f"timed out waiting for {what}")


def test_killed_node_leaves_slaves_safe_through_their_watchdog(veth_allowed: bool) -> None:
    if not veth_allowed:
        pytest.fail("needs root (veth pairs)")
    with RosRig(REPO / "config" / "laelaps.yaml", netns=True) as rig:
        c = rig.client
        assert c.wait_for_node() == "active"
        c.layout(timeout=10)
        # Operational with stiff gains and a lifted foot: the motors are working.
        writes = [
            make_write("all", name, value)
            for name, value in (
                ("Kp100_knee", 8000),
                ("Kp100_hip", 8000),
                ("Kd1000_knee", 50),
                ("Kd1000_hip", 50),
                ("y_cntr_traj1000", 560),
                ("traj_freq100", 100),
                ("Transition_time", 1),
                ("State_Machine", 1),
            )
        ]
        ok, message = c.write_many(writes)
        assert ok, message

        def driving() -> bool:
            return all(
                rig.sim("slave_info", slave=i)["al_state"] == OP
                and abs(rig.sim("probe", slave=i)["pwm_knee"]) > 0.0
                for i in LEGS
            )

        _wait(driving, 15, "all legs in OP with the knee motors driven")

        assert rig.node_proc is not None
        rig.node_proc.kill()  # no SIGINT: nothing gets the chance to send safe outputs
        rig.node_proc.wait(10)

        def safe() -> bool:
            for i in LEGS:
                info = rig.sim("slave_info", slave=i)
                probe = rig.sim("probe", slave=i)
                if not (info["watchdog_expired"] and info["al_state"] == SAFEOP):
                    return False
                if probe["pwm_knee"] != 0.0 or probe["pwm_hip"] != 0.0:
                    return False
            return True

        _wait(safe, 10, "every slave's watchdog to expire and its motors to stop")
        # Real ESCs report the expiry as an error with AL status code 0x001B (SM watchdog).
        for i in LEGS:
            info = rig.sim("slave_info", slave=i)
            assert info["al_error"] and info["al_status_code"] == 0x001B
