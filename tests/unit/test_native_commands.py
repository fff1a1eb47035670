"""The native command path (crates/commands, ether_ros.ros.native_commands).

1. Its resolver against the Python one (``bridge.resolve_write``), the reference: over a few
   thousand requests (names, cases, addresses, positions, all slaves, values in and out of range,
   text), whatever the native path applies by itself Python accepts too, with the same bits and
   the same answer; and every plain valid request takes the native path.
2. The receiver thread in this process with real rcl objects and the simulator in-process: a
   published write reaches the engine and is answered on ``write_results`` without Python;
   deferred requests go to the Python handler in order; detached, nothing is written natively.
"""

from __future__ import annotations

import itertools
import math
import os
import struct
import threading
import time
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import pytest
import rclpy
from ether_ros_msgs.msg import WriteResult, WriteVariable
from rclpy.context import Context
from rclpy.executors import SingleThreadedExecutor
from rclpy.serialization import serialize_message

from ether_ros import _native
from ether_ros.config import load_bus_config
from ether_ros.errors import EtherRosError
from ether_ros.master import workspace
from ether_ros.master.bus import Bus
from ether_ros.ros import bridge
from ether_ros.ros.layout import BusSpec
from ether_ros.ros.native_commands import (
    CommandPathError,
    NativeCommandPath,
    command_table,
    loaded_library,
)
from ether_ros.ros.node import QOS_COMMANDS
from ether_ros.ros.rig import domain_for
from ether_ros.ros.values import to_python
from ether_ros.sim.network import build_network

pytestmark = [pytest.mark.ros]

REPO = Path(__file__).resolve().parents[2]
Fields = list[tuple[int, int, int]]


@pytest.fixture(scope="module")
def mixed_bus() -> Iterator[tuple[Bus, BusSpec]]:
    cfg = load_bus_config(REPO / "config" / "mixed.yaml")
    with Bus.open(cfg, link=build_network(cfg)) as bus:
        yield bus, bridge.bus_spec(bus)


def request(
    slave: str = "",
    variable: str = "",
    value: float = 0.0,
    *,
    position: int = -1,
    all_slaves: bool = False,
    text: str = "",
    request_id: int = 1,
) -> WriteVariable:
    return WriteVariable(
        slave=slave,
        position=position,
        all_slaves=all_slaves,
        variable=variable,
        value=value,
        text=text,
        request_id=request_id,
    )


def python_resolution(bus: Bus, spec: BusSpec, r: WriteVariable) -> tuple[Fields, str] | None:
    """What the node's Python path writes (as image bit fields) and answers; None if refused."""
    try:
        writes = bridge.resolve_write(
            spec, r.slave, r.position, r.all_slaves, r.variable, r.value, r.text
        )
    except EtherRosError:
        return None
    fields = []
    for s, var, value in writes:
        slave = bus.slave(s.name)
        assert slave.area is not None and slave.layout is not None
        pv = slave.layout.variable(var.name)
        raw = pv.encode(to_python(value, var.type))
        fields.append((slave.area.output_offset * 8 + pv.bit_offset, pv.bit_length, raw))
    return sorted(fields), bridge.describe_writes(writes)


def requests(spec: BusSpec) -> Iterator[WriteVariable]:
    leg, io = spec.slaves[2], spec.slaves[4]
    variables = ["hip_angle", "nope", "", "Kp100_knee\n", "0x7000:ff"]
    for v in (*leg.outputs[::3], *io.outputs[::4]):
        variables += [v.name, v.name.lower(), v.name.upper(), v.address]
        variables += [f"{v.index:x}:{v.subindex:x}", f" {v.address} ", v.address.upper()]
    values = [0.0, 1.0, -1.0, 2.0, 127.0, 128.0, -129.0, 4e4, 1.5, 65535.0, -32768.0]
    values += [math.nan, math.inf, -0.0, 2.0**31, 1e-7]
    targets: list[dict[str, Any]] = [
        {"slave": leg.name},
        {"slave": io.name},
        {"slave": "nobody"},
        {"slave": "2"},
        {"slave": "9"},
        {"position": 4},
        {"position": 0},
        {"position": 7},
        {},
        {"all_slaves": True},
    ]
    for target, variable, value in itertools.product(targets, variables, values):
        yield request(variable=variable, value=value, **target)
    for text in ("5", "true", "0x10", "1.5", "x"):
        yield request(leg.name, "State_Machine", text=text)
        yield request(io.name, "AnalogOutput1", text=text)


def test_the_native_resolver_applies_only_what_python_accepts(
    mixed_bus: tuple[Bus, BusSpec],
) -> None:
    bus, spec = mixed_bus
    table = command_table(bus, spec)
    # A leg's trajectory record: the master checks it against the workspace, so Python.
    ruled = {
        name
        for s in bus.slaves
        if s.layout is not None and s.device is not None
        for name in workspace.ruled_outputs(
            s.device.type_name, [(v.name, v.index, v.subindex) for v in s.layout.outputs]
        )
    }
    assert "a_ellipse100" in ruled
    applied = refused_by_both = deferred_ruled = 0
    for r in requests(spec):
        native = table.resolve(serialize_message(r))
        python = python_resolution(bus, spec, r)
        if native is not None:
            assert python is not None, f"native applied what Python refuses: {r}"
            assert (sorted(native[0]), native[1]) == python, r
            assert r.variable not in ruled, f"native applied a ruled variable: {r}"
            applied += 1
        elif python is None:
            refused_by_both += 1
        elif r.variable in ruled:
            deferred_ruled += 1
        elif not r.text and r.variable in {v.name for s in spec.slaves for v in s.outputs}:
            pytest.fail(f"a plain valid write was left to Python: {r}")
    assert applied > 500 and refused_by_both > 500 and deferred_ruled > 0


def test_reals_and_wide_integers_are_encoded_as_python_encodes_them() -> None:
    rows = [
        ("s", 0, [
            ("f", 0x7000, 1, 0, 32, "real32", -3.4028234663852886e38, 3.4028234663852886e38, False),
            ("d", 0x7000, 2, 32, 64, "real64", -math.inf, math.inf, False),
            ("u", 0x7000, 3, 96, 64, "uint", 0.0, 2.0**64 - 1, False),
            ("i", 0x7000, 4, 160, 12, "int", -2048.0, 2047.0, False),
        ]),
    ]  # fmt: skip
    table = _native.CommandTable(rows)

    def fields(variable: str, value: float) -> Fields | None:
        out = table.resolve(serialize_message(request("s", variable, value)))
        return None if out is None else out[0]

    assert fields("f", 0.1) == [(0, 32, struct.unpack("<I", struct.pack("<f", 0.1))[0])]
    assert fields("d", -2.5) == [(32, 64, struct.unpack("<Q", struct.pack("<d", -2.5))[0])]
    assert fields("u", 2.0**53) == [(96, 64, 2**53)]
    assert fields("i", -1.0) == [(160, 12, 0xFFF)]
    assert fields("i", -2049.0) is None
    assert fields("f", 1e39) is None


def test_bad_tables_and_bytes_are_refused_with_the_reason() -> None:
    with pytest.raises(ValueError, match="unknown kind 'float'"):
        _native.CommandTable([("s", 0, [("v", 1, 1, 0, 32, "float", 0.0, 1.0, False)])])
    with pytest.raises(ValueError, match="Real32 with 16 bit"):
        _native.CommandTable([("s", 0, [("v", 1, 1, 0, 16, "real32", 0.0, 1.0, False)])])
    table = _native.CommandTable([])
    data = serialize_message(request("s", "v", 1.0))
    with pytest.raises(ValueError, match="message ends inside field 'value'"):
        table.resolve(data[:30])


def test_loaded_library_is_found_in_the_maps(tmp_path: Path) -> None:
    maps = tmp_path / "maps"
    maps.write_text(
        "7f00-7f01 r-xp 00000000 08:01 1 /opt/ros/lib/librcl_action.so\n"
        "7f01-7f02 r-xp 00000000 08:01 2 /opt/ros/lib/librcl.so\n"
        "7f02-7f03 r-xp 00000000 08:01 3 /usr/lib/with space/librcutils.so.1\n"
    )
    assert loaded_library("librcl", maps) == "/opt/ros/lib/librcl.so"
    assert loaded_library("librcutils", maps) == "/usr/lib/with space/librcutils.so.1"
    with pytest.raises(CommandPathError, match=r"librmw\.so is not loaded"):
        loaded_library("librmw", maps)


# ---------------------------------------------------------------------------- the receiver


class Rig:
    """A bus on the in-process simulator, an rclpy node serving pdo_listener natively, and a
    second node publishing commands and listening to the answers, in one ROS context."""

    def __init__(self, handler: Callable[[WriteVariable, bytes], None], lease: Any = None) -> None:
        self.context = Context()
        rclpy.init(context=self.context, domain_id=domain_for(os.getpid(), 5))
        cfg = load_bus_config(REPO / "config" / "laelaps.yaml")
        # Nobody feeds the engine's command watchdog here: a trip between two requests would
        # void the first (a stop's reset does not restart, docs/security.md), which is not
        # what these tests are about.
        cfg.bus.watchdog_ms = 0
        self.bus = Bus.open(cfg, link=build_network(cfg))
        self.bus.start()
        self.spec = bridge.bus_spec(self.bus)
        self.node = rclpy.create_node("native_under_test", context=self.context)
        results = self.node.create_publisher(WriteResult, "write_results", QOS_COMMANDS)
        self.path = NativeCommandPath(
            self.node, "pdo_listener", QOS_COMMANDS, results, handler, priority=10, lease=lease
        )
        self.client = rclpy.create_node("native_client", context=self.context)
        self.publisher = self.client.create_publisher(WriteVariable, "pdo_listener", QOS_COMMANDS)
        # A second publisher (another writer: its own GID) on the same client node.
        self.other = self.client.create_publisher(WriteVariable, "pdo_listener", QOS_COMMANDS)
        self.publishers: list[bytes] = []  # the GID of each deferred request, as handled
        self.answers: dict[int, WriteResult] = {}
        self.client.create_subscription(
            WriteResult,
            "write_results",
            lambda m: self.answers.__setitem__(m.request_id, m),
            QOS_COMMANDS,
        )
        self.executor = SingleThreadedExecutor(context=self.context)
        self.executor.add_node(self.client)
        self.thread = threading.Thread(target=self.executor.spin, daemon=True)
        self.thread.start()
        wait_until(lambda: self.publisher.get_subscription_count() > 0)
        wait_until(lambda: self.other.get_subscription_count() > 0)

    def publish(self, r: WriteVariable) -> None:
        self.publisher.publish(r)

    def output(self, slave: str, variable: str) -> Any:
        return self.bus.outputs(slave)[variable]

    def close(self) -> None:
        self.path.close()
        self.executor.shutdown(timeout_sec=2)
        self.client.destroy_node()
        self.node.destroy_node()
        self.bus.close()
        self.context.try_shutdown()
        self.thread.join(5)


def wait_until(condition: Callable[[], object], timeout: float = 10.0) -> None:
    deadline = time.monotonic() + timeout
    while not condition():
        if time.monotonic() > deadline:
            raise AssertionError("condition not met in time")
        time.sleep(0.01)


@pytest.fixture
def rig() -> Iterator[tuple[Rig, list[WriteVariable]]]:
    deferred: list[WriteVariable] = []
    holder: dict[str, Rig] = {}

    def handle(msg: WriteVariable, publisher: bytes) -> None:
        # The Python path's stand-in: apply text values after a pause, so a later native-able
        # request would overtake it if the order were not kept.
        assert len(publisher) == 16  # the GID of the publisher that sent it
        time.sleep(0.2)
        holder["rig"].publishers.append(publisher)
        deferred.append(msg)
        rig = holder["rig"]
        if msg.text.strip().isdigit():
            rig.bus.write(msg.slave, msg.variable, int(msg.text))

    r = Rig(handle)
    holder["rig"] = r
    try:
        yield r, deferred
    finally:
        r.close()


@pytest.mark.netns  # SCHED_FIFO threads, a bus with locked memory
def test_a_published_write_reaches_the_engine_without_python(
    rig: tuple[Rig, list[WriteVariable]],
) -> None:
    r, deferred = rig
    r.path.attach(r.bus, r.spec)
    assert r.path.receiver.scheduling() == "SCHED_FIFO 10"
    r.publish(request("front_left_leg", "Kp100_hip", 4321.0, request_id=11))
    wait_until(lambda: r.output("front_left_leg", "Kp100_hip") == 4321)
    wait_until(lambda: 11 in r.answers)
    assert r.answers[11].success
    assert r.answers[11].message == "wrote front_left_leg.Kp100_hip=4321"
    r.publish(request(variable="Kd1000_knee", value=3.0, all_slaves=True, request_id=12))
    wait_until(lambda: 12 in r.answers)
    assert [r.output(s.name, "Kd1000_knee") for s in r.spec.slaves] == [3] * 4
    counters = r.path.counters()
    assert counters["applied"] == 2 and counters["deferred"] == 0 and not deferred
    # A leg's trajectory goes to Python, which checks it against the workspace.
    r.publish(request(variable="b_ellipse100", value=3.0, all_slaves=True, request_id=13))
    r.publish(request("front_left_leg", "b_ellipse100", 3.0, request_id=14))
    wait_until(lambda: len(deferred) == 2)
    assert [m.request_id for m in deferred] == [13, 14]
    assert r.path.last_command_ns() > 0
    # The slave received it: the simulated firmware echoes its gains in the frames it answers.
    wait_until(lambda: r.bus.read("front_left_leg", "Kp100_hip") == 4321)


@pytest.mark.netns  # SCHED_FIFO threads, a bus with locked memory
def test_deferred_requests_keep_their_order(rig: tuple[Rig, list[WriteVariable]]) -> None:
    r, deferred = rig
    r.path.attach(r.bus, r.spec)
    r.publish(request("front_left_leg", "Kp100_knee", text="7", request_id=21))
    r.publish(request("front_left_leg", "Kp100_knee", 9.0, request_id=22))
    wait_until(lambda: len(deferred) == 2)
    assert [m.request_id for m in deferred] == [21, 22]
    assert r.path.counters()["deferred"] == 2
    # Once the queue is empty, valid requests take the native path again.
    r.publish(request("front_left_leg", "Kp100_knee", 10.0, request_id=23))
    wait_until(lambda: r.output("front_left_leg", "Kp100_knee") == 10)
    assert r.path.counters()["applied"] == 1 and len(deferred) == 2


@pytest.mark.netns  # SCHED_FIFO threads, a bus with locked memory
def test_a_flooding_publisher_does_not_hold_up_another(
    rig: tuple[Rig, list[WriteVariable]],
) -> None:
    """Requests Python must handle are queued per publisher and served in turn: while one
    publisher's ten slow requests wait, another's valid request is applied at once and its own
    deferred request is handled before the flood's last."""
    r, deferred = rig
    r.path.attach(r.bus, r.spec)
    for i in range(10):
        r.publish(request("front_left_leg", "Kp100_knee", text=str(100 + i), request_id=40 + i))
    wait_until(lambda: len(deferred) >= 1)
    r.other.publish(request("front_left_leg", "Kp100_hip", 555.0, request_id=60))
    r.other.publish(request("front_left_leg", "Kp100_hip", text="556", request_id=61))
    wait_until(lambda: 60 in r.answers)
    assert r.answers[60].success
    assert len(deferred) < 10  # applied natively while the flood still waits for Python
    wait_until(lambda: len(deferred) == 11, timeout=15)
    order = [m.request_id for m in deferred]
    assert order.index(61) < order.index(49)  # served in turn, not behind the whole flood
    assert [i for i in order if i != 61] == list(range(40, 50))  # each publisher in order
    assert r.path.counters()["applied"] == 1
    assert len(set(r.publishers)) == 2  # told apart by their GIDs
    wait_until(lambda: r.output("front_left_leg", "Kp100_knee") == 109)


@pytest.mark.netns  # SCHED_FIFO threads, a bus with locked memory
def test_the_lease_is_checked_by_publisher_on_the_native_thread() -> None:
    from ether_ros import _native

    gate = _native.LeaseGate()
    gate.set_enabled(True)
    deferred: list[tuple[WriteVariable, bytes]] = []
    r = Rig(lambda m, p: deferred.append((m, p)), lease=gate)
    try:
        r.path.attach(r.bus, r.spec)
        r.publish(request("front_left_leg", "Kp100_hip", 11.0, request_id=71))
        wait_until(lambda: 71 in r.answers)
        assert not r.answers[71].success
        assert "acquire it with the 'lease' service" in r.answers[71].message
        # Learn the publisher's GID from a request let through with the lease off.
        gate.set_enabled(False)
        r.publish(request("front_left_leg", "Kp100_hip", text="12", request_id=72))
        wait_until(lambda: len(deferred) == 1)
        mine = deferred[0][1]
        gate.set_enabled(True)
        now = time.clock_gettime_ns(time.CLOCK_MONOTONIC)
        gate.grant("/holder", 5, [mine], now + 60_000_000_000)
        r.publish(request("front_left_leg", "Kp100_hip", 13.0, request_id=73))
        wait_until(lambda: r.output("front_left_leg", "Kp100_hip") == 13)
        r.other.publish(request("front_left_leg", "Kp100_hip", 14.0, request_id=74))
        wait_until(lambda: 74 in r.answers)
        assert r.answers[74].message == "the control lease is held by '/holder'"
        assert r.output("front_left_leg", "Kp100_hip") == 13
        assert r.path.counters()["refused_lease"] == 2
    finally:
        r.close()


@pytest.mark.netns  # SCHED_FIFO threads, a bus with locked memory
def test_detached_every_request_goes_to_python(rig: tuple[Rig, list[WriteVariable]]) -> None:
    r, deferred = rig
    before = r.output("front_left_leg", "Kp100_hip")
    r.publish(request("front_left_leg", "Kp100_hip", before + 1, request_id=31))
    wait_until(lambda: len(deferred) == 1)
    assert r.output("front_left_leg", "Kp100_hip") == before
    assert r.path.counters()["applied"] == 0
    r.path.close()
    assert not r.path.receiver.is_running()


def test_garbage_never_crashes_the_resolver(mixed_bus: tuple[Bus, BusSpec]) -> None:
    """Bytes from the wire are untrusted: every mutation of a valid message is either decoded
    and resolved like any request, or refused with ValueError naming what is wrong."""

    bus, spec = mixed_bus
    table = command_table(bus, spec)
    good = serialize_message(request("front_left_leg", "Kp100_knee", 12.0, request_id=3))
    outcomes = mutation_outcomes(table.resolve, good, seed=4, count=3000)
    assert all(outcomes.values()), outcomes


def mutation_outcomes(
    resolve: Callable[[bytes], object], good: bytes, seed: int, count: int
) -> dict[str, int]:
    """How ``resolve`` took ``count`` random mutations of ``good`` (1–4 bytes changed, a third
    also truncated): applied, deferred (None) or refused with a ValueError naming the field or
    the encapsulation (anything else fails the test)."""
    import random

    rng = random.Random(seed)
    outcomes = {"applied": 0, "deferred": 0, "refused": 0}
    for _ in range(count):
        data = bytearray(good)
        for _ in range(rng.randint(1, 4)):
            data[rng.randrange(len(data))] = rng.randrange(256)
        data = data[: rng.randint(0, len(data))] if rng.random() < 0.3 else data
        try:
            out = resolve(bytes(data))
        except ValueError as exc:
            assert "field" in str(exc) or "encapsulation" in str(exc), exc
            outcomes["refused"] += 1
            continue
        outcomes["deferred" if out is None else "applied"] += 1
    return outcomes
