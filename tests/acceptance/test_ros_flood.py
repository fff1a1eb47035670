"""No starvation (issue 19, item 3): publishers flooding the node, each a process of its own
(tests/ros_actor.py), do not keep another client's valid commands from reaching the drives and
the slaves, nor the node's services from answering — a client that connects during the flood
included. Behaviour only: the latency under a flood is measured by bench/bench_flood.py.

- config/arm6.yaml with the lease off (a copy): invalid ``joint_commands`` (unknown joints and
  garbage, which the native path refuses by itself, and values beyond the limits, which it
  leaves to Python through the fair queue, at most 200 per second per publisher, so that the
  flood cannot starve the Python thread feeding the engine's command watchdog) and garbage on
  ``pdo_listener``;
- config/laelaps.yaml with the lease on: floods from publishers that do not hold it.
"""

from __future__ import annotations

import math
import os
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest
from test_ros_lease import Actor, on_wire

from ether_ros.ros.rig import RosRig
from ether_ros.testing.configs import config_with_lease_ttl, config_without_lease

pytestmark = [pytest.mark.netns, pytest.mark.ros]

REPO = Path(__file__).resolve().parents[2]
JOINT = "elbow"


@pytest.fixture
def arm_without_lease(tmp_path: Path) -> Path:
    return config_without_lease("arm6.yaml", tmp_path)


@pytest.fixture
def floods() -> Iterator[list[Actor]]:
    actors: list[Actor] = []
    yield actors
    for a in actors:
        a.close()


def flood(rig: RosRig, actors: list[Actor], topic: str, kind: str) -> Actor:
    a = Actor(rig, f"flood_{len(actors)}")
    actors.append(a)
    assert a("flood", topic=topic, kind=kind)["ok"]
    return a


def joint_position(latest: Any) -> float:
    js = latest.joint_state
    if js is None or JOINT not in js.name:
        return math.nan
    return float(js.position[list(js.name).index(JOINT)])


@pytest.mark.parametrize(
    "kinds",
    [
        # refused natively: unknown joints, garbage on both topics
        [("joint_commands", "unknown"), ("joint_commands", "garbage"), ("pdo_listener", "garbage")],
        # unknown joints (native), values beyond the limits (Python, fairly queued and at most
        # DEFERRALS_PER_S per publisher: the rest refused natively), garbage
        [("joint_commands", "unknown"), ("joint_commands", "limit"), ("pdo_listener", "garbage")],
    ],
    ids=["refused-natively", "left-to-python"],
)  # fmt: skip
def test_a_joint_moves_and_services_answer_under_invalid_floods(
    arm_without_lease: Path, floods: list[Actor], kinds: list[tuple[str, str]]
) -> None:
    if os.geteuid() != 0:
        pytest.skip("needs root (veth pairs)")
    with RosRig(arm_without_lease, netns=True) as rig:
        client = rig.client
        client.wait_for_node()
        ok, message, _ = client.axis_command("enable", [JOINT])
        assert ok, message
        flooders = [flood(rig, floods, topic, kind) for topic, kind in kinds]
        client.wait_for(lambda _l: all(f("flood_count")["sent"] > 1000 for f in flooders), 120)
        for target in (0.3, -0.2, 0.1):
            client.publish_joint_command([JOINT], position=[target])
            client.wait_for(lambda latest, t=target: abs(joint_position(latest) - t) < 0.02, 60)
        # Services answer, on the lifecycle node and on the command node.
        assert client.get_state(timeout=60) == "active"
        assert client.sdo_read("base_drive", 0x1000, 0, "UDINT", timeout=60).success
        # A client that connects now is answered as well.
        newcomer = Actor(rig, "newcomer")
        floods.append(newcomer)
        assert newcomer("lease", action="status")["ok"]
        assert newcomer("command", command="reset_watchdog")["ok"]
        counters = client.master_status()
        assert int(float(counters["ros_joint_commands_refused"])) > 0
        if ("joint_commands", "limit") in kinds:  # Python took its share, the rest was refused
            assert int(float(counters["ros_joint_commands_deferred"])) > 0
            assert int(float(counters["ros_joint_commands_refused_throttled"])) > 0
        assert all(f("flood_count")["sent"] > 5000 for f in flooders)


def test_writes_reach_the_wire_while_non_holders_flood(floods: list[Actor], tmp_path: Path) -> None:
    if os.geteuid() != 0:
        pytest.skip("needs root (veth pairs)")
    # The lease's time to live is raised from 3 s: the floods load the host so that the test
    # client's renewals may stall past 3 s, and the lease then lapses as it must (motion stops,
    # the writes are refused as "lapsed") — not what this test is about.
    config = config_with_lease_ttl("laelaps.yaml", tmp_path, ttl_s=30.0)
    with RosRig(config, netns=True) as rig:
        client = rig.client
        client.wait_for_node()
        assert client.write("front_left_leg", "Kp100_knee", 100)[0]  # takes the lease
        flooders = [
            flood(rig, floods, "pdo_listener", "text"),
            flood(rig, floods, "pdo_listener", "garbage"),
            flood(rig, floods, "joint_commands", "unknown"),
        ]
        client.wait_for(lambda _l: all(f("flood_count")["sent"] > 1000 for f in flooders), 120)
        for value in (2001, 2002, 2003):
            result = client.wait_result(
                client.publish_write("front_left_leg", "Kp100_knee", value), timeout=120
            )
            assert result.success, result.message
            on_wire(rig, "Kp100_knee", value, timeout=120)
        ok, message = client.write("hind_left_leg", "Kp100_hip", 321, timeout=60)
        assert ok, message
        on_wire(rig, "Kp100_hip", 321, slave="hind_left_leg", timeout=120)
        assert client.panic(timeout=60)[0]
        assert client.command("clear_panic", timeout=60)[0]
        status = client.master_status()
        assert int(float(status["ros_commands_refused_lease"])) > 0
