"""The arm (config/arm6.yaml, three two-axis CiA 402 drives) moved over ROS 2 only: the
simulator and the node run as their own processes on the two ends of a veth pair (the
simulator's end in its own network namespace); this process is an ordinary rclpy client with a
ROS domain of its own. It enables the axes through the services, moves joints with
``joint_commands`` and ``joint_trajectory``, checks the drives' positions in the simulator's
physics (``probe``), injects a drive fault through the simulator's control socket and reads it
back, with its text, from the node's diagnostics."""

from __future__ import annotations

import math
import time
from collections.abc import Iterator

import pytest

from arm_ros import JOINTS, enabled_arm_rig, positions
from ether_ros.ros.client import EtherRosClient
from ether_ros.ros.rig import RosRig

pytestmark = [pytest.mark.netns, pytest.mark.ros, pytest.mark.slow]


@pytest.fixture(scope="module")
def rig(veth_allowed: bool) -> Iterator[RosRig]:
    yield from enabled_arm_rig(veth_allowed)


def reach(client: EtherRosClient, targets: dict[str, float], timeout: float = 10.0) -> None:
    deadline = time.monotonic() + timeout
    while True:
        now = positions(client)
        if all(abs(now[j] - v) < 0.01 for j, v in targets.items()):
            return
        if time.monotonic() > deadline:
            raise AssertionError(f"joints at {now}, wanted {targets}")
        time.sleep(0.05)


def refusal(client: EtherRosClient, before: int) -> str:
    client.wait_for(lambda _l: len(client.joint_results) > before, timeout=5)
    result = client.joint_results[before]
    assert not result.success
    return str(result.message)


def test_joint_states_name_every_axis(rig: RosRig) -> None:
    msg = rig.client.wait_for(lambda latest: latest.joint_state, timeout=5)
    assert list(msg.name) == JOINTS
    assert len(msg.velocity) == len(msg.effort) == len(JOINTS)


def test_joint_commands_move_the_arm(rig: RosRig) -> None:
    c = rig.client
    c.publish_joint_command(["shoulder_pan", "elbow"], position=[0.3, -0.4])
    reach(c, {"shoulder_pan": 0.3, "elbow": -0.4})


def test_bad_joint_commands_are_refused(rig: RosRig) -> None:
    c = rig.client
    before_positions = positions(c)
    for names, arrays, why in [
        (["nope"], {"position": [0.1]}, "unknown joint 'nope'"),
        (["elbow"], {"position": [math.nan]}, "not a finite number"),
        (["wrist_1", "elbow"], {"position": [0.5, 9.0]}, "outside the limits"),
        (["elbow"], {"effort": [1.0]}, "takes a position, got effort"),
    ]:
        before = len(c.joint_results)
        c.publish_joint_command(names, **arrays)
        assert why in refusal(c, before)
    time.sleep(0.3)
    assert abs(positions(c)["wrist_1"] - before_positions["wrist_1"]) < 0.01


def test_joint_trajectory_moves_the_arm_in_time(rig: RosRig) -> None:
    c = rig.client
    before = len(c.joint_results)
    c.publish_trajectory(
        ["shoulder_lift", "wrist_2"], [(0.5, [0.2, 0.3]), (1.0, [0.4, -0.2])], start=time.time()
    )
    c.wait_for(lambda _l: len(c.joint_results) > before, timeout=5)
    assert c.joint_results[before].success, c.joint_results[before].message
    reach(c, {"shoulder_lift": 0.4, "wrist_2": -0.2})
    before = len(c.joint_results)
    c.publish_trajectory(["wrist_2"], [(0.5, [0.1]), (0.4, [0.2])])
    assert "not after the previous" in refusal(c, before)


def test_services_and_an_injected_fault(rig: RosRig) -> None:
    c = rig.client
    ok, message, _ = c.set_mode("warp", ["elbow"])
    assert not ok and "unknown mode 'warp'" in message
    ok, message, _ = c.axis_command("disable", ["nope"])
    assert not ok and "nope" in message
    ok, message, states = c.set_mode("csv", ["wrist_3"])
    assert ok, message
    ok, message, states = c.set_mode("csp", ["wrist_3"])
    assert ok, message
    ok, message, states = c.axis_command("disable", ["wrist_3"])
    assert ok and states == {"wrist_3": "switch_on_disabled"}, message
    ok, message, states = c.axis_command("enable", ["wrist_3"])
    assert ok and states == {"wrist_3": "operation_enabled"}, message

    rig.sim("fault", kind="drive_fault", slave="base_drive", error="over_current", axis=2)

    def reported(_latest: object) -> dict[str, str] | None:
        st = c.axis_states().get("shoulder_lift")
        return st if st and st["last_fault_code"] == "0x2310" else None

    st = c.wait_for(reported, timeout=10)
    assert st["last_fault_text"] == "continuous over-current"
    ok, message, states = c.axis_command("reset_fault", ["shoulder_lift"])
    assert ok, message
    ok, message, states = c.axis_command("enable", ["shoulder_lift"])
    assert ok and states == {"shoulder_lift": "operation_enabled"}, message
