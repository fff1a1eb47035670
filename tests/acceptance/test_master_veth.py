"""The master (``Bus``) against the simulator in its own process and network namespace, over a
veth pair: real frames through the kernel, nothing faked.

Covers: 4 legs to OP with DC, process data both ways (the legs move, the I/O box echoes),
a mixed bus, SDO in OP, faults injected through the simulator's control socket (detected,
reported, recovered from), panic and watchdog putting the safe outputs on the wire, and
stop/restart cycles. Timing is never asserted: waits have generous deadlines and only the
outcome is checked.
"""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path

import pytest

from ether_ros.config import BusConfig, load_bus_config
from ether_ros.errors import EtherRosError, MailboxError
from ether_ros.master import Bus, BusEvent
from ether_ros.sim.proof import SimProcess, table_6_1
from ether_ros.testing.netns import VethPair
from ether_ros.testing.wait import wait_for

pytestmark = pytest.mark.netns

REPO = Path(__file__).resolve().parents[2]
LAELAPS = REPO / "config" / "laelaps.yaml"
MIXED = REPO / "config" / "mixed.yaml"
LEGS = ["hind_right_leg", "hind_left_leg", "front_left_leg", "front_right_leg"]
MODE_CONFIGURATIONAL, MODE_OPERATIONAL = 1.0, 2.0
LINKS = ["packet", "xdp"]  # leg firmware "mode" in the probe


def _config(path: Path, interface: str, link: str = "packet", watchdog_ms: int = 0) -> BusConfig:
    cfg = load_bus_config(path, interface=interface, link=link)
    # A shared 2-core VM: a 1 ms cycle, no CPU pinning, no mlockall of the test process.
    cfg.bus.cycle_us = 1000
    cfg.bus.dc.sync0_shift_us = 200
    cfg.bus.realtime.cpu = None
    cfg.bus.realtime.lock_memory = False
    cfg.bus.watchdog_ms = watchdog_ms
    return cfg


class Recorder:
    def __init__(self) -> None:
        self.events: list[BusEvent] = []

    def __call__(self, event: BusEvent) -> None:
        self.events.append(event)

    def kinds(self, slave: str | None = None) -> list[str]:
        return [e.kind for e in self.events if slave is None or e.slave == slave]


@pytest.fixture(params=LINKS)
def link(request: pytest.FixtureRequest) -> str:
    """Every master test runs on both links: AF_PACKET and AF_XDP (native XDP on veth)."""
    return str(request.param)


@pytest.fixture
def sim_laelaps(veth_ns: VethPair) -> Iterator[SimProcess]:
    with SimProcess(LAELAPS, veth_ns.slave, veth_ns.netns) as sim:
        yield sim


@pytest.fixture
def sim_mixed(veth_ns: VethPair) -> Iterator[SimProcess]:
    with SimProcess(MIXED, veth_ns.slave, veth_ns.netns) as sim:
        yield sim


@pytest.fixture
def mixed_bus(
    sim_mixed: SimProcess, veth_ns: VethPair, link: str
) -> Iterator[tuple[Bus, SimProcess]]:
    with Bus.open(_config(MIXED, veth_ns.master, link), drift_frames=500) as bus:
        assert_link(bus, link)
        bus.start()
        yield bus, sim_mixed


def assert_link(bus: Bus, link: str) -> None:
    """The engine really runs on the link the test asked for."""
    assert ("AF_XDP" in bus.engine.link) == (link == "xdp"), bus.engine.link


def _states(bus: Bus) -> list[str]:
    return [s.state for s in bus.states()]


# Both DC modes on AF_PACKET; the link does not change the DC logic, so AF_XDP runs one mode.
@pytest.mark.parametrize(
    ("mode", "link"),
    [
        ("ref_follows_master", "packet"),
        ("master_follows_ref", "packet"),
        ("master_follows_ref", "xdp"),
    ],
)
def test_four_legs_reach_op_with_dc_and_walk(
    sim_laelaps: SimProcess, veth_ns: VethPair, mode: str, link: str
) -> None:
    cfg = _config(LAELAPS, veth_ns.master, link)
    cfg.bus.dc.mode = mode  # type: ignore[assignment]
    with Bus.open(cfg) as bus:
        assert_link(bus, link)
        bus.start()
        assert bus.plan is not None and bus.plan.dc.mode == mode
        assert _states(bus) == ["OP"] * 4
        for pos in range(4):
            info = sim_laelaps.request({"op": "slave_info", "slave": pos})
            assert info["al_state_name"] == "OP" and info["sync0_active"]
            assert info["station_address"] == 0x1001 + pos
        # DC delays grow along the line; every slave got one.
        delays = [s.dc.delay_ns for s in bus.slaves if s.dc is not None]
        assert len(delays) == 4 and delays == sorted(delays) and delays[0] == 0
        # Outputs through the API reach the legs: they start the trot and their desired angles
        # (echoed in the inputs) move along the ellipse.
        for leg in LEGS:
            bus.write_many(leg, table_6_1(leg, transition_s=1))
        seen: set[int] = set()

        def moving() -> bool:
            seen.add(int(bus.read("front_left_leg", "desired_hip_angle")))
            return len(seen) > 20

        wait_for("the leg to follow its trajectory", moving)
        probe = sim_laelaps.request({"op": "probe", "slave": 2})
        assert probe["mode"] == MODE_OPERATIONAL
        if mode == "master_follows_ref":
            # The followers are locked to the (unsteered) reference clock: offsets, delays and
            # drift compensation right, every FRMW finds them within microseconds (a wrong
            # delay or offset would leave hundreds of ns to ms, growing). In the other mode the
            # simulated reference is steered every cycle and its loop is not steady enough for
            # such a bound (see docs/distributed-clocks.md).
            for pos in (1, 2, 3):
                info = sim_laelaps.request({"op": "slave_info", "slave": pos})
                assert abs(info["dc_system_time_difference"]) < 10_000, info
        samples = bus.samples()
        assert len(samples) > 0 and int(samples.records["wkc"].max()) == 12


def test_mixed_bus_io_echo_and_sdo_in_op(mixed_bus: tuple[Bus, SimProcess]) -> None:
    bus, _sim = mixed_bus
    assert _states(bus) == ["OP"] * 5
    assert bus.layout is not None and bus.layout.expected_wkc == 5 * 3
    bus.write_many("io_box", {"DigitalOutput3": True, "AnalogOutput1": 1000})
    wait_for("the digital echo", lambda: bus.read("io_box", "DigitalInput3") is True)
    wait_for("the analog echo", lambda: int(bus.read("io_box", "AnalogInput1")) > 900)
    assert bus.inputs("io_box", stale_ok=True)["DigitalInput1"] is False
    # SDO during OP, interleaved with the cyclic frame by the engine.
    assert bus.sdo_read("front_left_leg", 0x1018, 1) == 0x00000A12
    assert bus.sdo_read("front_left_leg", 0x1018, 2) == 0x00A986FD
    assert bus.sdo_read("front_left_leg", 0x1008, 0) == "LaelapsII_Leg"
    assert bus.sdo_read("io_box", 0x1C13, 1) is not None
    # Downloads in OP reach the slave; its refusals come back as one-line errors naming it.
    with pytest.raises(MailboxError, match=r"'front_left_leg'.*0x06010002.*read-only"):
        bus.sdo_write("front_left_leg", 0x1018, 1, 5)
    with pytest.raises(MailboxError, match=r"'io_box'.*0x08000022"):
        bus.sdo_write("io_box", 0x1C12, 0, 0)  # no PDO re-assignment in OP
    assert bus.sdo_read("io_box", 0x1C12, 0) == 2
    assert _states(bus) == ["OP"] * 5


def test_panic_and_watchdog_put_safe_outputs_on_the_wire(
    sim_mixed: SimProcess, veth_ns: VethPair, link: str
) -> None:
    cfg = _config(MIXED, veth_ns.master, link, watchdog_ms=200)
    with Bus.open(cfg, drift_frames=500) as bus:
        bus.start()
        bus.write_many("front_left_leg", table_6_1("front_left_leg", transition_s=1))
        bus.write("io_box", "DigitalOutput1", True)
        wait_for("the echo", lambda: bus.read("io_box", "DigitalInput1") is True)

        def leg_mode() -> float:
            return float(sim_mixed.request({"op": "probe", "slave": 2})["mode"])

        wait_for("the leg to run", lambda: leg_mode() == MODE_OPERATIONAL)
        bus.panic()
        # Safe outputs: State_Machine 0 (the leg holds its pose), digital outputs 0.
        wait_for("safe leg", lambda: leg_mode() == MODE_CONFIGURATIONAL)
        wait_for("safe I/O", lambda: bus.read("io_box", "DigitalInput1") is False)
        bus.clear_panic()
        bus.write("io_box", "DigitalOutput1", True)
        bus.write_many("front_left_leg", table_6_1("front_left_leg", transition_s=1))
        wait_for("outputs back", lambda: bus.read("io_box", "DigitalInput1") is True)
        wait_for("the leg to run again", lambda: leg_mode() == MODE_OPERATIONAL)
        # Watchdog: nobody writes for longer than watchdog_ms → safe outputs again.
        wait_for("watchdog", lambda: bus.read("io_box", "DigitalInput1") is False)
        assert leg_mode() == MODE_CONFIGURATIONAL
        assert int(bus.stats()["watchdog_trips"]) >= 1


def test_stop_and_restart_many_times(sim_mixed: SimProcess, veth_ns: VethPair, link: str) -> None:
    with Bus.open(_config(MIXED, veth_ns.master, link), drift_frames=200) as bus:
        assert_link(bus, link)
        for _ in range(5):
            bus.start()
            assert _states(bus) == ["OP"] * 5
            bus.write("io_box", "DigitalOutput2", True)
            wait_for("echo", lambda: bus.read("io_box", "DigitalInput2") is True)
            bus.stop()
            assert _states(bus) == ["INIT"] * 5


def test_slave_reset_is_reported_and_recovered(mixed_bus: tuple[Bus, SimProcess]) -> None:
    bus, sim = mixed_bus
    rec = Recorder()
    bus.on_event(rec)
    sim.fault("reset", slave="hind_left_leg")
    wait_for("loss report", lambda: "slave_lost" in rec.kinds("hind_left_leg"))
    wait_for("recovery", lambda: "slave_recovered" in rec.kinds("hind_left_leg"))
    assert _states(bus) == ["OP"] * 5
    assert bus.slave("hind_left_leg").recoveries >= 1
    assert sim.request({"op": "slave_info", "slave": 1})["sync0_active"]


def test_a_recovered_slave_starts_from_its_safe_outputs(mixed_bus: tuple[Bus, SimProcess]) -> None:
    # Resetting a stop does not restart (ISO 13850): a slave that dropped out and is brought
    # back to OP does not resume what was commanded before; the others keep their commands.
    bus, sim = mixed_bus
    rec = Recorder()
    bus.on_event(rec)

    def received(slave: int, key: str) -> float:
        return float(sim.request({"op": "probe", "slave": slave})[key])

    bus.write_many("hind_left_leg", {"Kp100_knee": 1234, "Transition_time": 1})
    bus.write("front_left_leg", "Kp100_knee", 777)
    wait_for("hind_left_leg commanded", lambda: received(1, "cmd_kp_knee") == pytest.approx(12.34))
    wait_for("front_left_leg commanded", lambda: received(2, "cmd_kp_knee") == pytest.approx(7.77))
    sim.fault("reset", slave="hind_left_leg")
    wait_for("recovery", lambda: "slave_recovered" in rec.kinds("hind_left_leg"))
    assert bus.outputs("hind_left_leg")["Kp100_knee"] == 0
    # A new command for it changes what it writes, and only that: once the firmware has it,
    # the gain commanded before the reset is still at its safe value (0).
    bus.write("hind_left_leg", "Transition_time", 2)
    wait_for("the new command", lambda: received(1, "cmd_transition_time_s") == 2.0)
    assert received(1, "cmd_kp_knee") == 0.0
    assert bus.outputs("hind_left_leg")["Kp100_knee"] == 0
    # The other slaves were not touched by the recovery.
    assert received(2, "cmd_kp_knee") == pytest.approx(7.77)
    assert bus.outputs("front_left_leg")["Kp100_knee"] == 777


def test_refused_op_keeps_retrying_until_allowed(mixed_bus: tuple[Bus, SimProcess]) -> None:
    bus, sim = mixed_bus
    rec = Recorder()
    bus.on_event(rec)
    sim.fault("refuse_op", slave="io_box", on=True)
    # Cut the cable in front of the I/O box: it drops out of OP (no answer, then its process
    # data watchdog); once it is reachable again every attempt to bring it to OP is refused.
    sim.fault("link", up=False, at="io_box")
    wait_for("loss report", lambda: "slave_lost" in rec.kinds("io_box"))
    wait_for(
        "the I/O box's watchdog to take it out of OP",
        lambda: sim.request({"op": "slave_info", "slave": 4})["al_state_name"] != "OP",
    )
    sim.fault("link", up=True, at="io_box")

    def refusals() -> list[str]:
        return [e.message for e in rec.events if e.kind == "recovery_failed" and "OP" in e.message]

    wait_for("a refused recovery", lambda: any("refused OP" in m for m in refusals()))
    refusal = next(m for m in refusals() if "refused OP" in m)
    assert refusal.startswith("slave 4 (io_box): recovery failed: ")
    assert "AL status code 0x001A (synchronization error)" in refusal
    assert _states(bus)[:4] == ["OP"] * 4  # the others carry on
    sim.fault("refuse_op", slave="io_box", on=False)
    wait_for("recovery", lambda: "slave_recovered" in rec.kinds("io_box"))
    assert _states(bus) == ["OP"] * 5
    # The refusal came with a CoE emergency carrying the AL status code; it was reported (the
    # worker reads idle mailboxes, so the watchdog's own emergency, 0x001B, is reported too).
    emergencies = [e.message for e in rec.events if e.kind == "emergency"]
    assert all("io_box" in m and "emergency 0xA00" in m for m in emergencies), emergencies
    assert any("1a 00" in m for m in emergencies), emergencies


def test_link_down_and_up(mixed_bus: tuple[Bus, SimProcess]) -> None:
    bus, sim = mixed_bus
    rec = Recorder()
    bus.on_event(rec)
    sim.fault("link", up=False)
    wait_for("link loss", lambda: "link_lost" in rec.kinds())
    sim.fault("link", up=True)
    wait_for("link back", lambda: "link_restored" in rec.kinds())
    wait_for("all in OP", lambda: _states(bus) == ["OP"] * 5, timeout=20)
    bus.write("io_box", "DigitalOutput4", True)
    wait_for("echo after the link came back", lambda: bus.read("io_box", "DigitalInput4"))


def test_drop_corrupt_delay_are_counted_and_survived(mixed_bus: tuple[Bus, SimProcess]) -> None:
    bus, sim = mixed_bus
    before = bus.stats()
    sim.fault("drop", rate=0.2, burst=2)
    wait_for("lost frames", lambda: bus.stats()["lost_frames"] > before["lost_frames"])
    sim.fault("clear")
    sim.fault("corrupt", rate=0.3, bytes=2)
    wait_for(
        "corrupted frames noticed",
        lambda: bus.stats()["wkc_errors"] + bus.stats()["unmatched_frames"]
        + bus.stats()["lost_frames"] > before["wkc_errors"] + before["unmatched_frames"]
        + before["lost_frames"],
    )  # fmt: skip
    sim.fault("clear")
    sim.fault("delay", us=3000)  # longer than the cycle: frames come back late
    wait_for(
        "late frames",
        lambda: bus.stats()["late_frames"] + bus.stats()["lost_frames"]
        > before["late_frames"] + before["lost_frames"],
    )  # fmt: skip
    sim.fault("clear")
    wait_for("all in OP", lambda: _states(bus) == ["OP"] * 5, timeout=20)
    bus.write("io_box", "DigitalOutput5", True)
    wait_for("echo after the faults", lambda: bus.read("io_box", "DigitalInput5"))


def test_drift_step_and_stalled_mailbox(mixed_bus: tuple[Bus, SimProcess]) -> None:
    bus, sim = mixed_bus
    sim.fault("drift_step", slave="front_left_leg", ppm=50.0)
    sim.fault("stall_mailbox", slave="front_left_leg", on=True)
    with pytest.raises(EtherRosError, match="front_left_leg"):
        bus.sdo_read("front_left_leg", 0x1018, 1)
    sim.fault("stall_mailbox", slave="front_left_leg", on=False)
    wait_for("mailbox back", lambda: _sdo_ok(bus, "front_left_leg"))
    assert _states(bus) == ["OP"] * 5


def _sdo_ok(bus: Bus, slave: str) -> bool:
    try:
        return bus.sdo_read(slave, 0x1018, 1) == 0x00000A12
    except EtherRosError:
        return False
