"""The AF_XDP link's life on a real interface: what ``auto`` does where XDP is missing, two
masters on one interface, and that nothing stays attached to the interface after the master
process is killed with SIGKILL. The master runs in its own process where it matters; the
kernel's view (``ip -d link show``) is the judge."""

from __future__ import annotations

import logging
import os
import signal
import subprocess
import sys
from collections.abc import Iterator
from pathlib import Path

import pytest

from ether_ros.config import load_bus_config
from ether_ros.errors import LinkError
from ether_ros.master import Bus
from ether_ros.master.link import open_engine
from ether_ros.sim.proof import SimProcess
from ether_ros.testing.netns import VethPair, unique_name
from ether_ros.testing.wait import wait_for

pytestmark = pytest.mark.netns

MIXED = Path(__file__).resolve().parents[2] / "config" / "mixed.yaml"


def xdp_attached(ifname: str) -> bool:
    out = subprocess.run(
        ["ip", "-d", "link", "show", "dev", ifname], capture_output=True, text=True, check=True
    ).stdout
    return "prog/xdp" in out or " xdp " in out


@pytest.fixture
def bridge() -> Iterator[str]:
    """An interface whose driver has no native XDP (a Linux bridge)."""
    name = unique_name("erbr")
    subprocess.run(["ip", "link", "add", name, "type", "bridge"], check=True)
    subprocess.run(["ip", "link", "set", name, "up"], check=True)
    try:
        yield name
    finally:
        subprocess.run(["ip", "link", "del", name], check=False)


def test_xdp_without_driver_support_is_a_clear_error_and_auto_falls_back(
    bridge: str, caplog: pytest.LogCaptureFixture
) -> None:
    with pytest.raises(LinkError, match=rf"'{bridge}'.*no native XDP support"):
        open_engine(bridge, "xdp")
    assert not xdp_attached(bridge)
    with caplog.at_level(logging.WARNING, logger="ether_ros.master.link"):
        engine = open_engine(bridge, "auto")
    try:
        assert "AF_XDP" not in engine.link
        warnings = [r.getMessage() for r in caplog.records if r.levelno == logging.WARNING]
        assert len(warnings) == 1 and "\n" not in warnings[0], warnings
        assert "no native XDP support" in warnings[0] and "using AF_PACKET" in warnings[0]
    finally:
        engine.close()


def test_auto_takes_xdp_where_it_works(veth: VethPair) -> None:
    engine = open_engine(veth.master, "auto", busy_poll_us=20)
    try:
        assert "AF_XDP, copy mode" in engine.link
        assert xdp_attached(veth.master)
    finally:
        engine.close()
    assert not xdp_attached(veth.master)


def test_a_second_master_on_an_xdp_interface_is_refused(veth: VethPair) -> None:
    first = open_engine(veth.master, "xdp")
    try:
        with pytest.raises(LinkError, match=rf"'{veth.master}'.*another master"):
            open_engine(veth.master, "xdp")
        # AF_PACKET does not take the interface: a raw socket next to it is still allowed
        # (the frames would be answered twice; see docs/engine.md, "Links").
        open_engine(veth.master, "packet").close()
    finally:
        first.close()


def test_nothing_stays_attached_after_sigkill(veth: VethPair) -> None:
    code = (
        "import sys\n"
        "from ether_ros.master.link import open_engine\n"
        f"engine = open_engine({veth.master!r}, 'xdp')\n"
        "print(engine.link, flush=True)\n"
        "sys.stdin.read()\n"
    )
    child = subprocess.Popen(
        [sys.executable, "-c", code],
        stdin=subprocess.PIPE,
        stdout=subprocess.PIPE,
        text=True,
    )
    try:
        assert child.stdout is not None
        line = child.stdout.readline()
        assert "AF_XDP" in line, line
        assert xdp_attached(veth.master)
        os.kill(child.pid, signal.SIGKILL)
        child.wait(timeout=10)
    finally:
        if child.poll() is None:
            child.kill()
            child.wait()
    assert not xdp_attached(veth.master), "the XDP program outlived its process"
    # And the queue is free for the next master.
    open_engine(veth.master, "xdp").close()


@pytest.mark.parametrize("master_link", ["packet", "xdp"])
def test_the_simulator_serves_on_xdp(veth_ns: VethPair, master_link: str) -> None:
    """``ether-ros sim --link xdp``: the simulator's end has its own XDP program (in its
    namespace); a master on either link brings the mixed bus to OP and exchanges data."""
    cfg = load_bus_config(MIXED, interface=veth_ns.master, link=master_link)
    cfg.bus.cycle_us = 1000
    cfg.bus.realtime.cpu = None
    cfg.bus.realtime.lock_memory = False
    cfg.bus.watchdog_ms = 0
    with SimProcess(MIXED, veth_ns.slave, veth_ns.netns, link="xdp") as sim:
        attached = subprocess.run(
            ["ip", "-n", str(veth_ns.netns), "-d", "link", "show", "dev", veth_ns.slave],
            capture_output=True, text=True, check=True,
        ).stdout  # fmt: skip
        assert "prog/xdp" in attached
        with Bus.open(cfg, drift_frames=300) as bus:
            bus.start()
            assert [s.state for s in bus.states()] == ["OP"] * 5
            bus.write("io_box", "DigitalOutput2", True)
            wait_for(
                "the echo through the xdp simulator",
                lambda: bus.read("io_box", "DigitalInput2") is True,
                timeout=10,
            )
            assert int(bus.stats()["lost_frames"]) < int(bus.stats()["cycles"])
        stats = sim.request({"op": "stats"})
        assert stats["frames_answered"] > 100 and stats["send_errors"] == 0, stats
