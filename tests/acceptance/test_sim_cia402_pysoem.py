"""The simulated CiA 402 drive seen by an independent master: pysoem (SOEM, which knows nothing
of our code) on one end of a veth pair, ``ether-ros sim --esi devices/servo_drive.xml --device
ServoDrive2`` in its own process and network namespace on the other.

SOEM scans the 2-axis drive, maps its default PDOs, runs DC with SYNC0 and brings it to OP; the
test then drives the power state machine by controlword to Operation enabled on both axes, moves
axis 2 along a ramp of target positions in CSP and checks that the actual position follows
while axis 1 holds still; finally it injects an encoder fault on axis 2 through the simulator's
control socket, sees the fault bit, the error code 0x7305 and the CoE emergency, resets the
fault and enables the axis again.
"""

from __future__ import annotations

import time
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import pytest

from ether_ros.config.from_esi import bus_config_for_esi
from ether_ros.sim.proof import OP, SimProcess, SoemBus
from ether_ros.testing.netns import VethPair

pytestmark = pytest.mark.netns

REPO = Path(__file__).resolve().parents[2]
SERVO = REPO / "devices" / "servo_drive.xml"
# Generous: a frame held up by a VM hiccup still counts as answered; we test behaviour here.
RECEIVE_TIMEOUT_US = 50_000
AXES = 2
CSP = 8
COUNTS_PER_REV = 16_384
# Statusword state codings (mask 0x6F): ready to switch on, switched on, operation enabled.
READY, SWITCHED_ON, ENABLED = 0x21, 0x23, 0x27
FAULT_BIT = 0x08


def key(axis: int, index: int) -> str:
    """The process variable of object ``index`` (axis 1 numbering) on ``axis`` (0-based)."""
    return f"{index + 0x800 * axis:#06x}:00"


@pytest.fixture
def drive(veth_apart: VethPair) -> Iterator[tuple[SimProcess, SoemBus]]:
    args = ["--esi", str(SERVO), "--device", "ServoDrive2"]
    with SimProcess(None, veth_apart.slave, veth_apart.netns, args) as sim:
        cfg = bus_config_for_esi(SERVO, "ServoDrive2", 1, interface=veth_apart.master)
        bus = SoemBus(cfg, veth_apart.master, RECEIVE_TIMEOUT_US, netns=veth_apart.master_netns)
        try:
            yield sim, bus
        finally:
            bus.close()


def _wait(bus: SoemBus, done: Callable[[], bool], what: str, timeout_s: float = 5.0) -> None:
    """Cycle until ``done()``; fail naming ``what`` with the inputs seen last."""
    deadline = time.monotonic() + timeout_s
    while not done():
        assert time.monotonic() < deadline, f"{what}: inputs {bus.inputs(0)}"
        bus.run(0.01)


def _status(bus: SoemBus, axis: int) -> int:
    return int(bus.inputs(0)[key(axis, 0x6041)])


def _wait_status(bus: SoemBus, axis: int, mask: int, value: int, what: str) -> None:
    _wait(bus, lambda: _status(bus, axis) & mask == value, f"axis {axis + 1}: {what}")


def _command(bus: SoemBus, axis: int, word: int, state: int) -> None:
    """Write the controlword and wait for the statusword's state coding (mask 0x6F)."""
    bus.set_outputs(0, {key(axis, 0x6040): word})
    _wait_status(bus, axis, 0x6F, state, f"controlword {word:#06x}")


def _enable_csp(bus: SoemBus, axis: int) -> None:
    """CSP with the target at the actual position, then shutdown, switch on, enable."""
    here = int(bus.inputs(0)[key(axis, 0x6064)])
    bus.set_outputs(0, {key(axis, 0x6060): CSP, key(axis, 0x607A): here})
    _command(bus, axis, 0x06, READY)
    _command(bus, axis, 0x07, SWITCHED_ON)
    _command(bus, axis, 0x0F, ENABLED)
    assert int(bus.inputs(0)[key(axis, 0x6061)]) == CSP


def _to_op(sim: SimProcess, bus: SoemBus) -> None:
    assert bus.scan() == 1
    size = bus.configure(dc=True)
    assert size == AXES * (14 + 20), "default PDOs: 14 output and 20 input bytes per axis"
    bus.set_watchdog(2000)  # a VM stall of this Python master must not look like a dead one
    info = sim.request({"op": "slave_info", "slave": 0})
    assert info["sync0_active"], info
    assert bus.request_op(), bus.states()
    assert bus.master.expected_wkc == 3


def test_identity_and_dictionary_over_sdo(drive: tuple[SimProcess, SoemBus]) -> None:
    sim, bus = drive
    assert sim.ready_line.endswith(f"1 slaves on {sim.interface} ready")
    assert bus.scan() == 1
    s = bus.slaves[0]
    assert (s.name, s.man, s.id) == ("Servo drive, 2 axes (CiA 402)", 0x00000A12, 0x00020002)
    assert int.from_bytes(s.sdo_read(0x1000, 0), "little") & 0xFFFF == 402
    for axis in range(AXES):
        supported = int.from_bytes(s.sdo_read(0x6502 + 0x800 * axis, 0), "little")
        assert supported == 0x3A5, "PP, PV, HM, CSP, CSV, CST"
        assert int.from_bytes(s.sdo_read(0x608F + 0x800 * axis, 1), "little") == COUNTS_PER_REV
    assert s.sdo_read(0x1C12, 2) == (0x1610).to_bytes(2, "little")
    assert s.sdo_read(0x1A10, 1) == (0x6841_0010).to_bytes(4, "little")


def test_csp_ramp_and_encoder_fault(drive: tuple[SimProcess, SoemBus]) -> None:
    sim, bus = drive
    _to_op(sim, bus)
    for axis in range(AXES):
        _wait_status(bus, axis, 0x4F, 0x40, "switch on disabled at power-on")
        _enable_csp(bus, axis)
    still = int(bus.inputs(0)[key(0, 0x6064)])
    start = int(bus.inputs(0)[key(1, 0x6064)])

    # A ramp on axis 2: 2 motor revolutions per second for 1 s, targets from the wall clock
    # so that the ramp keeps its speed whatever this Python master's cycle jitter.
    speed = 2 * COUNTS_PER_REV
    worst = 0
    t0 = time.monotonic()

    def ramp(_: int) -> None:
        nonlocal worst
        elapsed = min(time.monotonic() - t0, 1.0)
        target = start + round(speed * elapsed)
        bus.set_outputs(0, {key(1, 0x607A): target})
        worst = max(worst, abs(target - int(bus.inputs(0)[key(1, 0x6064)])))

    bus.run(1.3, ramp)
    goal = start + speed
    # Behind by about a cycle or two of ramp (plus a VM hiccup); never near a revolution.
    assert worst < COUNTS_PER_REV // 2, worst
    _wait(bus, lambda: abs(int(bus.inputs(0)[key(1, 0x6064)]) - goal) <= 5, "settle on goal")
    inputs = bus.inputs(0)
    assert _status(bus, 1) & 0x6F == ENABLED and not _status(bus, 1) & FAULT_BIT
    assert abs(int(inputs[key(1, 0x60F4)])) <= 5, "following error after settling"
    assert abs(int(inputs[key(0, 0x6064)]) - still) <= 2, "axis 1 held still"

    # An encoder fault on axis 2, from outside (the simulator's control socket).
    sim.fault("drive_fault", slave=0, axis=2, error="encoder")
    _wait_status(bus, 1, 0x4F, FAULT_BIT, "fault state")
    inputs = bus.inputs(0)
    assert int(inputs[key(1, 0x603F)]) == 0x7305
    assert _status(bus, 0) & 0x6F == ENABLED, "axis 1 keeps running"
    # The CoE emergency: SOEM takes it from the mailbox at its next mailbox exchange.
    emergency = _read_emergency(bus)
    assert (emergency.error_code, emergency.error_reg) == (0x7305, 0x21), vars(emergency)
    assert emergency.b1 == 2, "axis number in the first data byte"
    assert bus.slaves[0].sdo_read(0x1001, 0) == bytes([0x21]), "error register"

    # Fault reset (rising edge of bit 7), then enable again from where the axis is.
    bus.set_outputs(0, {key(1, 0x6040): 0x00})
    bus.run(0.05)
    bus.set_outputs(0, {key(1, 0x6040): 0x80})
    _wait_status(bus, 1, 0x4F, 0x40, "switch on disabled after the reset")
    assert int(bus.inputs(0)[key(1, 0x603F)]) == 0
    bus.set_outputs(0, {key(1, 0x6040): 0x00})
    bus.run(0.05)
    _enable_csp(bus, 1)
    assert [state for state, _ in bus.states()] == [OP]


def _read_emergency(bus: SoemBus) -> Any:
    """The emergency SOEM receives from the mailbox while it waits for an SDO answer (pysoem
    hands it to the slave's emergency callback)."""
    seen: list[Any] = []
    slave = bus.slaves[0]
    slave.add_emergency_callback(seen.append)
    deadline = time.monotonic() + 5
    while not seen and time.monotonic() < deadline:
        slave.sdo_read(0x1001, 0)
        bus.run(0.01)
    assert seen, "no CoE emergency reached SOEM"
    return seen[0]


def test_a_master_may_remap_the_pdos(drive: tuple[SimProcess, SoemBus]) -> None:
    """The PDOs are not fixed: SOEM remaps axis 1 to controlword + target position and
    statusword + position actual value in PREOP (free run this time), and the drive answers
    through the new layout."""
    sim, bus = drive
    assert bus.scan() == 1
    layout = {0x1600: (0x6040_0010, 0x607A_0020), 0x1A00: (0x6041_0010, 0x6064_0020)}

    def remap(slave: Any) -> None:
        for pdo, entries in layout.items():
            slave.sdo_write(pdo, 0, bytes([0]))
            for sub, entry in enumerate(entries, start=1):
                slave.sdo_write(pdo, sub, entry.to_bytes(4, "little"))
            slave.sdo_write(pdo, 0, bytes([len(entries)]))

    bus.master.slaves[0].setup_func = remap
    assert bus.master.config_map() == (6 + 14) + (6 + 20)
    bus.set_watchdog(2000)
    assert bus.request_op(), bus.states()
    slave = bus.slaves[0]
    assert (len(slave.output), len(slave.input)) == (6 + 14, 6 + 20)
    slave.output = (0x06).to_bytes(2, "little") + bytes(4 + 14)  # shutdown on axis 1
    deadline = time.monotonic() + 5
    while int.from_bytes(bytes(slave.input)[:2], "little") & 0x6F != READY:
        assert time.monotonic() < deadline, bytes(slave.input).hex()
        bus.run(0.01)
    # Axis 2 kept its default layout right behind: its statusword at input byte 6.
    assert int.from_bytes(bytes(slave.input)[6:8], "little") & 0x4F == 0x40
    assert sim.request({"op": "slave_info", "slave": 0})["sync0_active"] is False
