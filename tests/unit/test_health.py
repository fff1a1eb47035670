"""Faults and health that tell the truth (issue 19, item 5), on the real simulator in process:

- ``link up`` undoes every link fault, the cuts inside the bus (``link --at 2 down``) too;
- ``Bus.read`` raises (``StaleInputs``) instead of returning the last inputs once the bus is
  down, and reads again once it is back;
- the diagnostics' levels come from rates over a window and the current state, not from
  totals since start: ERROR while slaves are cut off or the inputs are stale, WARN for a loss
  rate, OK again once the window has passed; the totals stay reported.
"""

from __future__ import annotations

import struct
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest

from ether_ros._native import Link
from ether_ros.config import load_bus_config
from ether_ros.master import Bus
from ether_ros.master.bus import StaleInputs
from ether_ros.master.groups import GroupStats
from ether_ros.ros import diagnostics
from ether_ros.sim.network import build_network
from ether_ros.testing.wait import wait_for

REPO = Path(__file__).resolve().parents[2]
BRD = 0x07


def brd_wkc(net: Any) -> int:
    """How many slaves a broadcast read reaches (its working counter)."""
    dgram = struct.pack("<BBHHHH", BRD, 0x11, 0, 0x0130, 2, 0) + b"\0\0" + b"\0\0"
    body = struct.pack("<H", len(dgram) | 0x1000) + dgram
    frame = (b"\xff" * 6 + b"\x02\0\0\0\0\x01" + b"\x88\xa4" + body).ljust(60, b"\0")
    reply = net.process_frame(frame)
    return 0 if reply is None else struct.unpack_from("<H", reply, 26 + 2)[0]


def test_link_up_undoes_every_link_fault() -> None:
    net = build_network(load_bus_config(REPO / "config" / "laelaps.yaml"))
    assert brd_wkc(net) == 4
    net.inject(Link(up=False, at=2))  # the cable between slaves 1 and 2
    assert brd_wkc(net) == 2
    net.inject(Link(up=True))  # plug every cable back
    assert brd_wkc(net) == 4
    net.inject(Link(up=False, at=3))
    net.inject(Link(up=False))  # the master's own cable as well
    assert brd_wkc(net) == 0
    net.inject(Link(up=True))
    assert brd_wkc(net) == 4
    # `--at` alone mends only that cable.
    net.inject(Link(up=False, at=1))
    net.inject(Link(up=False, at=3))
    net.inject(Link(up=True, at=3))
    assert brd_wkc(net) == 1


def test_the_sim_fault_command_mends_a_cut_inside_the_bus(tmp_path: Path) -> None:
    """The report of issue 19: ``sim-fault link --at 2 down`` then ``sim-fault link up`` exited 0
    and left slaves 2 and 3 cut off. Here through the command line and the simulator's control
    socket, as an operator runs them."""
    from ether_ros.cli.main import main
    from ether_ros.sim.control import ControlServer
    from ether_ros.sim.network import handle_request, slave_names

    cfg = load_bus_config(REPO / "config" / "laelaps.yaml")
    net = build_network(cfg)
    path = tmp_path / "sim.sock"
    server = ControlServer(path, slave_names(cfg), lambda op, k, a: handle_request(net, op, k, a))
    server.start()
    try:
        fault = ["sim-fault", "--control", str(path), "link"]
        assert main([*fault, "down", "--at", "2"]) == 0
        assert brd_wkc(net) == 2
        assert main([*fault, "up"]) == 0
        assert brd_wkc(net) == 4
    finally:
        server.close()


def _config() -> Any:
    cfg = load_bus_config(REPO / "config" / "laelaps.yaml")
    cfg.bus.cycle_us = 2000
    cfg.bus.realtime.policy = "other"
    cfg.bus.realtime.cpu = None
    cfg.bus.realtime.lock_memory = False
    cfg.bus.watchdog_ms = 0
    return cfg


@pytest.fixture
def bus_and_net() -> Iterator[tuple[Bus, Any]]:
    cfg = _config()
    net = build_network(cfg)
    with Bus.open(cfg, link=net) as bus:
        yield bus, net


def _stale(bus: Bus, slave: str) -> bool:
    try:
        bus.read(slave, "hip_angle")
    except StaleInputs:
        return True
    return False


def test_read_refuses_stale_inputs_while_the_bus_is_down(bus_and_net: tuple[Bus, Any]) -> None:
    bus, net = bus_and_net
    with pytest.raises(StaleInputs, match="bus is not running"):
        bus.read("hind_right_leg", "hip_angle")
    bus.start()
    wait_for("fresh inputs", lambda: bus.inputs_fresh("hind_right_leg"))
    bus.read("hind_right_leg", "hip_angle")
    assert bus.input_age("hind_right_leg") < 1.0
    net.inject(Link(up=False))
    wait_for("stale inputs", lambda: _stale(bus, "front_left_leg"))
    with pytest.raises(StaleInputs, match="slave 'hind_right_leg': inputs are stale"):
        bus.inputs("hind_right_leg")
    assert isinstance(bus.read("hind_right_leg", "hip_angle", stale_ok=True), int)
    assert not bus.inputs_fresh("hind_right_leg")
    # Outputs are what the master commands: never stale.
    bus.read("hind_right_leg", "Kp100_knee")
    net.inject(Link(up=True))
    wait_for("fresh inputs again", lambda: not _stale(bus, "front_left_leg"))
    bus.stop()


def test_the_master_level_follows_the_window_not_the_totals() -> None:
    window = diagnostics.Window(10.0)
    totals = {k: 0.0 for k in diagnostics.WINDOW_COUNTERS}

    def report(now: float, **more: float) -> Any:
        for k, v in more.items():
            totals[k] += v
        w = window.update(now, totals)
        return diagnostics.master_status("n", "active", dict(totals), {}, False, 0.0, window=w)

    assert report(0.0, cycles=2500, frames_sent=2500).level == diagnostics.OK
    # 50 of the 5000 frames sent since the start of the window lost: 1 % -> WARN.
    st = report(1.0, cycles=2500, frames_sent=2500, lost_frames=50)
    assert st.level == diagnostics.WARN and "1.00% of frames lost" in st.message
    # Quiet seconds: the loss stays in the window for its length, then the level is OK again.
    for t in range(2, 11):
        st = report(float(t), cycles=2500, frames_sent=2500)
        assert st.level == diagnostics.WARN
    st = report(11.5, cycles=2500, frames_sent=2500)
    assert st.level == diagnostics.OK and st.message == "running"
    values = diagnostics.values_of(st)
    assert values["lost_frames"] == "50"  # the total since start is still there
    assert values["window_lost_frames"] == "0"
    # A single lost frame in a window of thousands is counted, not alarmed.
    st = report(12.0, cycles=2500, frames_sent=2500, lost_frames=1)
    assert st.level == diagnostics.OK and "1 frame(s) lost" in st.message
    # Half the frames lost -> ERROR.
    assert report(13.0, cycles=2500, frames_sent=2500, lost_frames=2000).level == diagnostics.ERROR


def test_cut_off_slaves_and_stale_inputs_are_errors_now() -> None:
    ok = diagnostics.master_status("n", "active", {"cycles": 10}, {}, False, 0.0)
    assert ok.level == diagnostics.OK
    cut = "link lost behind slave 'coupler' port 2: slaves junction, io_3 unreachable"
    st = diagnostics.master_status("n", "active", {"cycles": 10}, {}, False, 0.0, [cut])
    assert st.level == diagnostics.ERROR and st.message == cut
    st = diagnostics.master_status(
        "n", "active", {}, {}, False, 0.0, stale=[0], input_age_s=0.25, frame_count=1
    )
    assert st.level == diagnostics.ERROR and st.message.startswith("the bus is down")
    assert diagnostics.values_of(st)["input_age_ms"] == "250.0"
    st = diagnostics.master_status("n", "active", {}, {}, False, 0.0, short_groups=["io"])
    assert st.level == diagnostics.ERROR and "group(s) io" in st.message
    # A group with two slaves cut off: its working counter is short now.
    short = GroupStats("io", 1, 1_000_000, ("a", "b"), (0,), 6, 2, 100, 0, 0, 90)
    windows = diagnostics.Windows(10.0)
    (g,) = diagnostics.group_statuses("n", [short], windows.groups, 0.0)
    assert g.level == diagnostics.ERROR and g.message == "working counter 2, expected 6"
    back = GroupStats("io", 1, 1_000_000, ("a", "b"), (0,), 6, 6, 5000, 0, 0, 90)
    (g,) = diagnostics.group_statuses("n", [back], windows.groups, 20.0)
    assert g.level == diagnostics.OK, g.message  # 90 bad replies long ago: counted, not alarmed
    assert diagnostics.values_of(g)["wkc_errors"] == "90"


def test_a_statistics_reset_restarts_the_window() -> None:
    window = diagnostics.Window(10.0)
    assert window.update(0.0, {"lost_frames": 5})["lost_frames"] == 5
    assert window.update(1.0, {"lost_frames": 7})["lost_frames"] == 7
    assert window.update(2.0, {"lost_frames": 1})["lost_frames"] == 1  # reset: from zero
