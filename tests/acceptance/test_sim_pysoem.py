"""The simulator seen by an independent master: pysoem (SOEM) on one end of a veth pair,
``ether-ros sim`` in its own process and network namespace on the other. Nothing is faked:
real frames go through the kernel between two processes.

What must hold, as on the hardware: SOEM finds the slaves and reads their SII, SDOs work, the
PDO mapping gives 38 output / 22 input bytes per leg, DC + SYNC0 let the legs reach OP, the
working counter is 3 per slave, the legs follow the Table 6.1 trot, and faults show up in
SOEM the way they do on a real bus.
"""

from __future__ import annotations

import math
import struct
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest

from ether_ros.config import BusConfig, load_bus_config
from ether_ros.master.dc import tree_delays
from ether_ros.sim.proof import INIT, OP, SAFEOP, SimProcess, SoemBus, TrackStats, table_6_1
from ether_ros.testing.netns import VethPair
from ether_ros.topology import open_ports, tree_from_ports

pytestmark = pytest.mark.netns

REPO = Path(__file__).resolve().parents[2]
LAELAPS = REPO / "config" / "laelaps.yaml"
GENERIC = REPO / "config" / "generic_io.yaml"
BRANCHED = REPO / "config" / "branched.yaml"
# Where the frame enters each slave of config/branched.yaml, ns after the coupler (from its
# link delays, worked out in tests/unit/test_topology.py).
BRANCHED_DELAYS = [0, 450, 1050, 3000, 3700, 4750, 5900]
LEG_NAMES = ["hind_right_leg", "hind_left_leg", "front_left_leg", "front_right_leg"]
# Generous: a frame held up by a VM hiccup still counts as answered; we test behaviour here.
RECEIVE_TIMEOUT_US = 50_000


def _bus(cfg: BusConfig, veth: VethPair) -> SoemBus:
    return SoemBus(cfg, veth.master, RECEIVE_TIMEOUT_US, netns=veth.master_netns)


@pytest.fixture
def laelaps(veth_apart: VethPair) -> Iterator[tuple[SimProcess, SoemBus]]:
    cfg = load_bus_config(LAELAPS)
    with SimProcess(LAELAPS, veth_apart.slave, veth_apart.netns) as sim:
        bus = _bus(cfg, veth_apart)
        try:
            yield sim, bus
        finally:
            bus.close()


def _to_op(bus: SoemBus, watchdog_ms: float = 2000) -> None:
    assert bus.scan() == len(bus.slaves_cfg)
    bus.configure()
    # A multi-ms VM stall of this Python master must not look like a dead master to the slaves
    # (the 100 ms default would take them out of OP); the watchdog test passes 100.
    bus.set_watchdog(watchdog_ms)
    for i, s in enumerate(bus.slaves_cfg):
        bus.set_outputs(i, table_6_1(s.name, 0, 0, 1) | {"State_Machine": 0})
    assert bus.request_op(), bus.states()


def test_scan_sdo_mapping_dc_and_op(laelaps: tuple[SimProcess, SoemBus]) -> None:
    sim, bus = laelaps
    assert sim.ready_line.endswith("4 slaves on " + sim.interface + " ready")
    assert bus.scan() == 4
    for s in bus.slaves:
        assert (s.name, s.man, s.id, s.rev) == ("LaelapsII_Leg", 0x00000A12, 0x00A986FD, 1)
        assert int.from_bytes(s.sdo_read(0x1018, 1), "little") == 0x00000A12
        assert int.from_bytes(s.sdo_read(0x1018, 2), "little") == 0x00A986FD
        assert s.sdo_read(0x1008, 0).rstrip(b"\0") == b"LaelapsII_Leg"
        assert s.sdo_read(0x1C12, 1) == (0x1600).to_bytes(2, "little")
    serials = [int.from_bytes(s.sdo_read(0x1018, 4), "little") for s in bus.slaves]
    assert len(set(serials)) == 4

    size = bus.configure()
    bus.set_watchdog(2000)  # see _to_op
    assert size == 4 * (38 + 22)
    for s in bus.slaves:
        assert (len(s.output), len(s.input)) == (38, 22)
        assert s.state == SAFEOP
    assert bus.master.expected_wkc == 3 * 4

    assert bus.request_op(), bus.states()
    bus.run(1.5)
    st = bus.stats
    assert st.cycles > 1000
    # Every answered frame carries the full working counter; a frame late beyond the (long)
    # receive timeout would be a lost one, which must stay rare.
    assert st.wkc_seen.get(12, 0) >= st.cycles - st.cycles // 100, st.wkc_seen
    assert all(w in (12, -1, 0) for w in st.wkc_seen), st.wkc_seen
    assert [state for state, _ in bus.states()] == [OP] * 4
    # The SII as SOEM read it: the DC slaves are DC capable.
    info = sim.request({"op": "slave_info", "slave": 0})
    assert isinstance(info, dict)


def test_trot_tracks_table_6_1(laelaps: tuple[SimProcess, SoemBus]) -> None:
    _, bus = laelaps
    problems: list[object] = []
    for _attempt in range(2):
        hip, knee, desired_hip = _trot(bus)
        problems = []
        for i in range(4):
            name = LEG_NAMES[i]
            # The legs move (a 5 cm step swings the hip by several degrees) ...
            if not hip[i].desired_span_deg > 3.0:
                problems.append(("hip span", name, hip[i].desired_span_deg))
            # ... and follow: RMS error well below the swing.
            if not hip[i].rms_deg < 0.2 * hip[i].desired_span_deg:
                problems.append(("hip rms", name, hip[i].rms_deg))
            if not knee[i].rms_deg < 0.2 * max(knee[i].desired_span_deg, 1.0):
                problems.append(("knee rms", name, knee[i].rms_deg))
        # Trot: diagonal legs in phase, the legs of one side in antiphase (Table 6.1 phases).
        hr, hl, fl, fr = (desired_hip[i] for i in range(4))
        phases = [_corr(fl, hr), _corr(fr, hl), _corr(fl, fr), _corr(hl, hr)]
        if not (phases[0] > 0.5 and phases[1] > 0.5 and phases[2] < -0.5 and phases[3] < -0.5):
            problems.append(("trot phases", phases))
        if not problems:
            break
        # Known flakes (docs/simulator.md, "Known issues"): now and then one leg's gait runs a
        # fixed fraction of a period behind the others under SOEM's DC set-up, and a simulator
        # process starved for a long stretch on a loaded host tracks worse for a while; a
        # fresh bring-up (scan, DC, OP) must then give Table 6.1's trot and its tracking.
    assert not problems, (problems, bus.stats)
    assert bus.stats.wkc_errors <= bus.stats.cycles // 100


def _trot(
    bus: SoemBus,
) -> tuple[dict[int, TrackStats], dict[int, TrackStats], dict[int, list[float]]]:
    """Bring the legs to OP, command the trot, and sample 2 s of it after the transition."""
    _to_op(bus)
    for i, s in enumerate(bus.slaves_cfg):
        bus.set_outputs(i, table_6_1(s.name, a_cm=5, b_cm=4, transition_s=1))
    # Wait until every leg has left its standing point (the firmware starts the ramp on its
    # next SYNC0 tick after the command), then let the 1 s transition into the trot finish.
    first = [bus.inputs(i)["desired_hip_angle"] for i in range(4)]
    deadline = time.monotonic() + 8.0
    while any(abs(bus.inputs(i)["desired_hip_angle"] - first[i]) < 100 for i in range(4)):
        assert time.monotonic() < deadline, ("a leg never started its trot", bus.states())
        bus.run(0.05)
    hip = {i: TrackStats() for i in range(4)}
    knee = {i: TrackStats() for i in range(4)}
    desired_hip: dict[int, list[float]] = {i: [] for i in range(4)}
    start = time.monotonic() + 1.2  # after the transition into the trot
    errors_before = [bus.stats.wkc_errors]

    def sample(k: int) -> None:
        # Only inputs of a cycle that came back whole: on a loaded host this Python master can
        # miss replies for a while, and stale inputs would repeat one point of the gait.
        fresh = bus.stats.wkc_errors == errors_before[0]
        errors_before[0] = bus.stats.wkc_errors
        if fresh and time.monotonic() >= start and k % 5 == 0:
            for i in range(4):
                v = bus.inputs(i)
                hip[i].add(v["hip_angle"] / 100, v["desired_hip_angle"] / 100)
                knee[i].add(v["knee_angle"] / 100, v["desired_knee_angle"] / 100)
                desired_hip[i].append(v["desired_hip_angle"] / 100)

    bus.run(3.2, sample)
    return hip, knee, desired_hip


def _corr(x: list[float], y: list[float]) -> float:
    n = min(len(x), len(y))
    x, y = x[:n], y[:n]
    mx, my = sum(x) / n, sum(y) / n
    sxy = sum((a - mx) * (b - my) for a, b in zip(x, y, strict=True))
    sxx = sum((a - mx) ** 2 for a in x)
    syy = sum((b - my) ** 2 for b in y)
    return sxy / math.sqrt(sxx * syy) if sxx and syy else 0.0


def test_faults_seen_by_soem(laelaps: tuple[SimProcess, SoemBus]) -> None:
    sim, bus = laelaps
    _to_op(bus)
    bus.run(0.2)
    before, cycles_before = bus.stats.lost, bus.stats.cycles
    sim.fault("drop", rate=0.3, burst=1)
    bus.run(0.5)
    dropped, cycles = bus.stats.lost - before, bus.stats.cycles - cycles_before
    # About 30 % of the frames never come back: SOEM sees no working counter for them.
    assert 0.1 * cycles < dropped < 0.6 * cycles, (dropped, cycles)
    sim.fault("clear")
    bus.run(0.1)
    before, cycles_before = bus.stats.lost, bus.stats.cycles
    bus.run(0.5)
    assert bus.stats.lost - before <= (bus.stats.cycles - cycles_before) // 100

    # Answers later than the master waits for are lost frames to it.
    bus.receive_timeout_us = 1_000
    sim.fault("delay", us=20_000)
    before = bus.stats.lost
    for _ in range(10):
        bus.cycle()
    assert bus.stats.lost - before >= 5
    sim.fault("clear")
    bus.receive_timeout_us = RECEIVE_TIMEOUT_US
    bus.run(0.3)
    assert bus.cycle() == 12

    # A slave that loses power forgets its station address (no answer there any more) and
    # comes back in INIT; the others stay in OP. The working counter drops by its 3.
    sim.fault("reset", slave="hind_left_leg")
    bus.run(0.1)
    assert bus.cycle() == 9
    states = bus.states()
    assert states[1] == (0, 0), states  # nothing answers at its configured address
    assert [s & 0x0F for s, _ in (states[0], states[2], states[3])] == [OP] * 3
    # SOEM's recovery finds it by position and gives it its address back: it is in INIT.
    assert bus.slaves[1].recover() > 0
    states = bus.states()
    assert states[1][0] & 0x0F == INIT, states


def test_refuse_op(laelaps: tuple[SimProcess, SoemBus]) -> None:
    sim, bus = laelaps
    assert bus.scan() == 4
    bus.configure()
    bus.set_watchdog(2000)  # see _to_op
    sim.fault("refuse_op", slave=2)
    assert not bus.request_op(timeout_s=1.0)
    states = bus.states()
    # The refusing slave stays in SAFEOP with the error flag and an AL status code.
    assert states[2][0] & 0x0F == SAFEOP and states[2][0] & 0x10, states
    assert states[2][1] != 0
    assert [s & 0x0F for s, _ in (states[0], states[1], states[3])] == [OP] * 3


def test_generic_io_loopback(veth_apart: VethPair) -> None:
    cfg = load_bus_config(GENERIC)
    with SimProcess(GENERIC, veth_apart.slave, veth_apart.netns) as sim:
        assert sim.ready_line.startswith("ether-ros sim: 2 slaves")
        bus = _bus(cfg, veth_apart)
        try:
            assert bus.scan() == 2
            assert [s.name for s in bus.slaves] == ["GenericIO", "GenericIO"]
            # io_b's config assigns only the digital PDOs: written over CoE in PREOP.
            assert bus.configure() == (5 + 5) + (1 + 1)
            bus.set_watchdog(2000)  # see _to_op
            assert bus.master.expected_wkc == 3 * 2
            assert bus.request_op(), bus.states()
            bus.set_outputs(0, {f"DigitalOutput{i}": i % 2 for i in range(1, 9)}
                            | {"AnalogOutput1": 1000, "AnalogOutput2": -500})  # fmt: skip
            bus.set_outputs(1, {"DigitalOutput3": 1, "DigitalOutput8": 1})
            bus.run(0.5)
            a, b = bus.inputs(0), bus.inputs(1)
            assert [a[f"DigitalInput{i}"] for i in range(1, 9)] == [
                bool(i % 2) for i in range(1, 9)
            ]
            assert abs(a["AnalogInput1"] - 1000) <= 10 and abs(a["AnalogInput2"] + 500) <= 10
            assert [k for k, v in b.items() if v] == ["DigitalInput3", "DigitalInput8"]
        finally:
            bus.close()


def test_sim_command_faults_from_the_command_line_and_clean_exit(veth_apart: VethPair) -> None:
    import json
    import subprocess
    import sys

    sim = SimProcess(GENERIC, veth_apart.slave, veth_apart.netns).start()
    try:
        assert sim.ready_line == f"ether-ros sim: 2 slaves on {veth_apart.slave} ready"
        assert sim.control.exists()
        cli = [sys.executable, "-m", "ether_ros.cli.main", "sim-fault", "-i", veth_apart.slave]
        done = subprocess.run([*cli, "refuse-op", "io_b"], capture_output=True, text=True)
        assert done.returncode == 0, done.stderr
        info = json.loads(subprocess.run([*cli, "slave-info", "io_b"], capture_output=True,
                                         text=True, check=True).stdout)  # fmt: skip
        assert info["refuse_op"] is True and info["name"] == "io_b"
        bad = subprocess.run([*cli, "reset", "io_c"], capture_output=True, text=True)
        assert bad.returncode == 2
        assert bad.stderr.strip() == (
            "ether-ros sim-fault: error: slave: no slave named 'io_c' (slaves: io_a, io_b)"
        )
        stats = json.loads(subprocess.run([*cli, "stats"], capture_output=True, text=True,
                                          check=True).stdout)  # fmt: skip
        assert stats["slaves"] == 2
    finally:
        err = sim.stop()
    assert sim.returncode == 0, err
    assert not sim.control.exists()


def test_link_down_and_stalled_mailbox(laelaps: tuple[SimProcess, SoemBus]) -> None:
    import pysoem

    sim, bus = laelaps
    _to_op(bus, watchdog_ms=100)
    bus.receive_timeout_us = 5_000  # frames that never come back cost this much each
    sim.fault("link", up=False)
    before = bus.stats.lost
    for _ in range(60):  # 300 ms without a frame: longer than the 100 ms watchdog
        bus.cycle()
    assert bus.stats.lost - before == 60  # cable pulled: nothing comes back
    sim.fault("link", up=True)
    # As on hardware: the process-data watchdog took every slave out of OP into SAFEOP with
    # AL status 0x001B (sync manager watchdog); acknowledging it and asking for OP recovers.
    states = bus.states()
    assert [(s & 0x0F, code) for s, code in states] == [(SAFEOP, 0x001B)] * 4, states
    for slave in bus.slaves:
        slave.state = SAFEOP | 0x10
        slave.write_state()
    assert bus.request_op(), bus.states()
    assert bus.cycle() == 12

    # Each slave reported the watchdog with a CoE emergency, which SOEM picks up with the
    # next mailbox exchange.
    emergencies: list[tuple[int, int]] = []
    for i, slave in enumerate(bus.slaves):
        slave.add_emergency_callback(lambda e, i=i: emergencies.append((i, e.error_code)))
    for slave in bus.slaves:
        assert slave.sdo_read(0x1018, 1) == (0x0A12).to_bytes(4, "little")
    assert sorted(i for i, _ in emergencies) == [0, 1, 2, 3], emergencies

    # A slave whose mailbox stalls leaves SOEM's SDO read without an answer.
    sim.fault("stall_mailbox", slave="front_right_leg")
    bus.master.sdo_read_timeout = 200_000
    with pytest.raises((pysoem.SdoError, pysoem.MailboxError, pysoem.WkcError)):
        bus.slaves[3].sdo_read(0x1018, 1)
    assert bus.slaves[2].sdo_read(0x1018, 1) == (0x0A12).to_bytes(4, "little")


def test_mixed_bus_legs_and_generic_io(veth_apart: VethPair) -> None:
    mixed = REPO / "config" / "mixed.yaml"
    cfg = load_bus_config(mixed)
    with SimProcess(mixed, veth_apart.slave, veth_apart.netns):
        bus = _bus(cfg, veth_apart)
        try:
            assert bus.scan() == 5
            assert [s.name for s in bus.slaves] == ["LaelapsII_Leg"] * 4 + ["GenericIO"]
            assert bus.configure() == 4 * (38 + 22) + (5 + 5)
            bus.set_watchdog(2000)  # see _to_op
            assert bus.master.expected_wkc == 3 * 5
            assert bus.request_op(), bus.states()
            bus.set_outputs(4, {"DigitalOutput5": True})
            bus.run(0.3)
            assert bus.cycle() == 15
            assert bus.inputs(4)["DigitalInput5"] is True
        finally:
            bus.close()


def test_branched_bus_delays_agree_with_soem(veth_apart: VethPair) -> None:
    """SOEM scans the branched bus (config/branched.yaml: a coupler, a junction, 7 slaves) and
    its ``config_dc`` writes each slave's propagation delay (0x0928). Our ``tree_delays`` on the
    receive times that same measurement latched, with the tree rebuilt from DL status, must
    agree: two independent implementations of the spec's delay measurement on a tree. Both
    must also equal the simulated links (where the frame enters each slave)."""
    cfg = load_bus_config(BRANCHED)
    with SimProcess(BRANCHED, veth_apart.slave, veth_apart.netns):
        bus = _bus(cfg, veth_apart)
        try:
            assert bus.scan() == 7
            assert [s.id for s in bus.slaves] == [c.product_code for c in cfg.by_position()]
            assert bus.master.config_dc()
            soem = [_register(s, 0x0928, 4) for s in bus.slaves]
            times = {k: struct.unpack("<4I", _raw(s, 0x0900, 16)) for k, s in enumerate(bus.slaves)}
            masks = [open_ports(_register(s, 0x0110, 2)) for s in bus.slaves]
        finally:
            bus.close()
    tree = tree_from_ports(masks)
    assert tree == cfg.tree()
    ours = tree_delays(tree, times)
    print(f"\nbranched bus delays (ns): SOEM {soem}, ether_ros {[ours[k] for k in range(7)]}")
    assert [ours[k] for k in range(7)] == soem, (ours, soem)
    # Within two steps of the ESCs' 10 ns clock (their time stamps have that jitter).
    assert all(abs(d - want) <= 20 for d, want in zip(soem, BRANCHED_DELAYS, strict=True)), soem


def _raw(slave: Any, address: int, size: int) -> bytes:
    return bytes(slave._fprd(address, size))


def _register(slave: Any, address: int, size: int) -> int:
    return int.from_bytes(_raw(slave, address, size), "little")
