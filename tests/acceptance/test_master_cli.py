"""``ether-ros slaves`` and ``ether-ros bench cycle`` as a user runs them: subprocesses against
the simulator in its own network namespace over a veth pair."""

from __future__ import annotations

import json
from collections.abc import Iterator
from pathlib import Path

import pytest
import yaml

from ether_ros.sim.proof import SimProcess
from ether_ros.testing.netns import VethPair
from user_commands import LAELAPS, REPO, ether_ros

pytestmark = pytest.mark.netns

LEGS = ["hind_right_leg", "hind_left_leg", "front_left_leg", "front_right_leg"]


@pytest.fixture
def sim(veth_ns: VethPair) -> Iterator[SimProcess]:
    with SimProcess(LAELAPS, veth_ns.slave, veth_ns.netns) as s:
        yield s


def test_slaves_lists_one_line_per_slave(sim: SimProcess, veth_ns: VethPair) -> None:
    r = ether_ros("slaves", "--interface", veth_ns.master)
    assert r.returncode == 0, r.stderr
    lines = r.stdout.strip().splitlines()
    assert len(lines) == 4
    for pos, line in enumerate(lines):
        fields = line.split()
        assert fields[:5] == [str(pos), f"0x{0x1001 + pos:04X}", "INIT", "0x00000A12", "0x00A986FD"]
        assert "LaelapsII_Leg" in line

    r = ether_ros("slaves", "--interface", veth_ns.master, "--config", str(LAELAPS), "--json")
    assert r.returncode == 0, r.stderr
    entries = json.loads(r.stdout)
    assert [e["configured_name"] for e in entries] == LEGS
    assert all(e["dc"] and e["mailbox"]["rx"][1] > 0 for e in entries)

    r = ether_ros("slaves", "--interface", veth_ns.master, "-v")
    assert r.returncode == 0 and "RxPDOs 0x1600" in r.stdout and "DC yes" in r.stdout


def test_slaves_with_a_wrong_config_is_one_line_error(
    sim: SimProcess, veth_ns: VethPair, tmp_path: Path
) -> None:
    data = yaml.safe_load(LAELAPS.read_text())
    data["esi"] = [str(REPO / "devices")]
    # The configuration expects an I/O box where the bus has a leg.
    data["slaves"][2] = {"name": "front_left_leg", "position": 2, "device": "GenericIO"}
    cfg = tmp_path / "wrong.yaml"
    cfg.write_text(yaml.safe_dump(data))
    r = ether_ros("slaves", "--interface", veth_ns.master, "--config", str(cfg))
    assert r.returncode == 2
    assert r.stderr.count("\n") == 1
    assert "slave 2 (front_left_leg): expected vendor 0x" in r.stderr
    assert "found vendor 0x00000A12 product 0x00A986FD" in r.stderr


def test_bench_cycle_reports_and_writes_json(
    sim: SimProcess, veth_ns: VethPair, tmp_path: Path
) -> None:
    out = tmp_path / "bench.json"
    r = ether_ros(
        "bench", "cycle", str(LAELAPS), "--interface", veth_ns.master,
        "--cycle-us", "1000", "--seconds", "1", "--json", str(out), "--drift-frames", "300",
    )  # fmt: skip
    assert r.returncode == 0, r.stderr
    assert "wake-up latency" in r.stdout and "round trip" in r.stdout
    result = json.loads(out.read_text())
    assert result["cycle_us"] == 1000 and result["cycles"] > 0
    for key in ("lost_frames", "late_frames", "unmatched_frames", "wkc_errors"):
        assert result[key] >= 0
    for key in ("wake_latency_us", "exec_us", "period_us", "rtt_us"):
        assert set(result[key]) == {"p50", "p99", "p999", "max"}
        assert result[key]["max"] >= result[key]["p50"] >= 0


def test_slaves_next_to_a_running_master_shows_op_and_disturbs_nothing(
    sim: SimProcess, veth_ns: VethPair
) -> None:
    from ether_ros.config import load_bus_config
    from ether_ros.master import Bus

    cfg = load_bus_config(LAELAPS, interface=veth_ns.master)
    cfg.bus.cycle_us = 1000
    cfg.bus.realtime.cpu = None
    cfg.bus.realtime.lock_memory = False
    cfg.bus.watchdog_ms = 0
    with Bus.open(cfg, drift_frames=300) as bus:
        bus.start()
        r = ether_ros("slaves", "--interface", veth_ns.master)
        assert r.returncode == 0, r.stderr
        assert [line.split()[2] for line in r.stdout.strip().splitlines()] == ["OP"] * 4
        assert [s.state for s in bus.states()] == ["OP"] * 4
