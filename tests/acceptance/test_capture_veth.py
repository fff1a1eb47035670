"""A capture on the master's own interface (tcpdump, tshark) sees what the master sends when
asked: with ``bus.capture`` the frames go through the kernel's transmit queue and its taps; by
default (``PACKET_QDISC_BYPASS``) they go straight to the driver and a capture there sees none
of them. Real frames on a veth pair, the simulator in its own process and namespace."""

from __future__ import annotations

import socket
import threading
from pathlib import Path

import pytest

from ether_ros.config import load_bus_config
from ether_ros.master import Bus
from ether_ros.sim.proof import SimProcess
from ether_ros.testing.netns import VethPair
from ether_ros.testing.wait import wait_for

pytestmark = pytest.mark.netns

REPO = Path(__file__).resolve().parents[2]
LAELAPS = REPO / "config" / "laelaps.yaml"
ETH_P_ALL = 0x0003


class Tap:
    """What tcpdump on the interface would see: outgoing EtherCAT frames."""

    def __init__(self, interface: str) -> None:
        self.outgoing = 0
        self.sock = socket.socket(socket.AF_PACKET, socket.SOCK_RAW, socket.htons(ETH_P_ALL))
        self.sock.bind((interface, ETH_P_ALL))
        self.sock.settimeout(0.1)
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, daemon=True)
        self._thread.start()

    def _run(self) -> None:
        while not self._stop.is_set():
            try:
                frame, address = self.sock.recvfrom(2048)
            except TimeoutError:
                continue
            if address[2] == socket.PACKET_OUTGOING and frame[12:14] == b"\x88\xa4":
                self.outgoing += 1

    def close(self) -> None:
        self._stop.set()
        self._thread.join(2)
        self.sock.close()


def captured(interface: str, capture: bool) -> tuple[int, int]:
    """(frames the tap saw, cycles run) for one bring-up and a few hundred cycles."""
    cfg = load_bus_config(LAELAPS, interface=interface)
    cfg.bus.cycle_us = 1000
    cfg.bus.dc.sync0_shift_us = 200
    cfg.bus.realtime.cpu = None
    cfg.bus.realtime.lock_memory = False
    cfg.bus.capture = capture
    tap = Tap(interface)
    try:
        with Bus.open(cfg) as bus:
            bus.start()
            wait_for("cycles", lambda: bus.stats()["cycles"] > 300)
            cycles = int(bus.stats()["cycles"])
            bus.stop()
    finally:
        tap.close()
    return tap.outgoing, cycles


def test_a_capture_sees_the_masters_frames_only_when_asked(veth_ns: VethPair) -> None:
    with SimProcess(LAELAPS, veth_ns.slave, veth_ns.netns):
        seen, cycles = captured(veth_ns.master, capture=True)
        assert seen >= cycles  # every cyclic frame, and the bring-up's
        seen, _ = captured(veth_ns.master, capture=False)
        assert seen == 0
