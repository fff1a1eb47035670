"""`ether-ros rt` as a user runs it: a real process against this machine and a real veth."""

from __future__ import annotations

import json

import pytest

from ether_ros.testing.netns import VethPair
from user_commands import ether_ros

pytestmark = pytest.mark.netns


def test_check_on_this_host_with_a_veth(veth: VethPair) -> None:
    out = ether_ros("rt", "check", "--interface", veth.master, "--cpu", "1", "--json")
    assert out.returncode in (0, 1), out.stderr
    rows = {c["name"]: c for c in json.loads(out.stdout)["checks"]}
    # A veth has no hardware IRQ and no coalescing: nothing to tune there.
    assert "virtual interface" in rows["NIC IRQ affinity"]["found"]
    assert rows["interrupt coalescing"]["status"] in ("pass", "skip")
    assert rows["capabilities"]["status"] == "pass"  # the tests run as root


def test_setup_dry_run_on_this_host_changes_nothing(veth: VethPair) -> None:
    with open("/proc/sys/kernel/sched_rt_runtime_us") as fh:
        before = fh.read()
    out = ether_ros("rt", "setup", "--cpu", "1", "--interface", veth.master)
    assert out.returncode == 0, out.stderr
    assert "dry run" in out.stdout or "nothing to change" in out.stdout
    with open("/proc/sys/kernel/sched_rt_runtime_us") as fh:
        assert fh.read() == before


def test_unknown_interface_is_a_one_line_error() -> None:
    out = ether_ros("rt", "check", "--interface", "nosuch0")
    assert out.returncode == 2
    assert (
        out.stderr.strip() == "ether-ros rt: error: network interface 'nosuch0' not found "
        "under /sys/class/net"
    )
