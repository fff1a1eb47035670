"""The ether_ros node over ROS 2 only: the simulator and the node run as their own processes on
the two ends of a veth pair (the simulator's end in its own network namespace); this process is
an ordinary ROS 2 client (its own domain id).

What reaches the slaves is checked in the simulator (its control socket: the firmware's
trajectory parameters, AL states), what comes back on the node's topics (outputs echo of the
wire image, decoded inputs, joint states, diagnostics)."""

from __future__ import annotations

import os
import time
from collections.abc import Callable, Iterator
from pathlib import Path

import pytest

from ether_ros._native import protocol
from ether_ros.ros.client import ClientError, EtherRosClient, Latest, make_write
from ether_ros.ros.rig import RosRig, domain_for
from ether_ros.testing.configs import config_with_watchdog

pytestmark = [pytest.mark.netns, pytest.mark.ros, pytest.mark.slow]

REPO = Path(__file__).resolve().parents[2]
LEGS = ("hind_right_leg", "hind_left_leg", "front_left_leg", "front_right_leg")
# A point at the Table 6.1 standing centre, then an ellipse with 4 cm ground clearance.
STANDING = {
    "x_cntr_traj1000": 0,
    "y_cntr_traj1000": 599,
    "a_ellipse100": 0,
    "b_ellipse100": 0,
    "traj_freq100": 100,
    "phase_deg": 0,
    "FlatnessParam100": 0,
}


@pytest.fixture(scope="module")
def rig(veth_allowed: bool, tmp_path_factory: pytest.TempPathFactory) -> Iterator[RosRig]:
    if not veth_allowed:
        pytest.fail("the ROS acceptance tests need root (veth pairs)")
    # A 1 s engine watchdog instead of 100 ms: a trip voids the commands before it, and the
    # node's feeder can stall 100 ms on a loaded VM (testing/configs.py).
    config = config_with_watchdog("laelaps.yaml", tmp_path_factory.mktemp("node"), 1000)
    with RosRig(config, raw=True, netns=True) as rig:
        assert rig.client.wait_for_node() == "active"
        rig.client.layout(timeout=10)
        yield rig


def write_all(client: EtherRosClient, slave: str, values: dict[str, float]) -> None:
    ok, message = client.write_many([make_write(slave, k, float(v)) for k, v in values.items()])
    assert ok, message


def echo(client: EtherRosClient, slave: str, variable: str, value: float) -> float:
    """Wait until the outputs echo (the image as it went on the wire) shows ``value``."""
    return (
        client.wait_for(
            lambda latest: latest.outputs.get(slave, {}).get(variable) == value or None, timeout=5
        )
        and value
    )


def feed_until_echo(
    client: EtherRosClient, command: Callable[[], None], slave: str, variable: str, value: float
) -> None:
    """Send ``command`` every 100 ms until the outputs echo shows ``value`` (20 s at most)."""
    deadline = time.monotonic() + 20
    while True:
        command()
        try:
            client.wait_for(
                lambda latest: latest.outputs.get(slave, {}).get(variable) == value or None,
                timeout=0.1,
            )
            return
        except ClientError:
            assert time.monotonic() < deadline, f"{slave}.{variable} never echoed {value}"


def test_layout_joint_states_and_diagnostics(rig: RosRig) -> None:
    c = rig.client
    layout = c.layout()
    assert [s.name for s in layout.slaves] == list(LEGS)
    leg = layout.slave("front_left_leg")
    assert leg.device == "LaelapsII_Leg" and leg.position == 2
    assert leg.output("0x7030:04").name == "b_ellipse100"
    joints = c.wait_for(lambda latest: latest.joint_state, timeout=5)
    assert list(joints.name) == [
        f"{leg}_{j}" for leg in ("hr", "hl", "fl", "fr") for j in ("hip", "knee")
    ]
    assert len(joints.position) == len(joints.velocity) == len(joints.effort) == 8
    states = c.wait_for(lambda latest: len(c.slave_states()) == 4 and c.slave_states(), 5)
    assert states == dict.fromkeys(LEGS, "OP")
    master = c.master_status()
    assert master["lifecycle_state"] == "active"
    assert int(master["cycles"]) > 0 and "rtt_p99_ns" in master


def test_write_reaches_the_slave_and_its_effect_comes_back(rig: RosRig) -> None:
    c = rig.client
    write_all(c, "front_left_leg", {"State_Machine": 0, "Transition_time": 0, **STANDING})
    write_all(c, "front_left_leg", {"b_ellipse100": 4})
    echo(c, "front_left_leg", "b_ellipse100", 4.0)
    # The firmware of slave 2 accepted the ellipse it received in the frames.
    probe = c.wait_for(
        lambda _l: (p := rig.sim("probe", slave=2))["traj_b_m"] == pytest.approx(0.04) and p, 5
    )
    assert probe["traj_a_m"] == 0.0
    assert rig.sim("probe", slave=3)["traj_b_m"] != pytest.approx(0.04)
    # Operational: the toe follows the ellipse; the desired knee angle reported in the inputs
    # and the measured one in joint_states move.
    seen: list[float] = []
    joint: list[float] = []

    def moving(latest: Latest) -> bool:
        seen.append(latest.inputs.get("front_left_leg", {}).get("desired_knee_angle", 0.0))
        if latest.joint_state is not None:
            joint.append(latest.joint_state.position[5])  # fl_knee
        return max(seen) - min(seen) > 500 and max(joint) - min(joint) > 0.05  # 5°, 0.05 rad

    gains = {"Kp100_knee": 8000, "Kd1000_knee": 50, "Kp100_hip": 8000, "Kd1000_hip": 50}
    write_all(c, "front_left_leg", {**gains, "FilterBandwidth": 20, "State_Machine": 1})
    c.wait_for(moving, timeout=10)
    write_all(c, "front_left_leg", {"State_Machine": 0, "b_ellipse100": 0})


def test_write_to_all_slaves_at_once(rig: RosRig) -> None:
    c = rig.client
    write_all(c, "all", {"State_Machine": 0, "Transition_time": 0, **STANDING})
    request = c.publish_write("all", "b_ellipse100", 3)  # the thesis's /pdo_listener topic
    result = c.wait_result(request)
    assert result.success, result.message
    for position, leg in enumerate(LEGS):
        echo(c, leg, "b_ellipse100", 3.0)
        c.wait_for(
            lambda _l, p=position: rig.sim("probe", slave=p)["traj_b_m"] == pytest.approx(0.03),
            5,
        )


def test_topic_writes_take_the_native_path_and_others_python_in_order(rig: RosRig) -> None:
    """Valid pdo_listener writes are applied by the node's native thread (counted in the
    diagnostics); a text value goes through Python, and a valid write sent right behind it
    waits for it, so the last value sent is the one that stays."""
    c = rig.client

    def counter(key: str) -> int:
        return int(float(c.master_status().get(f"ros_{key}", "0")))

    c.wait_for(lambda _l: c.master_status().get("ros_commands_native") is not None, 5)
    native, deferred = counter("commands_native"), counter("commands_deferred")
    result = c.wait_result(c.publish_write("hind_left_leg", "Kd1000_knee", 42))
    assert result.success and result.message == "wrote hind_left_leg.Kd1000_knee=42"
    echo(c, "hind_left_leg", "Kd1000_knee", 42.0)
    first = c.publish_write("hind_left_leg", "Kd1000_knee", "0x20")  # text: Python
    second = c.publish_write("hind_left_leg", "Kd1000_knee", 33)
    assert c.wait_result(first).success and c.wait_result(second).success
    echo(c, "hind_left_leg", "Kd1000_knee", 33.0)
    c.wait_for(lambda _l: counter("commands_deferred") >= deferred + 2, 5)
    assert counter("commands_native") >= native + 1
    assert c.latest.outputs["hind_left_leg"]["Kd1000_knee"] == 33.0


@pytest.mark.parametrize(
    ("slave", "variable", "value", "reason"),
    [
        ("front_left_leg", "Kp100_knee", 40000.0, "outside -32768..32767"),
        ("front_left_leg", "Kp100_knee", 1.5, "not an integer"),
        ("front_left_leg", "hip_angle", 1.0, "is an input"),
        ("front_left_leg", "no_such_variable", 1.0, "not a variable"),
        ("nobody", "Kp100_knee", 1.0, "no slave named 'nobody'"),
        (7, "Kp100_knee", 1.0, "no slave at position 7"),
        ("front_left_leg", "State_Machine", "maybe", "not an integer"),
    ],
)
def test_invalid_writes_are_refused_and_change_nothing(
    rig: RosRig, slave: str | int, variable: str, value: float | str, reason: str
) -> None:
    c = rig.client
    write_all(c, "front_left_leg", {"Kp100_knee": 1234})
    echo(c, "front_left_leg", "Kp100_knee", 1234.0)
    ok, message = c.write(slave, variable, value)
    assert not ok and reason in message
    result = c.wait_result(c.publish_write(slave, variable, value))
    assert not result.success and reason in result.message
    # All or nothing: a valid write next to an invalid one is not applied either.
    ok, message = c.write_many(
        [make_write("front_left_leg", "Kp100_knee", 999.0), make_write(slave, variable, value)]
    )
    assert not ok and reason in message
    commanded = c.wait_for(
        lambda latest: latest.commanded.get("front_left_leg", {}).get("Kp100_knee") == 1234.0,
        timeout=5,
    )
    assert commanded
    assert c.latest.outputs["front_left_leg"]["Kp100_knee"] == 1234.0


def test_panic_puts_safe_outputs_on_the_wire_until_cleared(rig: RosRig) -> None:
    c = rig.client
    write_all(c, "all", {"Kp100_knee": 777, "State_Machine": 0})
    for leg in LEGS:
        echo(c, leg, "Kp100_knee", 777.0)
    ok, message = c.panic()
    assert ok, message
    for leg in LEGS:  # the safe image: State_Machine 0, everything else 0
        echo(c, leg, "Kp100_knee", 0.0)
    raw = c.wait_for(lambda latest: latest.raw is not None and latest.raw, 5)
    assert raw.working_counter == raw.expected_working_counter
    c.wait_for(lambda _l: c.master_status().get("panic") == "true", timeout=5)
    # Commands are still accepted (they wait behind the panic) but do not reach the wire.
    assert c.write("front_left_leg", "Kp100_knee", 555)[0]
    assert c.latest.outputs["front_left_leg"]["Kp100_knee"] == 0.0
    ok, message = c.command("clear_panic")
    assert ok, message
    # Clearing does not restart (ISO 13850): neither the command sent during the panic nor
    # those from before it come back; the outputs stay safe until commanded again.
    assert "stay at their safe values" in message, message
    assert c.latest.outputs["front_left_leg"]["Kp100_knee"] == 0.0
    c.wait_for(
        lambda latest: latest.commanded.get("hind_right_leg", {}).get("Kp100_knee") == 0.0,
        timeout=5,
    )
    # A new command to one leg: that leg only.
    assert c.write("front_left_leg", "Kp100_knee", 555)[0]
    echo(c, "front_left_leg", "Kp100_knee", 555.0)
    for leg in LEGS:
        if leg != "front_left_leg":
            assert c.latest.outputs[leg]["Kp100_knee"] == 0.0, leg


def test_command_watchdog_puts_safe_outputs_on_the_wire(rig: RosRig) -> None:
    c = rig.client
    write_all(c, "front_right_leg", {"Kp100_hip": 321})
    echo(c, "front_right_leg", "Kp100_hip", 321.0)
    ok, reason = c.set_parameter("command_timeout_ms", 300)
    assert ok, reason
    try:
        # No command for 300 ms (+ the rig's 1 s engine watchdog): safe outputs.
        echo(c, "front_right_leg", "Kp100_hip", 0.0)
        c.wait_for(lambda _l: c.master_status().get("ros_watchdog_active") == "1", timeout=5)

        # The next command feeds it again and reaches the wire; the commands from before the
        # trip do not come back (a trip is a stop: its reset does not restart), so Kp100_hip
        # stays at its safe value. A loaded host may deliver the echo later than the next
        # 300 ms trip, so the commands keep coming (as a live client's would) until the echo
        # shows them.
        def service_write() -> None:
            assert c.write("front_right_leg", "Kd1000_hip", 5)[0]

        feed_until_echo(c, service_write, "front_right_leg", "Kd1000_hip", 5.0)
        assert c.latest.outputs["front_right_leg"]["Kp100_hip"] == 0.0
        # The same through the topic, whose writes the native path applies.
        c.wait_for(lambda _l: c.master_status().get("ros_watchdog_active") == "1", timeout=5)
        echo(c, "front_right_leg", "Kd1000_hip", 0.0)

        def topic_write() -> None:
            assert c.wait_result(c.publish_write("front_right_leg", "Kd1000_hip", 6)).success

        feed_until_echo(c, topic_write, "front_right_leg", "Kd1000_hip", 6.0)
        assert c.latest.outputs["front_right_leg"]["Kp100_hip"] == 0.0
    finally:
        assert c.set_parameter("command_timeout_ms", 0)[0]


def test_sdo_services(rig: RosRig) -> None:
    c = rig.client
    resp = c.sdo_read("front_left_leg", 0x1018, 1, "uint32")
    assert resp.success and resp.value == 0x0A12
    assert bytes(resp.data) == (0x0A12).to_bytes(4, "little")
    raw = c.sdo_read("2", 0x1018, 2)
    assert raw.success and int.from_bytes(bytes(raw.data), "little") == 0x00A986FD
    missing = c.sdo_read("front_left_leg", 0x5FFF, 0, "uint8")
    assert not missing.success and missing.message
    # The abort code arrives as data (docs/ros.md, "Error codes"), not only in the text.
    assert (missing.error, missing.code) == ("SdoAbort", protocol.sdo_abort.ABORT_NO_OBJECT)
    assert missing.code == 0x06020000
    assert (raw.error, raw.code) == ("", 0)
    answer = c.sdo_write("front_left_leg", 0x1018, 1, "uint32", "5")
    ok, message = answer
    assert not ok and message  # the identity object is read-only
    assert (answer.error, answer.code) == ("SdoAbort", protocol.sdo_abort.ABORT_READ_ONLY)
    answer = c.sdo_write("front_left_leg", 0x1018, 1, "uint8", "300")
    assert not answer.success and "outside 0..255" in answer.message
    assert answer.error and answer.code == 0  # refused before the wire: no abort code
    nobody = c.sdo_read("nobody", 0x1018, 1)
    assert not nobody.success and nobody.error and nobody.code == 0


def test_parameters_mirror_the_configuration(rig: RosRig) -> None:
    c = rig.client
    params = c.get_parameters(
        ["bus.cycle_us", "bus.dc.sync0_shift_us", "slaves.front_left_leg.position",
         "slaves.hind_right_leg.vendor_id", "ros.decoded_decimation"]
    )  # fmt: skip
    assert params == {
        "bus.cycle_us": 400,
        "bus.dc.sync0_shift_us": 55.0,
        "slaves.front_left_leg.position": 2,
        "slaves.hind_right_leg.vendor_id": 0x0A12,
        "ros.decoded_decimation": 10,
    }
    ok, reason = c.set_parameter("bus.cycle_us", 200)
    assert not ok and "configuration file" in reason
    ok, reason = c.set_parameter("ros.decoded_decimation", 0)
    assert not ok and "must be within 1..1000000 (got 0)" in reason
    assert c.set_parameter("ros.decoded_decimation", 5)[0]
    assert c.get_parameters(["ros.decoded_decimation"]) == {"ros.decoded_decimation": 5}
    assert c.set_parameter("ros.decoded_decimation", 10)[0]


def test_a_failed_activation_is_reported_and_recoverable(rig: RosRig) -> None:
    c = rig.client
    assert c.command("stop")[0] and c.get_state() == "inactive"
    rig.sim("fault", kind="refuse_op", slave="hind_left_leg")
    try:
        answer = c.command("start")
        ok, message = answer
        assert not ok
        assert "activate failed" in message and "hind_left_leg" in message, message
        # The slave's AL status code as data (the simulator refuses OP with 0x001A).
        assert answer.code == protocol.al_code.SYNCHRONIZATION_ERROR, (answer.error, answer.code)
        assert answer.error == "AlStateRefused"
        assert c.get_state() == "inactive"
    finally:
        rig.sim("fault", kind="refuse_op", slave="hind_left_leg", on=False)
    assert c.command("start") == (True, "running: slaves in OP")
    c.wait_for(lambda _l: c.slave_states() == dict.fromkeys(LEGS, "OP"), timeout=10)


def test_every_lifecycle_transition(rig: RosRig) -> None:
    """Runs last in this module: it ends with the node shut down."""
    c = rig.client
    assert c.get_state() == "active"
    assert c.change_state("deactivate")
    assert c.get_state() == "inactive"
    states = {rig.sim("slave_info", slave=p)["al_state_name"] for p in range(4)}
    assert "OP" not in states
    ok, message = c.write("front_left_leg", "Kp100_knee", 1)
    assert not ok and "inactive" in message
    assert c.change_state("activate")
    c.wait_for(
        lambda _l: all(rig.sim("slave_info", slave=p)["al_state_name"] == "OP" for p in range(4)),
        timeout=10,
    )
    assert c.command("stop") == (True, "stopped: safe outputs sent, slaves left OP")
    assert c.get_state() == "inactive"
    assert c.command("start")[0] and c.get_state() == "active"
    assert c.command("restart")[0] and c.get_state() == "active"
    assert c.change_state("deactivate") and c.change_state("cleanup")
    assert c.get_state() == "unconfigured"
    assert not c.command("frobnicate")[0]
    assert c.change_state("configure") and c.get_state() == "inactive"
    assert c.change_state("activate") and c.get_state() == "active"
    assert c.write("front_left_leg", "Kp100_knee", 42)[0]
    echo(c, "front_left_leg", "Kp100_knee", 42.0)
    assert c.change_state("active_shutdown")
    assert c.get_state() == "finalized"
    assert rig.stop_node() == 0


def test_inactive_start_and_a_generic_io_bus(veth_allowed: bool) -> None:
    """``run --inactive`` leaves the transitions to the caller; the node works for any ESI (two
    generic I/O slaves here): layout, writes by name, no joint states without a joint mapping."""
    if not veth_allowed:
        pytest.fail("the ROS acceptance tests need root (veth pairs)")
    config = REPO / "config" / "generic_io.yaml"
    with RosRig(config, inactive=True, domain_id=domain_for(os.getpid(), 1)) as rig:
        c = rig.client
        assert c.wait_for_node() == "unconfigured"
        assert rig.sim("slave_info", slave=0)["al_state_name"] == "INIT"
        assert c.change_state("configure") and c.get_state() == "inactive"
        layout = c.layout()
        assert [(s.name, s.device) for s in layout.slaves] == [
            ("io_a", "GenericIO"),
            ("io_b", "GenericIO"),
        ]
        assert c.change_state("activate")
        assert c.wait_for(lambda _l: c.slave_states() == {"io_a": "OP", "io_b": "OP"}, 10)
        output = layout.slave("io_b").outputs[0]
        ok, message = c.write("all", output.name, 1)
        assert ok, message
        for slave in ("io_a", "io_b"):
            c.wait_for(lambda latest, s=slave: latest.outputs.get(s, {}).get(output.name) == 1.0)
        assert c.latest.counts.get("joint_states", 0) == 0
        # SIGINT (as from Ctrl-C or a process manager): the node deactivates and releases the
        # bus before it exits; the slaves are left out of OP.
        assert rig.stop_node() == 0
        states = {rig.sim("slave_info", slave=p)["al_state_name"] for p in range(2)}
        assert "OP" not in states, states
        assert "inactive: safe outputs sent" in rig.node_log.read_text()
