"""Buses larger than one frame, LRD + LWR, and slave groups at their own cycles: the master
(``Bus``) against ``ether-ros sim`` in its own process and network namespace over a veth pair.

- three 640 + 640-byte slaves (tests/data/wide_io.xml) and a DC I/O box: at least three cyclic
  frames, OP, data both ways; one of the wide slaves refuses LRW (its simulated ESC reports
  0x0008 bit 9 and ignores LRW) and is served by LWR + LRD;
- two legs at the bus cycle and two I/O boxes in a group at four times the cycle: the
  simulator's per-slave count of frames carrying process data shows the rates, SYNC0 runs at
  each group's cycle; cutting the cable in front of the I/O group loses that group only — the
  legs keep OP and their working counter — and the group comes back when the cable does.

Timing is never asserted: rates are compared as ratios of counts over the same interval.
"""

from __future__ import annotations

import time
from pathlib import Path

import pytest

from ether_ros.config import BusConfig, load_bus_config
from ether_ros.master import Bus, BusEvent
from ether_ros.sim.proof import SimProcess
from ether_ros.testing.netns import VethPair
from ether_ros.testing.wait import wait_for

pytestmark = pytest.mark.netns

REPO = Path(__file__).resolve().parents[2]
WIDE_IO = REPO / "tests" / "data" / "wide_io.xml"

WIDE_BUS = f"""\
bus: {{name: wide, cycle_us: 1000, watchdog_ms: 0,
      dc: {{enabled: true, sync0_shift_us: 200}},
      realtime: {{cpu: null, lock_memory: false}}}}
esi: [{REPO / "devices"}, {WIDE_IO}]
slaves:
  - {{name: wide_0, device: WideIO, sim: {{device: loopback}}}}
  - {{name: wide_1, device: WideIO, sim: {{device: loopback, lrw: false}}}}
  - {{name: wide_2, device: WideIO, sim: {{device: loopback}}}}
  - {{name: io_box, device: GenericIO, sim: {{device: generic_io}}}}
"""

GROUPS_BUS = f"""\
bus: {{name: grouped, cycle_us: 1000, watchdog_ms: 0,
      dc: {{enabled: true, reference: 0, sync0_shift_us: 200}},
      realtime: {{cpu: null, lock_memory: false}}}}
esi: [{REPO / "devices"}]
slaves:
  - {{name: leg_a, device: LaelapsII_Leg, safe_outputs: {{State_Machine: 0}}}}
  - {{name: leg_b, device: LaelapsII_Leg, safe_outputs: {{State_Machine: 0}}}}
  - {{name: io_a, device: GenericIO, sim: {{device: generic_io}}}}
  - {{name: io_b, device: GenericIO, sim: {{device: generic_io}}}}
groups:
  - {{name: io, cycle_us: 4000, slaves: [io_a, io_b]}}
"""


def _write(tmp_path: Path, text: str) -> Path:
    path = tmp_path / "bus.yaml"
    path.write_text(text)
    return path


def _config(path: Path, interface: str) -> BusConfig:
    return load_bus_config(path, interface=interface)


def _frames(bus: Bus) -> list[dict[str, int]]:
    return list(bus.stats()["frames"])


def test_a_bus_of_three_frames_reaches_op_and_serves_an_lrw_refusing_slave(
    veth_ns: VethPair, tmp_path: Path
) -> None:
    path = _write(tmp_path, WIDE_BUS)
    with (
        SimProcess(path, veth_ns.slave, veth_ns.netns),
        Bus.open(_config(path, veth_ns.master)) as bus,
    ):
        bus.start()
        assert [s.state for s in bus.states()] == ["OP"] * 4
        assert bus.layout is not None and bus.plan is not None
        frames = bus.plan.frames
        assert len(frames) >= 3
        # The slave whose ESC refuses LRW: found by its feature register, given LWR + LRD.
        wide_1 = next(s for s in bus.slaves if s.name == "wide_1")
        assert not wide_1.found.lrw_supported
        assert bus.layout.area("wide_1").lrw is False
        kinds = [d.kind for f in frames for d in f.datagrams]
        assert "lwr" in kinds and "lrd" in kinds
        # Data both ways through every frame: each wide slave's outputs come back as its
        # inputs (loopback), the I/O box reports what it was told.
        for k in range(3):
            bus.write_many(f"wide_{k}", {"Out 1": 0x1000 + k, "Out 80": 0xABC0 + k})

        def echoed() -> bool:
            return all(
                bus.read(f"wide_{k}", "In 1") == 0x1000 + k
                and bus.read(f"wide_{k}", "In 80") == 0xABC0 + k
                for k in range(3)
            )

        wait_for("the outputs of every frame to come back as inputs", echoed)
        # Every frame's working counter as planned (LWR/LRD +1 each, LRW +2/+1).
        expected = [f.expected_wkc for f in bus.layout.frames]
        wait_for(
            "every frame's working counter",
            lambda: [f["last_wkc"] for f in _frames(bus)] == expected,
        )
        before = [f["wkc_errors"] for f in _frames(bus)]
        time.sleep(0.3)
        assert [f["wkc_errors"] for f in _frames(bus)] == before
        assert all(f["sent"] > 100 for f in _frames(bus))


def test_groups_run_at_their_own_rate_and_a_lost_group_does_not_disturb_the_other(
    veth_ns: VethPair, tmp_path: Path
) -> None:
    path = _write(tmp_path, GROUPS_BUS)
    with (
        SimProcess(path, veth_ns.slave, veth_ns.netns) as sim,
        Bus.open(_config(path, veth_ns.master)) as bus,
    ):
        events: list[BusEvent] = []
        bus.on_event(events.append)
        bus.start()
        assert [s.state for s in bus.states()] == ["OP"] * 4
        groups = {g.name: g for g in bus.group_stats()}
        assert groups["io"].every == 4 and groups["default"].every == 1
        assert set(groups["io"].slaves) == {"io_a", "io_b"}

        def pd_frames(slave: int) -> int:
            return int(sim.request({"op": "slave_info", "slave": slave})["process_data_frames"])

        # Over the same interval the I/O group's slaves see a quarter of the legs' frames.
        legs0, io0 = pd_frames(0), pd_frames(2)
        time.sleep(1.0)
        legs, io = pd_frames(0) - legs0, pd_frames(2) - io0
        assert legs > 200
        assert 0.2 < io / legs < 0.3, (legs, io)
        # SYNC0 at each group's cycle.
        for slave, cycle in ((0, 1_000_000), (2, 4_000_000)):
            info = sim.request({"op": "slave_info", "slave": slave})
            if info["sync0_active"]:
                assert info["sync0_cycle_ns"] == cycle
        assert sim.request({"op": "slave_info", "slave": 0})["sync0_active"]
        # Cut the cable in front of the I/O group: only that group's frames go wrong.
        sim.request({"op": "fault", "kind": "link", "up": False, "at": 2})
        wait_for(
            "the I/O group's working counter errors",
            lambda: {g.name: g for g in bus.group_stats()}["io"].wkc_errors > 5,
        )
        before = {g.name: g for g in bus.group_stats()}
        time.sleep(0.5)
        now = {g.name: g for g in bus.group_stats()}
        # The legs' frames keep going out and coming back right; the I/O group's do not.
        # (Frames lost to this VM's own stalls are the path's floor, 0.1-0.6 % on a quiet host
        # in docs/benchmarks.md and several % on a loaded one: not a disturbance. A disturbed
        # group loses or errs on every frame.)
        sent = now["default"].sent - before["default"].sent
        assert sent > 100
        assert now["default"].wkc_errors == before["default"].wkc_errors
        assert now["default"].lost - before["default"].lost <= sent // 4
        assert now["default"].wkc_ok and not now["io"].wkc_ok
        states = {s.name: s.state for s in bus.states()}
        assert states["leg_a"] == states["leg_b"] == "OP"
        wkc_events = [e.message for e in events if e.kind == "wkc_error"]
        assert any(m.startswith("group io:") for m in wkc_events)
        assert not any(m.startswith("group default:") for m in wkc_events)
        # The cable back: the group recovers to OP.
        sim.request({"op": "fault", "kind": "clear"})
        wait_for(
            "the I/O group back in OP",
            lambda: [s.state for s in bus.states()] == ["OP"] * 4,
            timeout=30,
        )
        wait_for(
            "the I/O group's working counter",
            lambda: {g.name: g for g in bus.group_stats()}["io"].wkc_ok,
        )


def test_line128_reaches_op_at_1khz_with_the_expected_working_counter(
    veth_ns: VethPair,
) -> None:
    path = REPO / "config" / "line128.yaml"
    cfg = _config(path, veth_ns.master)
    # A shared 2-core VM: no CPU pinning, no mlockall of the test process.
    cfg.bus.realtime.cpu = None
    cfg.bus.realtime.lock_memory = False
    with SimProcess(path, veth_ns.slave, veth_ns.netns), Bus.open(cfg) as bus:
        bus.start()
        assert len(bus.slaves) == 128 and bus.cycle_ns == 1_000_000
        assert {s.state for s in bus.states()} == {"OP"}
        assert bus.layout is not None and len(bus.layout.frames) >= 3
        # 32 legs and 32 drives with outputs and inputs (+3 each), 64 I/O boxes (+3 each).
        assert bus.layout.expected_wkc == 128 * 3
        expected = [f.expected_wkc for f in bus.layout.frames]
        wait_for(
            "every frame's working counter",
            lambda: [f["last_wkc"] for f in _frames(bus)] == expected,
        )
        samples = bus.samples()
        assert int(samples.records["wkc"].max()) == 128 * 3
