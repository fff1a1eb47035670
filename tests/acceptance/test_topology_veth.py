"""A branched bus end to end: the simulator (``ether-ros sim``, its own process and network
namespace) runs config/branched.yaml — a coupler with two branches, one through a 2-port
junction — and the master (``Bus``) talks to it over a veth pair. Nothing is faked.

Checked: ``ether-ros graph`` draws the tree with port numbers; the master rebuilds the tree from
the slaves' DL status, measures the propagation delays per branch (equal to the simulated
links), reaches OP with the clocks locked; a cable pulled behind the coupler's port 2 is located
and reported, and the slaves come back when it is plugged in again; a bus cabled differently
from the configuration is refused with the first difference named. Timing is never asserted
(generous deadlines, loose lock bounds).
"""

from __future__ import annotations

import json
from collections.abc import Iterator
from pathlib import Path

import pytest
from test_master_veth import _config, wait_for

from ether_ros.config import load_bus_config
from ether_ros.errors import BusError
from ether_ros.master import Bus
from ether_ros.sim.proof import SimProcess
from ether_ros.testing.netns import VethPair
from ether_ros.topology import Link
from user_commands import ether_ros

pytestmark = pytest.mark.netns

REPO = Path(__file__).resolve().parents[2]
BRANCHED = REPO / "config" / "branched.yaml"
NAMES = ["coupler", "io_1", "io_2", "junction", "leg", "io_3", "io_4"]
# Where the frame enters each slave, ns after the coupler, from the link delays of
# config/branched.yaml (worked out in tests/unit/test_topology.py).
DELAYS = [0, 450, 1050, 3000, 3700, 4750, 5900]
FOLLOWER_BOUND_NS = 10_000


@pytest.fixture
def sim(veth_ns: VethPair) -> Iterator[SimProcess]:
    with SimProcess(BRANCHED, veth_ns.slave, veth_ns.netns) as s:
        yield s


def _differences(sim: SimProcess) -> list[int]:
    infos = [sim.request({"op": "slave_info", "slave": k}) for k in range(len(NAMES))]
    return [int(i["dc_system_time_difference"]) for i in infos]


def test_branched_bus_reaches_op_with_dc_locked_and_a_pulled_cable_is_located(
    sim: SimProcess, veth_ns: VethPair
) -> None:
    events: list[tuple[str, str]] = []
    with Bus.open(_config(BRANCHED, veth_ns.master), drift_frames=500) as bus:
        assert bus.tree == load_bus_config(BRANCHED).tree()
        assert bus.tree[4] == Link(3, 3)  # the leg on the junction's port 3
        bus.on_event(lambda e: events.append((e.kind, e.message)))
        bus.start()
        delays = {s.name: s.dc.delay_ns for s in bus.slaves if s.dc is not None}
        assert list(delays) == NAMES
        # The ESCs stamp on their 10 ns clock at a phase the frame does not control (0 or
        # 10 ns between two stamps of one instant, as a real ET1100's): a delay computed from
        # differences of those stamps is good to about two steps.
        for name, want in zip(NAMES, DELAYS, strict=True):
            assert abs(delays[name] - want) <= 20, delays
        assert all(s.state == "OP" for s in bus.states())
        wait_for(
            "DC lock",
            lambda: all(abs(d) < FOLLOWER_BOUND_NS for d in _differences(sim)[1:]),
            timeout=20.0,
        )

        # Pull the cable on port 2 of the coupler: the junction's whole branch goes silent.
        sim.fault("link", up=False, at="coupler", port=2)
        message = (
            "link lost behind slave 'coupler' port 2: slaves junction, leg, io_3, io_4 unreachable"
        )
        wait_for("the cut located", lambda: ("branch_lost", message) in events)
        assert bus.supervisor is not None and bus.supervisor.branch_problems() == [message]
        # The slaves behind the cut carry the report; the other branch is untouched.
        wait_for("io_4 marked", lambda: bus.states()[6].problem == message)
        states = {s.name: s for s in bus.states()}
        assert states["io_2"].state == "OP" and not states["io_2"].problem
        assert states["junction"].problem == message
        # Plugged in again: the branch answers, its slaves are back in OP.
        sim.fault("link", up=True, at="coupler", port=2)
        wait_for("branch restored", lambda: any(k == "branch_restored" for k, _ in events))
        wait_for("all in OP", lambda: all(s.state == "OP" for s in bus.states()))


def test_a_bus_cabled_differently_is_refused_naming_the_first_difference(
    veth_ns: VethPair, tmp_path: Path
) -> None:
    # The bus: io_4 hangs on io_3's port 1 instead of the junction's port 2.
    text = BRANCHED.read_text().replace("[../devices]", f"[{REPO / 'devices'}]")
    recabled = tmp_path / "recabled.yaml"
    recabled.write_text(
        text.replace(
            "connected_to: {slave: junction, port: 2}", "connected_to: {slave: io_3, port: 1}"
        )
    )
    with SimProcess(recabled, veth_ns.slave, veth_ns.netns), pytest.raises(BusError) as err:
        Bus.open(_config(BRANCHED, veth_ns.master))
    assert str(err.value) == (
        "the bus differs from the configuration: slave 6: config expects 'io_4' on port 2 of"
        " 'junction', the bus has it on port 1 of 'io_3'"
    )


def test_graph_draws_the_tree_with_ports(sim: SimProcess, veth_ns: VethPair) -> None:
    out = ether_ros("graph", "-i", veth_ns.master, "-c", str(BRANCHED))
    assert out.returncode == 0, out.stderr
    edges = [line.strip() for line in out.stdout.splitlines() if "->" in line]
    assert edges == [
        "master -> slave0;",
        'slave0 -> slave1 [label="port 1"];',
        'slave1 -> slave2 [label="port 1"];',
        'slave0 -> slave3 [label="port 2"];',
        'slave3 -> slave4 [label="port 3"];',
        'slave3 -> slave5 [label="port 1"];',
        'slave3 -> slave6 [label="port 2"];',
    ]
    assert 'slave3 [label="3: junction' in out.stdout
    nodes = ether_ros("graph", "-i", veth_ns.master, "--json")
    assert nodes.returncode == 0, nodes.stderr
    tree = json.loads(nodes.stdout)
    assert [n["open_ports"] for n in tree] == [[0, 1, 2], [0, 1], [0], [0, 1, 2, 3], [0], [0], [0]]
