"""DC arithmetic (delays per branch: tests/unit/test_topology.py): offsets, SYNC0 start time,
AssignActivate bytes; and the DC bring-up against the in-process simulator on its manual
clock, in both modes."""

from __future__ import annotations

import random
import struct
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import pytest

from ether_ros._native import Reset
from ether_ros._native.protocol import reg
from ether_ros.config import load_bus_config
from ether_ros.master.datagrams import Cmd, Datagram, DatagramService, fixed_address, u16, u64
from ether_ros.master.dc import (
    MASK64,
    DcSlave,
    DistributedClocks,
    assign_activate_bytes,
    decode_time_diff,
    diff32,
    reference_filter_depth,
    sync0_start_time,
    system_time_offsets,
)
from ether_ros.sim.spec import bus_order, slave_spec
from ether_ros.topology import line

REPO = Path(__file__).resolve().parents[2]
LAELAPS = REPO / "config" / "laelaps.yaml"
START_NS = 5_000_000_000
TIME_OFFSET_NS = 630_000_000_000_000_000  # DC system time = host time + this (~20 years)
CYCLE_NS = 400_000


def test_diff32_handles_wraparound() -> None:
    assert diff32(10, 5) == 5
    assert diff32(3, 0xFFFF_FFFE) == 5


def test_offsets_make_every_system_time_equal_to_master_plus_delay() -> None:
    master = 1_000_000_000_000
    local = [5, 123_456_789, 2**63 + 7]
    delays = [0, 700, 1400]
    offsets = system_time_offsets(master, local, delays)
    for t, d, o in zip(local, delays, offsets, strict=True):
        assert (t + o) & MASK64 == master + d


def test_sync0_start_is_aligned_to_the_cycle_plus_shift_with_margin() -> None:
    cycle, shift, margin = 400_000, 55_000, 100_000_000
    now = 1_234_567_891
    start = sync0_start_time(now, cycle, shift, margin)
    assert (start - shift) % cycle == 0
    assert start - shift >= now + margin
    assert start - shift < now + margin + cycle
    with pytest.raises(ValueError):
        sync0_start_time(now, 0, 0, 0)


def test_assign_activate_low_byte_is_unit_control_high_byte_activation() -> None:
    assert assign_activate_bytes(0x0300) == (0x00, 0x03)
    assert assign_activate_bytes(0x0700) == (0x00, 0x07)
    assert assign_activate_bytes(0x0001) == (0x01, 0x00)


def test_time_difference_sign_bit() -> None:
    assert decode_time_diff(0x0000_0010) == 16
    assert decode_time_diff(0x8000_0010) == -16


@dataclass
class ManualBus:
    """Four leg slaves on a simulated line whose time only moves when the test moves it."""

    net: Any
    engine: Any
    dg: DatagramService
    slaves: list[DcSlave]
    now: int = START_NS

    def advance(self, ns: int) -> None:
        self.net.advance_clock(ns)
        self.now += ns

    def master_time(self) -> int:
        return self.now + TIME_OFFSET_NS

    def time_diff(self, pos: int) -> int:
        data, wkc = self.dg.fprd(self.slaves[pos].station, 0x092C, 4)
        assert wkc == 1
        return decode_time_diff(struct.unpack("<I", data)[0])


@pytest.fixture
def manual_bus() -> Iterator[ManualBus]:
    from ether_ros._native import Engine, SimNetwork

    cfg = load_bus_config(LAELAPS)
    net = SimNetwork(manual_clock_ns=START_NS)
    drifts = [50.0, -7.5, 25.0, -3.0]  # the reference drifts +50 ppm
    for pos, (slave, drift) in enumerate(zip(bus_order(cfg), drifts, strict=True)):
        # The drift as the configuration gives it (sim.drift_ppm): the spec is made whole.
        sim = slave.sim.model_copy(update={"drift_ppm": drift})
        net.add_slave(slave_spec(slave.model_copy(update={"sim": sim}), pos))
    engine = Engine.open_sim(net)
    dg = DatagramService(engine)
    slaves = []
    for pos in range(len(drifts)):
        assert dg.apwr(pos, 0x0010, u16(0x1001 + pos)) == 1
        slaves.append(DcSlave(pos, 0x1001 + pos, f"leg{pos}"))
    try:
        yield ManualBus(net, engine, dg, slaves)
    finally:
        engine.close()


def _bring_up(bus: ManualBus) -> DistributedClocks:
    dc = DistributedClocks(bus.dg, bus.master_time, drift_frames=3000)
    dc.measure(bus.slaves, line(len(bus.slaves)))
    dc.configure_reference_loop(bus.slaves[0], CYCLE_NS)
    # Static drift compensation, 16 FRMW per frame, frames 100 µs apart.
    frames = 3000 // 16
    for _ in range(frames):
        bus.advance(100_000)
        bus.dg.batch([Datagram(Cmd.FRMW, fixed_address(0x1001, reg.DC_SYSTEM_TIME), 8)] * 16)
    return dc


def _cycles(bus: ManualBus, seconds: float, write_reference: bool) -> Callable[[], list[int]]:
    """Run 400 µs cycles as the engine does; the frame leaves 10..40 µs after the planned
    instant whose master time the FPWR carries. Returns a reader of all slaves' 0x092C."""
    rng = random.Random(7)
    address = fixed_address(bus.slaves[0].station, reg.DC_SYSTEM_TIME)
    planned = bus.now + 100_000_000
    for _ in range(int(seconds * 1e9) // CYCLE_NS):
        lag = rng.randint(10_000, 40_000)
        bus.advance(planned + lag - bus.now)
        frame = [Datagram(Cmd.FRMW, address, 8)]
        if write_reference:
            frame.insert(0, Datagram(Cmd.FPWR, address, u64(planned + TIME_OFFSET_NS)))
        assert all(r.wkc >= 1 for r in bus.dg.batch(frame))
        planned += CYCLE_NS
    return lambda: [bus.time_diff(pos) for pos in range(len(bus.slaves))]


def test_reference_filter_spans_at_most_a_quarter_of_the_loop_time_constant() -> None:
    assert reference_filter_depth(400_000) == 6  # 64 cycles = 25.6 ms of a 160 ms loop
    assert reference_filter_depth(1_000_000) == 5
    assert reference_filter_depth(125_000) == 8  # capped
    assert reference_filter_depth(100_000_000) == 0
    for cycle in (250_000, 400_000, 1_000_000, 4_000_000):
        assert (1 << reference_filter_depth(cycle)) * cycle <= 40_000_000
    with pytest.raises(ValueError):
        reference_filter_depth(0)


def test_reference_loop_settings_reach_the_reference(manual_bus: ManualBus) -> None:
    dc = DistributedClocks(manual_bus.dg, manual_bus.master_time)
    dc.configure_reference_loop(manual_bus.slaves[0], 400_000)
    start, _ = manual_bus.dg.fprd(0x1001, 0x0930, 2)
    depth, _ = manual_bus.dg.fprd(0x1001, 0x0934, 1)
    assert struct.unpack("<H", start)[0] == 0x7FFF and depth[0] == 6
    # The others keep the ESC defaults.
    start, _ = manual_bus.dg.fprd(0x1002, 0x0930, 2)
    depth, _ = manual_bus.dg.fprd(0x1002, 0x0934, 1)
    assert struct.unpack("<H", start)[0] == 0x1000 and depth[0] == 4


def test_a_reset_reference_gets_its_loop_settings_again(manual_bus: ManualBus) -> None:
    dc = DistributedClocks(manual_bus.dg, manual_bus.master_time)
    dc.measure(manual_bus.slaves, line(len(manual_bus.slaves)))
    reference = manual_bus.slaves[0]
    dc.configure_reference_loop(reference, 1_000_000)
    manual_bus.net.inject(Reset(slave=0))
    assert manual_bus.dg.apwr(0, 0x0010, u16(reference.station)) == 1
    start, _ = manual_bus.dg.fprd(reference.station, 0x0930, 2)
    assert struct.unpack("<H", start)[0] == 0x1000  # power-on default
    dc.resync_slave(None, reference)
    start, _ = manual_bus.dg.fprd(reference.station, 0x0930, 2)
    depth, _ = manual_bus.dg.fprd(reference.station, 0x0934, 1)
    assert struct.unpack("<H", start)[0] == 0x7FFF and depth[0] == 5


def test_time_difference_sign_matches_the_slave() -> None:
    # A slave's 0x092C is local − received: a received time ahead of the slave reads negative.
    from ether_ros._native import Engine, SimNetwork

    cfg = load_bus_config(LAELAPS)
    net = SimNetwork(manual_clock_ns=START_NS)
    net.add_slave(slave_spec(bus_order(cfg)[0], 0))
    with Engine.open_sim(net) as engine:
        dg = DatagramService(engine)
        dg.apwr(0, 0x0010, u16(0x1001))
        now = struct.unpack("<Q", dg.fprd(0x1001, reg.DC_SYSTEM_TIME, 8)[0])[0]
        assert dg.fpwr(0x1001, reg.DC_SYSTEM_TIME, u64(now + 5_000)) == 1
        raw = struct.unpack("<I", dg.fprd(0x1001, 0x092C, 4)[0])[0]
        assert raw & 0x8000_0000, "bit 31: local smaller than received"
        assert decode_time_diff(raw) == -5_000


def test_offsets_from_the_master_clock_put_every_slave_on_it(manual_bus: ManualBus) -> None:
    dc = DistributedClocks(manual_bus.dg, manual_bus.master_time, drift_frames=0)
    dc.measure(manual_bus.slaves, line(len(manual_bus.slaves)))
    delays = [s.delay_ns for s in manual_bus.slaves]
    # The ESC stamps on its 10 ns clock with a phase jitter (ESC datasheet: 100 MHz), so a
    # measured delay is right to within two clock steps.
    assert all(abs(d - want) <= 20 for d, want in zip(delays, [0, 500, 1000, 1500], strict=True))
    # Right after the offsets (the manual clock stands still), each slave's system time is the
    # master's time at the latch + its delay: a frame passes slave i `delay` after the
    # reference, so all slaves agree on the system time at each instant (to a few 10 ns steps).
    for s in manual_bus.slaves:
        data, _ = manual_bus.dg.fprd(s.station, reg.DC_SYSTEM_TIME, 8)
        system_time = struct.unpack("<Q", data)[0]
        assert abs(system_time - manual_bus.master_time() - s.delay_ns) <= 30, s.name


def test_ref_follows_master_locks_reference_and_followers(manual_bus: ManualBus) -> None:
    _bring_up(manual_bus)
    read_diffs = _cycles(manual_bus, 3.0, write_reference=True)
    diffs = read_diffs()
    info = [manual_bus.net.slave_info(pos) for pos in range(4)]
    # The reference steers onto the written master time: Δ is back near 0 (within the 10..40 µs
    # send jitter, averaged) and its speed correction learned its +50 ppm drift, far from the
    # ±500 ppm limit it used to saturate at.
    assert abs(diffs[0]) < 10_000, diffs
    assert abs(info[0]["dc_correction_ppm"] + 50.0) < 10.0, info[0]
    # The followers follow the reference.
    assert all(abs(d) < 5_000 for d in diffs[1:]), diffs
    # And the reference's system time is the master's, minus the mean send lag (25 µs) and
    # one hop.
    reference_time = manual_bus.dg.frmw(0x1001, reg.DC_SYSTEM_TIME, 8)[0]
    lag = manual_bus.master_time() - struct.unpack("<Q", reference_time)[0]
    assert 10_000 < lag < 40_000, lag


def test_master_follows_ref_followers_lock_to_the_free_reference(manual_bus: ManualBus) -> None:
    _bring_up(manual_bus)
    read_diffs = _cycles(manual_bus, 1.0, write_reference=False)
    diffs = read_diffs()
    assert all(abs(d) <= 5 for d in diffs[1:]), diffs
    info = [manual_bus.net.slave_info(pos) for pos in range(4)]
    assert info[0]["dc_correction_ppm"] == 0.0
    for pos, drift in ((1, -7.5), (2, 25.0), (3, -3.0)):
        assert abs(info[pos]["dc_correction_ppm"] - (50.0 - drift)) < 0.5, info[pos]
