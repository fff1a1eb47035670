"""One state machine brings the slaves up and brings them back (``master/slave_fsm.py``),
against the simulator in its own process and network namespace over a veth pair: a slave
power-cycled under a running bus and a cable pulled and plugged in again come back to OP while
the other slaves keep cycling; a configured slave that is missing, and a different device in
its place, are refused at bring-up naming the slave (and the configured and found identity).
Timing is never asserted: waits have generous deadlines and only the outcome is checked.
"""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path

import pytest
from test_master_veth import Recorder, _config, _states

from ether_ros.errors import BusError, IdentityMismatch
from ether_ros.master import Bus
from ether_ros.sim.proof import SimProcess
from ether_ros.testing.netns import VethPair
from ether_ros.testing.wait import wait_for

pytestmark = pytest.mark.netns

REPO = Path(__file__).resolve().parents[2]
MIXED = REPO / "config" / "mixed.yaml"
IO_BOX = "  - {name: io_box, position: 4, device: GenericIO, sim: {device: generic_io}}\n"


def _sim_config(tmp_path: Path, io_box_line: str) -> Path:
    """config/mixed.yaml for the simulator with the I/O box's line replaced."""
    text = MIXED.read_text().replace("[../devices]", f"[{REPO / 'devices'}]")
    assert IO_BOX in text
    path = tmp_path / "sim.yaml"
    path.write_text(text.replace(IO_BOX, io_box_line))
    return path


@pytest.fixture
def running(veth_ns: VethPair) -> Iterator[tuple[Bus, SimProcess]]:
    with (
        SimProcess(MIXED, veth_ns.slave, veth_ns.netns) as sim,
        Bus.open(_config(MIXED, veth_ns.master), drift_frames=500) as bus,
    ):
        bus.start()
        yield bus, sim


def _echo(bus: Bus, k: int, value: bool) -> bool:
    bus.write("io_box", f"DigitalOutput{k}", value)
    return bus.read("io_box", f"DigitalInput{k}") is value


def test_a_power_cycled_slave_comes_back_while_the_others_keep_cycling(
    running: tuple[Bus, SimProcess],
) -> None:
    bus, sim = running
    rec = Recorder()
    bus.on_event(rec)
    sim.fault("reset", slave="hind_left_leg")
    wait_for("loss report", lambda: "slave_lost" in rec.kinds("hind_left_leg"))
    # While its machine takes it back through INIT, PREOP and SAFEOP, the I/O box echoes.
    wait_for("echo on during the recovery", lambda: _echo(bus, 3, True))
    wait_for("recovery", lambda: "slave_recovered" in rec.kinds("hind_left_leg"), timeout=30)
    assert _states(bus) == ["OP"] * 5
    s = bus.slave("hind_left_leg")
    assert s.runtime.recoveries >= 1 and not s.runtime.lost
    assert [e for e in rec.kinds() if e == "slave_lost"] == ["slave_lost"]
    wait_for("echo off", lambda: _echo(bus, 3, False))


def test_a_cable_pulled_and_plugged_in_again(running: tuple[Bus, SimProcess]) -> None:
    bus, sim = running
    rec = Recorder()
    bus.on_event(rec)
    sim.fault("link", up=False, at="io_box")
    wait_for("loss report", lambda: "slave_lost" in rec.kinds("io_box"))
    assert _states(bus)[:4] == ["OP"] * 4  # the legs carry on
    sim.fault("link", up=True, at="io_box")
    wait_for("recovery", lambda: "slave_recovered" in rec.kinds("io_box"), timeout=30)
    assert _states(bus) == ["OP"] * 5
    wait_for("echo after the cable is back", lambda: _echo(bus, 6, True))
    assert not any(e.kind == "slave_lost" and e.slave != "io_box" for e in rec.events)


def test_a_configured_slave_missing_is_named(veth_ns: VethPair, tmp_path: Path) -> None:
    with (
        SimProcess(_sim_config(tmp_path, ""), veth_ns.slave, veth_ns.netns),
        pytest.raises(BusError, match=r"slave 4 \(io_box\) is missing: the bus has only 4"),
    ):
        Bus.open(_config(MIXED, veth_ns.master))


def test_a_different_device_in_its_place_is_named(veth_ns: VethPair, tmp_path: Path) -> None:
    leg = "  - {name: io_box, position: 4, device: LaelapsII_Leg}\n"
    with (
        SimProcess(_sim_config(tmp_path, leg), veth_ns.slave, veth_ns.netns),
        pytest.raises(IdentityMismatch) as err,
    ):
        Bus.open(_config(MIXED, veth_ns.master))
    e = err.value
    assert e.slave == "slave 4 (io_box)"
    assert e.found[1] == 0x00A986FD and e.expected[1] != e.found[1]
    assert "expected vendor" in str(e) and "found vendor 0x00000A12 product 0x00A986FD" in str(e)
