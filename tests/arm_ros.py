"""The arm (config/arm6.yaml) on a ROS rig, as the ROS acceptance tests share it: the rig with
every axis enabled, and the joints' positions read from ``joint_states`` messages *stamped*
after a given moment.

Why the stamps: on a loaded host the topic can pause for longer than a test's polling period,
and the client then keeps answering with its latest message. Two equal readings of one stale
message would call a moving arm "at rest" (and a test then saw the previous test's motion as
its own). A reading here always comes from a message taken after the moment asked for.
"""

from __future__ import annotations

import time
from collections.abc import Iterator
from pathlib import Path

import pytest

from ether_ros.ros.client import EtherRosClient
from ether_ros.ros.rig import RosRig

REPO = Path(__file__).resolve().parents[1]
ARM6 = REPO / "config" / "arm6.yaml"
JOINTS = ["shoulder_pan", "shoulder_lift", "elbow", "wrist_1", "wrist_2", "wrist_3"]


def enabled_arm_rig(veth_allowed: bool) -> Iterator[RosRig]:
    """The body of a module fixture: the arm's node and simulator, every axis enabled."""
    if not veth_allowed:
        pytest.fail("the ROS acceptance tests need root (veth pairs)")
    with RosRig(ARM6, netns=True) as rig:
        assert rig.client.wait_for_node() == "active"
        ok, message, states = rig.client.axis_command("enable")
        assert ok, message
        assert states == dict.fromkeys(JOINTS, "operation_enabled")
        yield rig


def _stamp(msg: object) -> float:
    stamp = msg.header.stamp  # type: ignore[attr-defined]
    return float(stamp.sec) + float(stamp.nanosec) * 1e-9


def stamped_positions(
    client: EtherRosClient, after: float, timeout: float = 30.0
) -> tuple[float, dict[str, float]]:
    """The first joint_states stamped at or after ``after`` (wall clock, seconds): its stamp
    and the joints' positions."""

    def fresh(latest: object) -> object:
        msg = latest.joint_state  # type: ignore[attr-defined]
        return msg if msg is not None and _stamp(msg) >= after else None

    msg = client.wait_for(fresh, timeout=timeout)
    return _stamp(msg), dict(zip(msg.name, msg.position, strict=True))  # type: ignore[attr-defined]


def positions(client: EtherRosClient) -> dict[str, float]:
    """The joints' positions from a joint_states taken after this call."""
    return stamped_positions(client, time.time())[1]


def settled(client: EtherRosClient, timeout: float = 30.0) -> dict[str, float]:
    """The positions once the arm is at rest: two joint_states stamped at least 0.1 s apart
    (both taken after this call) agree within 0.2 mrad."""
    deadline = time.monotonic() + timeout
    stamp, last = stamped_positions(client, time.time())
    while True:
        stamp, now = stamped_positions(client, stamp + 0.1)
        if all(abs(now[j] - last[j]) < 2e-4 for j in JOINTS):
            return now
        assert time.monotonic() < deadline, f"the arm does not settle: {last} → {now}"
        last = now
