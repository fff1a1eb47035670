"""CiA 402 axes as ROS joints, with the node and the simulator's cia402 drives in one process
(config/arm6.yaml): joint_states, joint_commands, joint_trajectory, the axis services and the
axis diagnostics, and refusals that write nothing. The acceptance test does the same over veth
with the node and the client in separate processes."""

from __future__ import annotations

import math
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest
from builtin_interfaces.msg import Duration
from rclpy.serialization import serialize_message
from sensor_msgs.msg import JointState
from test_ros_node_inprocess import running_node
from trajectory_msgs.msg import JointTrajectory, JointTrajectoryPoint

from ether_ros._native import DriveFault
from ether_ros.ros.client import EtherRosClient
from ether_ros.ros.node import QOS_COMMANDS, EtherRosNode
from ether_ros.testing.wait import wait_for

# netns: the bus runs with its configuration's realtime section (SCHED_FIFO, locked memory).
pytestmark = [pytest.mark.ros, pytest.mark.netns]

ARM = Path(__file__).resolve().parents[2] / "config" / "arm6.yaml"
JOINTS = ["shoulder_pan", "shoulder_lift", "elbow", "wrist_1", "wrist_2", "wrist_3"]


@pytest.fixture(scope="module")
def arm() -> Iterator[tuple[EtherRosNode, EtherRosClient, Any]]:
    with running_node(5, ARM) as (node, client, net):
        ok, message = node.run_command("start")
        assert ok, message
        ok, message, states = client.axis_command("enable")
        assert ok, message
        assert states == dict.fromkeys(JOINTS, "operation_enabled")
        yield node, client, net


def joint_positions(client: EtherRosClient) -> dict[str, float]:
    msg = client.wait_for(lambda latest: latest.joint_state)
    return dict(zip(msg.name, msg.position, strict=True))


def wait_position(client: EtherRosClient, joint: str, target: float, timeout: float = 20.0) -> None:
    deadline = time.monotonic() + timeout
    while abs(joint_positions(client)[joint] - target) > 0.01:
        if time.monotonic() > deadline:
            diag = client.wait_for(lambda latest: latest.diagnostics)
            axis = [dict((v.key, v.value) for v in s.values) for s in diag.status
                    if s.name.endswith(f"axis {joint}")]  # fmt: skip
            raise AssertionError(
                f"{joint} at {joint_positions(client)[joint]}, not {target}: {axis}"
                f" (lease token {client.lease_token}, lost: {client.lease_lost!r})"
            )
        time.sleep(0.05)


def command_seq(node: EtherRosNode) -> dict[str, int]:
    return {name: int(axis.status()["command_seq"]) for name, axis in node._axes.items()}


def refusal(client: EtherRosClient, before: int) -> str:
    client.wait_for(lambda _l: len(client.joint_results) > before)
    result = client.joint_results[before]
    assert not result.success
    return str(result.message)


def test_joint_states_has_every_axis_in_si(arm: Any) -> None:
    _node, client, _net = arm
    msg = client.wait_for(lambda latest: latest.joint_state)
    assert list(msg.name) == JOINTS
    assert len(msg.position) == len(msg.velocity) == len(msg.effort) == len(JOINTS)
    assert all(abs(p) < 3.2 for p in msg.position)  # radians, not encoder counts
    # Only the elbow of arm6 has extras: joint_extras names it alone (its values are checked
    # in test_ros_extras_inprocess.py).
    extras = client.wait_for(lambda latest: latest.joint_extras)
    assert set(extras.joints) == {"elbow"}


def test_joint_commands_move_the_named_joints_only(arm: Any) -> None:
    node, client, _net = arm
    before = joint_positions(client)
    native = node.joint_command_path_counters()["applied"]
    client.publish_joint_command(["elbow", "wrist_2"], position=[0.4, -0.3])
    wait_position(client, "elbow", 0.4)
    wait_position(client, "wrist_2", -0.3)
    assert abs(joint_positions(client)["shoulder_pan"] - before["shoulder_pan"]) < 0.01
    # written by the native thread, not by Python
    assert node.joint_command_path_counters()["applied"] == native + 1


@pytest.mark.parametrize(
    ("names", "arrays", "why"),
    [
        (["nope"], {"position": [0.1]}, "unknown joint 'nope'"),
        (["elbow"], {"position": [math.nan]}, "not a finite number"),
        (["elbow"], {"position": [9.0]}, "outside the limits"),
        (["elbow"], {"velocity": [0.1]}, "takes a position, got velocity"),
        (["elbow", "wrist_1"], {"position": [0.1]}, "1 value(s) for 2 joint name(s)"),
        (["elbow", "elbow"], {"position": [0.1, 0.2]}, "named twice"),
        # one bad joint: the good one is not written either
        (["wrist_1", "elbow"], {"position": [0.2, 7.0]}, "outside the limits"),
    ],
)
def test_bad_joint_commands_are_refused_and_write_nothing(
    arm: Any, names: list[str], arrays: dict[str, list[float]], why: str
) -> None:
    node, client, _net = arm
    seq = command_seq(node)
    counters = node.joint_command_path_counters()
    before = len(client.joint_results)
    client.publish_joint_command(names, **arrays)
    assert why in refusal(client, before)
    assert command_seq(node) == seq
    after = node.joint_command_path_counters()
    # Refused either by Python or, for what is wrong by its structure (unknown or repeated
    # names, array lengths), on the native thread with Python's words: never both.
    structural = why.startswith(("unknown joint", "1 value(s)", "named twice"))
    assert after["refused"] == counters["refused"] + structural
    assert after["deferred"] == counters["deferred"] + (not structural)


@pytest.mark.parametrize(
    ("topic", "message", "why"),
    [
        (
            "joint_commands",
            JointState(name=["wrist_1", "elbow#junk"], position=[0.1, 0.3]),
            "joint_commands refused: field 'name' holds a NUL at byte 5",
        ),
        (
            "joint_trajectory",
            JointTrajectory(
                joint_names=["elbow#junk"],
                points=[JointTrajectoryPoint(positions=[0.3], time_from_start=Duration(sec=1))],
            ),
            "joint_trajectory refused: field 'joint_names' holds a NUL at byte 5",
        ),
    ],
)
def test_a_joint_name_with_a_nul_is_refused_not_cut(
    arm: Any, topic: str, message: Any, why: str
) -> None:
    """Issue 19: ``elbow\\0junk`` in raw CDR moved the elbow (rclpy cuts the name at the NUL).
    Refused by the native decoder, on the native path (joint_commands) and before rclpy reads
    it (joint_trajectory)."""
    node, client, _net = arm
    seq = command_seq(node)
    before = len(client.joint_results)
    publisher = client.node.create_publisher(type(message), topic, QOS_COMMANDS)
    client.wait_for(lambda _l: publisher.get_subscription_count() > 0)
    # arm6.yaml has the control lease on: the new publisher is the holder's once the client
    # acquires it again (who may command is checked before what is commanded).
    ok, text = client.acquire_lease(takeover=True)
    assert ok, text
    publisher.publish(serialize_message(message).replace(b"#", b"\0"))
    assert refusal(client, before) == why
    assert command_seq(node) == seq
    client.node.destroy_publisher(publisher)


def test_joint_trajectory_runs_in_time(arm: Any) -> None:
    _node, client, _net = arm
    elbow = joint_positions(client)["elbow"]
    before = len(client.joint_results)
    client.publish_trajectory(["shoulder_lift", "wrist_1"], [(0.4, [0.3, -0.2]), (0.8, [0.5, 0.1])])
    client.wait_for(lambda _l: len(client.joint_results) > before)
    assert client.joint_results[before].success, client.joint_results[before].message
    wait_position(client, "shoulder_lift", 0.5)
    wait_position(client, "wrist_1", 0.1)
    assert abs(joint_positions(client)["elbow"] - elbow) < 0.01  # not in it: kept its command


@pytest.mark.parametrize(
    ("names", "points", "why"),
    [
        (["nope"], [(0.5, [0.1])], "unknown joint"),
        (["elbow"], [(0.5, [0.1]), (0.5, [0.2])], "not after the previous"),
        (["elbow"], [(0.5, [math.nan])], "not finite"),
        (["elbow"], [(0.5, [5.0])], "outside the limits"),
        (["elbow"], [(0.001 * (i + 1), [0.0]) for i in range(2000)], "at most"),
        (["elbow"], [], "no points"),
    ],
)
def test_bad_trajectories_are_refused_and_write_nothing(
    arm: Any, names: list[str], points: list[tuple[float, list[float]]], why: str
) -> None:
    node, client, _net = arm
    seq = command_seq(node)
    before = len(client.joint_results)
    client.publish_trajectory(names, points)
    assert why in refusal(client, before)
    assert command_seq(node) == seq


def test_trajectory_stamp_in_the_past_is_refused(arm: Any) -> None:
    _node, client, _net = arm
    before = len(client.joint_results)
    client.publish_trajectory(["elbow"], [(0.5, [0.1])], start=time.time() - 5)
    assert "in the past" in refusal(client, before)


def test_services_refuse_bad_input(arm: Any) -> None:
    _node, client, _net = arm
    ok, message, _ = client.axis_command("disable", ["nope"])
    assert not ok and "unknown joint(s) 'nope'" in message
    ok, message, _ = client.set_mode("warp", ["elbow"])
    assert not ok and "unknown mode 'warp'" in message


def test_set_mode_disable_enable(arm: Any) -> None:
    node, client, _net = arm
    ok, message, states = client.set_mode("csv", ["wrist_3"])
    assert ok, message
    assert node._axes["wrist_3"].status()["mode_display"] == "csv"
    before = len(client.joint_results)
    client.publish_joint_command(["wrist_3"], position=[0.1])  # csv takes a velocity
    assert "takes a velocity, got position" in refusal(client, before)
    ok, message, states = client.set_mode("csp", ["wrist_3"])
    assert ok, message
    ok, message, states = client.axis_command("disable", ["wrist_3"])
    assert ok and states == {"wrist_3": "switch_on_disabled"}, message
    ok, message, states = client.axis_command("enable", ["wrist_3"])
    assert ok and states == {"wrist_3": "operation_enabled"}, message


def test_home_service_homes_and_gives_the_joint_back_in_its_mode(arm: Any) -> None:
    """The home service: the drive's configured method (the ESI's 0x6098 default, 37: the home
    is the current position, 0x607C = 0), the joint back in csp and enabled, homing_runs
    counted; a joint not enabled is refused with the reason."""
    node, client, _net = arm
    axis = node._axes["wrist_2"]
    ok, message, _ = client.axis_command("disable", ["wrist_2"])
    assert ok, message
    ok, message, _ = client.axis_command("home", ["wrist_2"])
    assert not ok and "homing needs the axis enabled" in message, message
    ok, message, _ = client.axis_command("enable", ["wrist_2"])
    assert ok, message
    runs = int(axis.status()["homing_runs"])
    ok, message, states = client.axis_command("home", ["wrist_2"], timeout=40)
    assert ok and states == {"wrist_2": "operation_enabled"}, message
    st = axis.status()
    assert int(st["homing_runs"]) == runs + 1 and st["mode_display"] == "csp"
    assert abs(axis.position - axis.spec.config.position_offset) < 0.01


def test_injected_fault_shows_in_diagnostics_with_its_text(arm: Any) -> None:
    node, client, net = arm
    faults = int(node._axes["wrist_1"].status()["faults"])
    net.inject(DriveFault(slave=1, error="encoder", axis=2))  # elbow_drive axis 2: wrist_1

    def reported(_latest: Any) -> dict[str, str] | None:
        st = client.axis_states().get("wrist_1")
        return st if st and int(st["faults"]) > faults else None

    st = client.wait_for(reported, timeout=10)
    assert st["last_fault_code"] == "0x7305"
    assert st["last_fault_text"] == "incremental encoder 1 fault"
    assert "0x7305 incremental encoder 1 fault" in st["message"]
    ok, message, states = client.axis_command("reset_fault", ["wrist_1"])
    assert ok, message
    ok, message, states = client.axis_command("enable", ["wrist_1"])
    assert ok and states == {"wrist_1": "operation_enabled"}, message


def test_joint_commands_refused_when_not_active(arm: Any) -> None:
    node, client, _net = arm
    ok, message = node.run_command("stop")
    assert ok, message
    try:
        before = len(client.joint_results)
        client.publish_joint_command(["elbow"], position=[0.1])
        assert "the node is inactive" in refusal(client, before)
        ok, message, _ = client.axis_command("enable")
        assert not ok and "inactive" in message
    finally:
        node.run_command("start")
        ok, message, _ = client.axis_command("enable")
        assert ok, f"enable after start: {message} (lease lost: {client.lease_lost!r})"


def test_the_console_operates_the_axes(arm: Any) -> None:
    from ether_ros.console.app import Console

    node, client, _net = arm
    lines: list[str] = []
    with Console(client, out=lines.append) as console:
        seq = command_seq(node)
        console.line("move elbow 9")  # refused by the console: nothing is sent
        assert "outside the limits [-2.5, 2.5]" in lines[-1]
        assert command_seq(node) == seq
        console.line("move elbow -0.25")
        assert lines[-1].startswith("accepted elbow position=-0.25"), lines[-1]
        wait_position(client, "elbow", -0.25)
        console.line("set_mode elbow warp")
        assert "unknown mode 'warp'" in lines[-1]
        console.line("disable elbow")
        # Done once the drive has left operation_enabled: through quick_stop_active when the
        # elbow was still settling (hand-overs are bounded in acceleration), then disabled.
        assert lines[-1].startswith("disable done (elbow: "), lines[-1]
        client.wait_for(
            lambda _l: client.axis_states().get("elbow", {}).get("state") == "switch_on_disabled",
            10,
        )
        # A move to an axis that cannot move is not executed, and the answer says why.
        seq = command_seq(node)
        console.line("move elbow 0.1")
        assert lines[-1].startswith("error: not executed"), lines[-1]
        assert "not enabled (switch_on_disabled)" in lines[-1], lines[-1]
        assert "sent" not in lines[-1]
        assert command_seq(node) == seq
        console.line("enable all")
        assert lines[-1].startswith("enable done (shoulder_pan: operation_enabled")


def test_a_slow_enable_holds_up_no_other_callback(arm: Any, monkeypatch: Any) -> None:
    """An enable waits for the drive (seconds, for a slow one): the lifecycle service, joint
    commands and trajectories are still served meanwhile. The drive is the faked layer here: its
    enable blocks until released."""
    import threading

    node, client, _net = arm
    release = threading.Event()
    entered = threading.Event()

    def slow_enable(timeout: float = 2.0) -> None:
        entered.set()
        release.wait(10)

    monkeypatch.setattr(node._axes["wrist_2"], "enable", slow_enable)
    answer: list[Any] = []
    caller = threading.Thread(
        target=lambda: answer.append(client.axis_command("enable", ["wrist_2"]))
    )
    caller.start()
    try:
        assert entered.wait(5)
        assert client.get_state(timeout=2) == "active"
        before = len(client.joint_results)
        client.publish_trajectory(["wrist_1"], [(0.3, [0.05])])
        client.wait_for(lambda _l: len(client.joint_results) > before, timeout=2)
        assert client.joint_results[before].success
        client.publish_joint_command(["elbow"], position=[0.15])
        wait_position(client, "elbow", 0.15, timeout=2)
        assert not answer  # the enable is still waiting
    finally:
        release.set()
        caller.join(10)
    assert answer and answer[0][0], answer


def test_a_trajectory_for_a_disabled_axis_is_refused_with_the_reason(arm: Any) -> None:
    """Issue 19: a trajectory for an axis out of Operation Enabled was answered "accepted" and
    never ran; now it is refused naming the state and what to do."""
    node, client, _net = arm
    ok, message, _ = client.axis_command("disable", ["wrist_3"])
    assert ok, message
    try:
        seq = command_seq(node)
        before = len(client.joint_results)
        client.publish_trajectory(["wrist_3", "elbow"], [(0.5, [0.1, 0.1])])
        why = refusal(client, before)
        assert "axis wrist_3 is switch_on_disabled, not operation_enabled" in why, why
        assert "enable the axis first" in why
        assert command_seq(node) == seq
    finally:
        ok, message, _ = client.axis_command("enable", ["wrist_3"])
        assert ok, message


@pytest.mark.parametrize("event", ["set_mode", "disable", "lease"])
def test_a_joint_trajectory_that_stops_early_says_why(arm: Any, event: str) -> None:
    """Issue 24: a joint_trajectory whose joint leaves it (another mode, disabled, or the
    control lease lapses: the lease thread's call) is reported on joint_results with the joint
    and what happened, and the other joint of it stops instead of going on alone. 10 s long:
    stopping long before its end proves it."""
    node, client, _net = arm
    start = joint_positions(client)
    before = len(client.joint_results)
    client.publish_trajectory(
        ["wrist_2", "wrist_3"], [(10.0, [start["wrist_2"] + 1.0, start["wrist_3"] + 1.0])]
    )
    client.wait_for(lambda _l: len(client.joint_results) > before, timeout=30)
    assert client.joint_results[before].success, client.joint_results[before].message
    wait_for(
        "the trajectory running",
        lambda: all(node._axes[j].status()["trajectory_active"] for j in ("wrist_2", "wrist_3")),
        timeout=30,
    )
    after = len(client.joint_results)
    try:
        if event == "set_mode":
            ok, message, _ = client.set_mode("csv", ["wrist_3"])
            reason = "joint 'wrist_3' left csp (now csv)"
        elif event == "disable":
            ok, message, _ = client.axis_command("disable", ["wrist_3"])
            reason = "joint 'wrist_3' disabled"
        else:
            node._stop_motion("the control lease lapsed (test)")
            ok, message, reason = True, "", "control lease lapsed"
        assert ok, message
        client.wait_for(lambda _l: len(client.joint_results) > after, timeout=30)
        result = client.joint_results[after]
        assert not result.success
        assert result.message == f"joint_trajectory aborted: {reason} (wrist_2, wrist_3)", [
            r.message for r in client.joint_results[before:]
        ]
        wrist_2 = node._axes["wrist_2"]
        wait_for("wrist_2 at rest", lambda: wrist_2.status()["idle"])
        assert wrist_2.status()["trajectory_stopped"]
        assert abs(wrist_2.position - start["wrist_2"]) < 0.8
    finally:
        ok, message, _ = client.set_mode("csp", ["wrist_3"])
        assert ok, message
        ok, message, _ = client.axis_command("enable")
        assert ok, message
