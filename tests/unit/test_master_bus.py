"""The Bus API end to end over the in-process link to the real simulator (no root needed):
bring-up to OP, process data both ways, validation before the wire, SDO in OP, stop."""

from __future__ import annotations

import time
from collections.abc import Iterator

import pytest

from ether_ros._native import Reset
from ether_ros.config.bus import PdoAssign
from ether_ros.config.process import ProcessValueError
from ether_ros.errors import BusError
from ether_ros.master import Bus
from ether_ros.testing.wait import wait_for
from master_rigs import relaxed_config, sim_bus, sim_network


@pytest.fixture
def bus() -> Iterator[Bus]:
    with sim_bus() as (b, _net):
        yield b


def test_validation_happens_before_the_wire(bus: Bus) -> None:
    with pytest.raises(ProcessValueError, match="no process variable 'no_such_thing'"):
        bus.write("front_left_leg", "no_such_thing", 1)
    with pytest.raises(ProcessValueError, match="is an input"):
        bus.write("front_left_leg", "hip_angle", 1)
    with pytest.raises(ProcessValueError, match="out of range"):
        bus.write("front_left_leg", "Kp100_knee", 40000)  # int16
    with pytest.raises(ProcessValueError, match="integer"):
        bus.write("front_left_leg", "Kp100_knee", "fast")
    with pytest.raises(ProcessValueError, match="bool"):
        bus.write("front_left_leg", "State_Machine", 2)
    with pytest.raises(BusError, match="no slave 'left_wing'"):
        bus.write("left_wing", "State_Machine", 1)
    assert bus.outputs("front_left_leg")["State_Machine"] == 0


def test_start_to_op_exchange_and_stop(bus: Bus) -> None:
    bus.start()
    assert [s.state for s in bus.states()] == ["OP"] * 4
    assert bus.layout is not None and bus.layout.expected_wkc == 12
    bus.write("front_left_leg", "Kp100_knee", 1234)
    assert bus.read("front_left_leg", "Kp100_knee") == 1234
    inputs = bus.inputs("hind_right_leg")
    assert "hip_angle" in inputs and "knee_angle" in inputs
    samples = bus.samples()
    assert len(samples) > 0
    assert int(samples.records["wkc"][-1]) == 12
    bus.stop()
    assert [s.state for s in bus.states()] == ["INIT"] * 4


def test_identity_mismatch_is_named() -> None:
    cfg = relaxed_config()
    net = sim_network(cfg)
    cfg.slaves[2].product_code = 0x0BADBEEF
    message = (
        r"slave 2 \(front_left_leg\): expected vendor 0x00000A12 product 0x0BADBEEF, "
        r"found vendor 0x00000A12 product 0x00A986FD"
    )
    with pytest.raises(BusError, match=message):
        Bus.open(cfg, link=net)


def test_reset_reference_clock_comes_back_in_sync() -> None:
    cfg = relaxed_config()
    net = sim_network(cfg)
    with Bus.open(cfg, link=net, drift_frames=100) as bus:
        bus.start()
        events: list[str] = []
        bus.on_event(lambda e: events.append(f"{e.kind} {e.slave}"))
        net.inject(Reset(slave=0))  # type: ignore[attr-defined]
        deadline = time.monotonic() + 10
        while "slave_recovered hind_right_leg" not in events and time.monotonic() < deadline:
            time.sleep(0.02)
        assert "slave_lost hind_right_leg" in events
        assert "slave_recovered hind_right_leg" in events
        assert [s.state for s in bus.states()] == ["OP"] * 4
        # Its system time was restored from a running slave (the reset put it back at its local
        # time, years away from the system time since 2000): the two read the same date.
        ref, other = (net.slave_info(p) for p in (0, 1))  # type: ignore[attr-defined]
        assert abs(ref["dc_system_time"] - other["dc_system_time"]) < 1_000_000_000
        assert ref["sync0_active"]


def test_pdo_assignment_override_is_written_over_coe() -> None:
    cfg = relaxed_config("mixed.yaml")
    net = sim_network(cfg)
    io = cfg.slaves[4]
    io.pdo_assign = PdoAssign(rx=[0x1601], tx=[0x1A01])  # analog only
    with Bus.open(cfg, link=net, drift_frames=100) as bus:
        area = bus.slave("io_box").area
        assert area is not None and (area.output_bytes, area.input_bytes) == (4, 4)
        bus.start()
        assert [s.state for s in bus.states()] == ["OP"] * 5
        assert bus.sdo_read("io_box", 0x1C12, 0) == 1
        assert bus.sdo_read("io_box", 0x1C12, 1) == 0x1601
        with pytest.raises(ProcessValueError, match="DigitalOutput1"):
            bus.write("io_box", "DigitalOutput1", True)
        bus.write("io_box", "AnalogOutput2", -1200)
        wait_for("the analog echo", lambda: bus.read("io_box", "AnalogInput2") <= -1100)  # type: ignore[operator]


def test_pdo_override_on_a_fixed_device_is_refused_by_name() -> None:
    cfg = relaxed_config()
    net = sim_network(cfg)
    cfg.slaves[1].pdo_assign = PdoAssign(rx=[0x1600], tx=[])
    message = r"slave 1 \(hind_left_leg\): .* cannot change its PDO"
    with Bus.open(cfg, link=net, drift_frames=100) as bus, pytest.raises(BusError, match=message):
        bus.start()


def test_writers_of_different_variables_keep_each_others_values() -> None:
    cfg = relaxed_config("mixed.yaml")
    with Bus.open(cfg, link=sim_network(cfg), drift_frames=100) as bus:
        bus.start()
        io = bus.slave("io_box")
        assert io.area is not None and io.layout is not None
        # A second writer (like the native ROS command path) sets DigitalOutput1 in the engine
        # directly, behind the Bus's back.
        dout1 = io.layout.variable("DigitalOutput1")
        bus.engine.write_output_fields([(io.area.output_offset * 8 + dout1.bit_offset, 1, 1)])
        # Then Python writes other variables of the same slave. Writing the slave's whole area
        # from the Bus's own copy would put DigitalOutput1 back to 0.
        bus.write_many("io_box", {"DigitalOutput3": True, "AnalogOutput1": 1000})
        bus.write("io_box", "DigitalOutput8", True)
        outputs = bus.outputs("io_box")
        assert outputs["DigitalOutput1"] is True and bus.read("io_box", "DigitalOutput1") is True
        assert outputs["DigitalOutput3"] is True and outputs["DigitalOutput8"] is True
        assert outputs["AnalogOutput1"] == 1000 and outputs["DigitalOutput2"] is False
        begin = io.area.output_offset
        image = bytes(bus.engine.outputs())
        assert image[begin] == 0b1000_0101
        assert image[begin + 1 : begin + 3] == (1000).to_bytes(2, "little")

        # Both writers' values reach the slave (its firmware echoes outputs to inputs).
        def echoed() -> bool:
            inputs = bus.inputs("io_box")
            digital = all(inputs[f"DigitalInput{n}"] is True for n in (1, 3, 8))
            return digital and float(inputs["AnalogInput1"]) > 900

        wait_for("the echo of both writers' outputs", echoed)
        assert bus.read("io_box", "DigitalInput2", stale_ok=True) is False


def test_write_all_is_one_masked_write_and_a_bad_value_changes_nothing(bus: Bus) -> None:
    bus.start()
    legs = [s.name for s in bus.slaves]
    bus.write_many("front_left_leg", {"Kp100_knee": -7, "Red_LED": True})
    before = bytes(bus.engine.outputs())
    with pytest.raises(ProcessValueError, match="bool"):
        bus.write_all("Blue_LED", 2)
    assert bytes(bus.engine.outputs()) == before
    assert bus.write_all("Blue_LED", True) == 4
    for leg in legs:
        assert bus.read(leg, "Blue_LED") is True
    # Neighbouring bits and variables stay as they were.
    assert bus.outputs("front_left_leg")["Red_LED"] is True
    assert bus.read("front_left_leg", "Kp100_knee") == -7
    assert bus.outputs("hind_left_leg")["Red_LED"] is False


def test_engine_refuses_bad_output_fields_by_name(bus: Bus) -> None:
    bus.start()
    before = bytes(bus.engine.outputs())
    with pytest.raises(ValueError, match=r"output field #1 .*1\.\.=64"):
        bus.engine.write_output_fields([(0, 1, 1), (8, 65, 0)])
    assert bus.layout is not None
    past_outputs = bus.layout.output_bytes * 8
    with pytest.raises(ValueError, match="outside the output ranges"):
        bus.engine.write_output_fields([(past_outputs, 8, 1)])
    assert bytes(bus.engine.outputs()) == before


def test_branched_bus_to_op_with_delays_per_branch() -> None:
    cfg = relaxed_config("branched.yaml")
    with Bus.open(cfg, link=sim_network(cfg), drift_frames=100) as b:
        assert b.tree == cfg.tree()
        b.start()
        assert all(s.state == "OP" for s in b.states())
        # Where the frame enters each slave after the coupler (tests/unit/test_topology.py).
        # The ESCs stamp on their 10 ns clock with a phase jitter (ESC datasheet: 100 MHz), so a
        # measured delay is right to within two clock steps.
        delays = [s.dc.delay_ns for s in b.slaves if s.dc is not None]
        expected = [0, 450, 1050, 3000, 3700, 4750, 5900]
        assert all(abs(d - e) <= 20 for d, e in zip(delays, expected, strict=True)), delays


def test_links_without_a_configured_delay_have_a_real_links_delay() -> None:
    # Issue 17: with `sim.delay_ns` unset every measured propagation delay used to be 0, which no
    # real link gives. The legs are 100BASE-TX slaves (ESI Physics "YY"): each hop takes
    # ether_ros.sim.spec.DELAY_MII_NS, measured by the master on the ESC's 10 ns clock.
    from ether_ros.sim.spec import DELAY_MII_NS

    cfg = relaxed_config()
    for s in cfg.slaves:
        assert s.sim is not None
        s.sim.delay_ns = None
    with Bus.open(cfg, link=sim_network(cfg), drift_frames=100) as b:
        b.start()
        delays = [s.dc.delay_ns for s in b.slaves if s.dc is not None]
    expected = [k * DELAY_MII_NS for k in range(len(cfg.slaves))]
    assert all(abs(d - e) <= 20 for d, e in zip(delays, expected, strict=True)), delays


def test_the_eeprom_is_handed_back_to_the_pdi_after_the_sii_is_read() -> None:
    # Issue 17: the master took the EEPROM (0x0500 = 2, "force ECAT access") and never gave it
    # back; as SOEM, it offers it to the PDI (0x0500 = 1) once the SII is read, and the slave
    # application takes it (0x0501 bit 0, ESC datasheet "EEPROM access").
    cfg = relaxed_config()
    net = sim_network(cfg)
    with Bus.open(cfg, link=net, drift_frames=100) as b:
        b.start()
        assert all(s.state == "OP" for s in b.states())
        for p in range(len(cfg.slaves)):
            assert net.slave_info(p)["eeprom_at_pdi"], p  # type: ignore[attr-defined]
