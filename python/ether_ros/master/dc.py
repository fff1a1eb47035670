"""Distributed clocks: propagation delays, offsets, drift compensation and SYNC0 activation.

Steps (ETG.1000.4 §9 / ESC datasheet "Distributed Clocks"):

1. A broadcast write to 0x0900 makes every slave latch the local time at which the frame passed
   each port (0x0900..0x090F, 32 bit) and at its processing unit (0x0918, 64 bit).
2. The frame enters a slave on port 0 and comes back into each open port after the branch
   behind it (ports in the order 0 → 3 → 1 → 2). On a tree, a slave C on port p of its DC
   parent P (``tree_delays``): the frame reached P, spent ``t_P[prev] − t_P[0]`` in P's
   earlier branches (prev: P's open port before p), then crossed the link to C, C's own
   branches (``t_C[last] − t_C[0]``) and the link back before ``t_P[p]``; so C's propagation
   delay (0x0928) is P's + the earlier branches + half of (branch time − C's own). In a line
   this is half the difference of neighbours' loop times.
3. System time offset (0x0920) makes every slave's system time (local + offset) read the same
   value at the same instant: the master's time when the latch frame passed the reference, plus
   the propagation delay to that slave.
4. Static drift compensation: many FRMW 0x0910 from the reference clock; each slave compares the
   received time (+ its delay) with its own and trims its clock speed. A write to 0x0910 never
   sets a clock: the ESC averages Δ = local − received (shown in 0x092C) and speeds its clock up
   or slows it down, in bounded steps, until Δ ≈ 0. In ``ref_follows_master`` the engine writes
   the master's time (``CLOCK_MONOTONIC + time_offset_ns``, the same clock the offsets below
   are computed from) to the reference every cycle, so the offset written here only has to be
   right to within what the reference's loop slews out (µs), and its drift is left to that loop.
5. SYNC0: cycle time (0x09A0), start time (0x0990) aligned to a cycle boundary of the system
   time plus the configured shift, then the activation word from the ESI (AssignActivate, low
   byte → cyclic unit control 0x0980, high byte → activation 0x0981).
"""

from __future__ import annotations

import logging
import struct
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field

from ether_ros._native import protocol
from ether_ros._native.protocol import dc_time_difference, reg
from ether_ros.errors import BusError
from ether_ros.master.datagrams import (
    Cmd,
    Datagram,
    DatagramService,
    fixed_address,
    u16,
    u32,
    u64,
)
from ether_ros.topology import Link, forwarding_ports, used_ports

log = logging.getLogger(__name__)

MASK32 = 0xFFFFFFFF
MASK64 = 0xFFFFFFFFFFFFFFFF

# Seconds from 1970-01-01 to 2000-01-01: EtherCAT system time counts from the year 2000.
EPOCH_2000_S = 946_684_800

# The reference clock's time control loop, when it follows the master's time: the written time
# carries the master's send jitter (tens of µs on a PC), which the ESC's default loop (speed
# counter start 0x1000, Δ averaged over 16 compares) passes on as speed changes of tens of ppm
# that the other slaves must follow. The smallest bandwidth 0x0930 allows (8x below the
# default) and an average over up to a quarter of the loop's time constant keep the reference
# steady; the others keep the defaults (their compares carry no jitter).
REFERENCE_SPEED_COUNTER_START = 0x7FFF
# Loop time constant at that setting (the simulated ESC: 20 ms at 0x1000, proportional).
REFERENCE_LOOP_TAU_NS = 20_000_000 * REFERENCE_SPEED_COUNTER_START // 0x1000
MAX_FILTER_DEPTH = 8


def diff32(later: int, earlier: int) -> int:
    """``later - earlier`` for 32-bit latch times that may have wrapped in between."""
    return (later - earlier) & MASK32


def signed64(value: int) -> int:
    value &= MASK64
    return value - (1 << 64) if value & (1 << 63) else value


def tree_delays(tree: Sequence[Link], times: Mapping[int, Sequence[int]]) -> dict[int, int]:
    """Propagation delay from the first DC slave to every DC slave, on a tree.

    ``tree``: where each slave hangs (by position, every slave of the bus); ``times``: for the
    DC slaves (by position), their receive times at ports 0..3 (0x0900..0x090C, 32 bit) from
    one broadcast. A slave's DC parent is the nearest DC slave towards the master, and the
    branch it sits in is the parent's port towards it. The frame's way out and back over a
    link take equally long (the spec's assumption). A DC slave without a DC slave before it
    (the reference, or one on a branch of a slave without DC that does not lead through the
    reference) gets 0.
    """
    delays: dict[int, int] = {}
    for c in sorted(times):
        link = tree[c]
        while link.parent is not None and link.parent not in times:
            link = tree[link.parent]
        parent, port = link.parent, link.port
        if parent is None:
            delays[c] = 0
            continue
        t_p, t_c = times[parent], times[c]
        # The parent's open port the frame came back through just before it left through
        # `port` (port 0 itself when this is the parent's first branch).
        before = [
            q
            for q in forwarding_ports(used_ports(tree, parent))
            if protocol.PORT_ORDER.index(q) < protocol.PORT_ORDER.index(port)
        ]
        prev = before[-1] if before else 0
        own = forwarding_ports(used_ports(tree, c))
        inside = diff32(t_c[own[-1]], t_c[0]) if own else 0
        branch = diff32(t_p[port], t_p[prev])
        delays[c] = delays[parent] + diff32(t_p[prev], t_p[0]) + max(0, branch - inside) // 2
    return delays


def system_time_offsets(
    master_time: int, local_times: Sequence[int], delays: Sequence[int]
) -> list[int]:
    """Offsets (0x0920, two's complement u64) so that local + offset = master's system time.

    ``local_times`` are the processing-unit latches (0x0918) of one broadcast; the frame passed
    slave *i* ``delays[i]`` ns after it passed the reference, when the master's clock read
    ``master_time``.
    """
    return [(master_time + d - t) & MASK64 for t, d in zip(local_times, delays, strict=True)]


def sync0_start_time(now: int, cycle_ns: int, shift_ns: int, margin_ns: int) -> int:
    """First SYNC0: the first cycle boundary of the system time at least ``margin_ns`` from
    ``now``, plus the shift (the master sends at the boundaries, slaves act ``shift`` later)."""
    if cycle_ns <= 0:
        raise ValueError("cycle time must be positive")
    earliest = now + margin_ns
    boundary = -(-earliest // cycle_ns) * cycle_ns
    return boundary + shift_ns


def reference_filter_depth(cycle_ns: int) -> int:
    """0x0934 for the reference clock: average Δ over 2^n compares (one per cycle) spanning at
    most a quarter of the loop's time constant — a longer average delays the loop enough to
    make it ring."""
    if cycle_ns <= 0:
        raise ValueError("cycle time must be positive")
    depth = 0
    while depth < MAX_FILTER_DEPTH and (2 << depth) * cycle_ns <= REFERENCE_LOOP_TAU_NS // 4:
        depth += 1
    return depth


def assign_activate_bytes(assign_activate: int) -> tuple[int, int]:
    """(0x0980 cyclic unit control, 0x0981 activation) from an ESI AssignActivate word.

    E.g. 0x0300 → SYNC0 with cyclic operation; 0x0700 adds SYNC1."""
    return assign_activate & 0xFF, (assign_activate >> 8) & 0xFF


def decode_time_diff(raw: int) -> int:
    """0x092C as ``local − received`` in ns: bits 0..30 are the magnitude of the (filtered)
    difference, bit 31 is set when the slave's local copy of the system time is *smaller* than
    the received time (the slave is behind), which makes the value negative."""
    return dc_time_difference(raw)


@dataclass
class DcSlave:
    """A DC-capable slave as the DC setup sees it."""

    position: int
    station: int
    name: str
    assign_activate: int = 0  # 0: no SYNC0 for this slave (DC used as a time base only)
    # SYNC0 period when the slave's group runs slower than the bus cycle (0: the bus cycle).
    sync0_cycle_ns: int = 0
    delay_ns: int = 0
    offset: int = 0


@dataclass
class DcResult:
    reference: DcSlave
    slaves: list[DcSlave]
    start_time: int | None = None
    time_diffs: list[int] = field(default_factory=list)


class DistributedClocks:
    """Runs the DC setup over the datagram service (INIT or PREOP, before SAFEOP)."""

    def __init__(
        self,
        dg: DatagramService,
        master_time: Callable[[], int],
        drift_frames: int = 3000,
        drift_per_frame: int = 16,
        start_margin_ns: int = 100_000_000,
    ) -> None:
        self.dg = dg
        self.master_time = master_time  # master's system time now, ns since 2000
        self.drift_frames = drift_frames
        self.drift_per_frame = drift_per_frame
        self.start_margin_ns = start_margin_ns
        # (station, 0x0930, 0x0934) given to the reference, to give again after a reset.
        self._reference_loop: tuple[int, int, int] | None = None

    def measure(self, slaves: Sequence[DcSlave], tree: Sequence[Link]) -> None:
        """Latch receive times and set delays and offsets on every DC slave (first = reference);
        ``tree`` is where every slave of the bus hangs (by position)."""
        # The latch happens while the frame passes the reference: take the middle of the
        # broadcast's round trip as the master's time at that moment.
        before = self.master_time()
        wkc = self.dg.bwr(reg.DC_RECEIVE_TIME_PORT0, u32(0))
        send_time = (before + self.master_time()) // 2
        if wkc < len(slaves):
            raise BusError(f"DC: only {wkc} slaves latched receive times, expected {len(slaves)}")
        ports = self.dg.batch(
            [
                Datagram(Cmd.FPRD, fixed_address(s.station, reg.DC_RECEIVE_TIME_PORT0), 16)
                for s in slaves
            ]
        )
        locals_ = self.dg.batch(
            [
                Datagram(Cmd.FPRD, fixed_address(s.station, reg.DC_RECEIVE_TIME_PU), 8)
                for s in slaves
            ]
        )
        for s, r1, r2 in zip(slaves, ports, locals_, strict=True):
            if r1.wkc != 1 or r2.wkc != 1:
                raise BusError(f"slave {s.position} ({s.name}): no answer reading DC receive times")
        times = {
            s.position: struct.unpack("<4I", r.data) for s, r in zip(slaves, ports, strict=True)
        }
        by_position = tree_delays(tree, times)
        delays = [by_position[s.position] for s in slaves]
        local_times = [struct.unpack_from("<Q", r.data)[0] for r in locals_]
        offsets = system_time_offsets(send_time, local_times, delays)
        writes: list[Datagram] = []
        for s, d, o in zip(slaves, delays, offsets, strict=True):
            s.delay_ns, s.offset = d, o
            writes.append(
                Datagram(Cmd.FPWR, fixed_address(s.station, reg.DC_SYSTEM_TIME_OFFSET), u64(o))
            )
            writes.append(
                Datagram(Cmd.FPWR, fixed_address(s.station, reg.DC_SYSTEM_TIME_DELAY), u32(d))
            )
        for s, r in zip([s for s in slaves for _ in (0, 1)], self.dg.batch(writes), strict=True):
            if r.wkc != 1:
                raise BusError(f"slave {s.position} ({s.name}): writing DC offset/delay failed")
        log.info("DC delays (ns): %s", {s.name: s.delay_ns for s in slaves})

    def compensate_drift(self, reference: DcSlave) -> None:
        """Static drift compensation: the reference's time, many times, to all other slaves.

        The master's own time is not written to the reference here, in either mode: from
        Python it would be stale by the time the frame passes (tens of µs, varying), and every
        such write makes the reference's control loop chase that error. In
        ``ref_follows_master`` the engine writes it from the real-time thread every cycle,
        stamped with the planned send instant."""
        address = fixed_address(reference.station, reg.DC_SYSTEM_TIME)
        remaining = self.drift_frames
        while remaining > 0:
            n = min(self.drift_per_frame, remaining)
            self.dg.batch([Datagram(Cmd.FRMW, address, 8) for _ in range(n)])
            remaining -= n

    def read_time_diffs(self, slaves: Sequence[DcSlave]) -> list[int]:
        replies = self.dg.batch(
            [
                Datagram(Cmd.FPRD, fixed_address(s.station, reg.DC_SYSTEM_TIME_DIFF), 4)
                for s in slaves
            ]
        )
        return [decode_time_diff(struct.unpack_from("<I", r.data)[0]) for r in replies]

    def configure_reference_loop(self, reference: DcSlave, cycle_ns: int) -> None:
        """Set the reference clock's loop for following the master's time (a lower bandwidth,
        0x0930, and a deeper Δ average, 0x0934, for ``cycle_ns`` compares). Harmless when the
        master follows the reference instead: nothing then writes the reference's 0x0910."""
        depth = reference_filter_depth(cycle_ns)
        who = f"slave {reference.position} ({reference.name})"
        self.dg.write_checked(
            reference.station, reg.DC_FILTER_DEPTH, bytes([depth]), "DC filter depth", who
        )
        # Written last: a write to the speed counter start restarts the loop.
        self.dg.write_checked(
            reference.station,
            reg.DC_SPEED_COUNTER_START,
            u16(REFERENCE_SPEED_COUNTER_START),
            "DC speed counter start",
            who,
        )
        self._reference_loop = (reference.station, REFERENCE_SPEED_COUNTER_START, depth)

    def activate_sync0(
        self,
        slaves: Sequence[DcSlave],
        cycle_ns: int,
        shift_ns: int,
        reference: DcSlave | None = None,
    ) -> int:
        """Set the reference clock's loop for the cycle (``configure_reference_loop``), then
        program SYNC0 on the slaves that use it; returns the start time (system time), 0 when
        none uses SYNC0. ``reference`` (default: the first slave) tells the time."""
        clock = reference or slaves[0]
        self.configure_reference_loop(clock, cycle_ns)
        users = [s for s in slaves if s.assign_activate]
        if not users:
            return 0
        data, wkc = self.dg.fprd(clock.station, reg.DC_SYSTEM_TIME, 8)
        if wkc != 1:
            raise BusError(f"slave {clock.position} ({clock.name}): no DC system time")
        now = struct.unpack("<Q", data)[0]
        start = sync0_start_time(now, cycle_ns, shift_ns, self.start_margin_ns)
        for s in users:
            unit, activation = assign_activate_bytes(s.assign_activate)
            who = f"slave {s.position} ({s.name})"
            self.dg.write_checked(s.station, reg.DC_ACTIVATION, b"\0", "DC activation", who)
            period = s.sync0_cycle_ns or cycle_ns
            self.dg.write_checked(s.station, reg.DC_SYNC0_CYCLE, u32(period), "SYNC0 cycle", who)
            self.dg.write_checked(s.station, reg.DC_SYNC1_CYCLE, u32(0), "SYNC1 cycle", who)
            self.dg.write_checked(s.station, reg.DC_START_TIME, u64(start), "SYNC0 start time", who)
            self.dg.write_checked(
                s.station,
                reg.DC_CYCLIC_UNIT_CONTROL,
                u16(unit | (activation << 8)),
                "AssignActivate",
                who,
            )
        return start

    def deactivate(self, slaves: Sequence[DcSlave]) -> None:
        self.dg.batch(
            [Datagram(Cmd.FPWR, fixed_address(s.station, reg.DC_ACTIVATION), b"\0") for s in slaves]
        )

    def resync_slave(self, source: DcSlave | None, slave: DcSlave) -> None:
        """Give one slave (back after a reset) the running system time again.

        One broadcast latches every slave's local receive time; the frame passed ``source`` (a
        DC slave that kept running) ``source.delay_ns`` after the reference and ``slave``
        ``slave.delay_ns`` after it, so the slave's offset is ``source``'s system time at its
        latch + the delay difference − the slave's local latch. Without a running source (the
        reference alone was reset) the master's time is the source, as at start-up. The
        propagation delay is the one measured at start-up (the cabling did not change)."""
        send_time = self.master_time()
        self.dg.bwr(reg.DC_RECEIVE_TIME_PORT0, u32(0))
        requests = [Datagram(Cmd.FPRD, fixed_address(slave.station, reg.DC_RECEIVE_TIME_PU), 8)]
        if source is not None:
            requests += [
                Datagram(Cmd.FPRD, fixed_address(source.station, reg.DC_RECEIVE_TIME_PU), 8),
                Datagram(Cmd.FPRD, fixed_address(source.station, reg.DC_SYSTEM_TIME_OFFSET), 8),
            ]
        replies = self.dg.batch(requests)
        if any(r.wkc != 1 for r in replies):
            raise BusError(f"slave {slave.position} ({slave.name}): DC re-sync got no answer")
        values = [struct.unpack("<Q", r.data)[0] for r in replies]
        local = values[0]
        if source is not None:
            source_time = (values[1] + values[2] - source.delay_ns) & MASK64
        else:
            source_time = send_time
        slave.offset = (source_time + slave.delay_ns - local) & MASK64
        who = f"slave {slave.position} ({slave.name})"
        offset, delay = u64(slave.offset), u32(slave.delay_ns)
        self.dg.write_checked(slave.station, reg.DC_SYSTEM_TIME_OFFSET, offset, "DC offset", who)
        self.dg.write_checked(slave.station, reg.DC_SYSTEM_TIME_DELAY, delay, "DC delay", who)
        if self._reference_loop is not None and self._reference_loop[0] == slave.station:
            # The reference lost its loop settings with the reset.
            _, speed, depth = self._reference_loop
            self.dg.write_checked(
                slave.station, reg.DC_FILTER_DEPTH, bytes([depth]), "DC filter", who
            )
            self.dg.write_checked(
                slave.station, reg.DC_SPEED_COUNTER_START, u16(speed), "DC speed", who
            )
