"""One master per interface, and the inspection tools through it.

A running node (``ether-ros run``, in its own process) holds its interface: a second master
(``ether-ros run`` again, or ``Bus.open`` in another process) is refused with a message naming
the running one, and its slaves never leave OP for it. The inspection commands (``slaves``,
``states``, ``upload``, ``reg-read``, ``sii-read``, ``master``) answer beside it through the
running master, without opening the interface; what would change the running bus (a state
change, a register write) is refused. The running bus loses nothing to them: its slaves stay
in OP and its working counter stays right.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
from collections.abc import Iterator
from pathlib import Path

import pytest

from ether_ros.claim import InterfaceBusy, OwnerClient, OwnerError, ask
from ether_ros.master import Bus
from ether_ros.ros.rig import domain_for
from ether_ros.sim.proof import SimProcess
from ether_ros.testing.netns import VethPair
from ether_ros.testing.wait import wait_for

pytestmark = [pytest.mark.netns, pytest.mark.ros]

REPO = Path(__file__).resolve().parents[2]
LAELAPS = REPO / "config" / "laelaps.yaml"


def _cli(*words: str, timeout: float = 120) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        [sys.executable, "-m", "ether_ros.cli.main", *words],
        capture_output=True,
        text=True,
        timeout=timeout,
        check=False,
    )


@pytest.fixture(scope="module")
def running_node(veth_allowed: bool) -> Iterator[tuple[str, subprocess.Popen[str]]]:
    """``ether-ros run`` on the simulated Laelaps bus, in OP; yields (interface, process)."""
    if not veth_allowed:
        pytest.fail("creating a network namespace needs root; run the tests as root")
    env = {**os.environ, "ROS_DOMAIN_ID": str(domain_for(os.getpid(), 37))}
    with VethPair.create(netns=True) as veth, SimProcess(LAELAPS, veth.slave, veth.netns):
        node = subprocess.Popen(
            [sys.executable, "-m", "ether_ros.cli.main", "run", str(LAELAPS), "-i", veth.master],
            stdout=subprocess.PIPE,
            stderr=subprocess.PIPE,
            text=True,
            env=env,
        )
        try:

            def in_op() -> bool:
                if node.poll() is not None:
                    raise AssertionError(f"ether-ros run ended: {node.stderr.read()}")  # type: ignore[union-attr]
                try:
                    states = ask(veth.master, "states")
                except (OSError, OwnerError):
                    return False  # not claimed yet, or claimed and still scanning
                return bool(states) and all(s["state"] == "OP" for s in states)

            wait_for("the node's bus in OP", in_op, timeout=120)
            yield veth.master, node
        finally:
            node.terminate()
            try:
                node.wait(timeout=60)
            except subprocess.TimeoutExpired:
                node.kill()
                node.wait()


def _bus_health(interface: str) -> tuple[list[str], int]:
    """The running bus's AL states and its working-counter error count, asked of it."""
    states = [s["state"] for s in ask(interface, "states")]
    return states, int(ask(interface, "stats")["wkc_errors"])


def test_a_second_master_is_refused_naming_the_running_one(
    running_node: tuple[str, subprocess.Popen[str]],
) -> None:
    interface, node = running_node
    states, wkc_errors = _bus_health(interface)
    second = _cli("run", str(LAELAPS), "-i", interface)
    assert second.returncode != 0
    assert f"another master is already running on {interface}" in second.stderr
    assert f"pid {node.pid}" in second.stderr
    assert "node /ether_comm" in second.stderr
    assert "Traceback" not in second.stderr
    # In this process too, through the Python API, with the owner as data.
    with pytest.raises(InterfaceBusy) as refused:
        Bus.open(LAELAPS, interface=interface)
    assert refused.value.owner["pid"] == node.pid
    assert refused.value.owner["node"] == "/ether_comm"
    # The running bus did not notice.
    assert _bus_health(interface) == (["OP"] * len(states), wkc_errors)


def test_inspection_commands_answer_through_the_running_master(
    running_node: tuple[str, subprocess.Popen[str]],
) -> None:
    interface, node = running_node
    before_states, wkc_errors = _bus_health(interface)
    assert before_states and set(before_states) == {"OP"}
    for _round in range(3):
        slaves = _cli("slaves", "-i", interface, "--json")
        assert slaves.returncode == 0, slaves.stderr
        entries = json.loads(slaves.stdout)
        assert [e["state"] for e in entries] == before_states
        assert entries[0]["configured_name"]  # the running master's names
        upload = _cli("upload", "-i", interface, "-p", "0", "0x1018:01", "--json")
        assert upload.returncode == 0, upload.stderr
        assert json.loads(upload.stdout)["value"] == 0x00000A12  # Laelaps II vendor id
        # AL status register 0x0130: OP (8), read by the running master.
        reg = _cli("reg-read", "-i", interface, "-p", "1", "0x0130", "--type", "uint16", "--json")
        assert reg.returncode == 0, reg.stderr
        assert json.loads(reg.stdout)["value"] & 0x0F == 8
        states = _cli("states", "-i", interface, "--json")
        assert [e["state"] for e in json.loads(states.stdout)] == before_states
    sii = _cli("sii-read", "-i", interface, "-p", "2", "--json")
    assert sii.returncode == 0 and json.loads(sii.stdout)["vendor_id"] == 0x00000A12
    master = _cli("master", "-i", interface, "--json")
    assert master.returncode == 0, master.stderr
    assert json.loads(master.stdout)["master"]["pid"] == node.pid
    # What would change the running bus is refused, saying who runs it.
    for words in (
        ["states", "-i", interface, "INIT"],
        ["reg-write", "-i", interface, "-p", "0", "0x0120", "0x0001"],
    ):
        refused = _cli(*words)
        assert refused.returncode != 0
        assert "driven by a running master" in refused.stderr and str(node.pid) in refused.stderr
    # The running bus lost nothing: every slave in OP, no working-counter error.
    assert _bus_health(interface) == (before_states, wkc_errors)


def test_the_claim_serves_only_known_requests_and_checks_their_arguments(
    running_node: tuple[str, subprocess.Popen[str]],
) -> None:
    interface, _node = running_node
    with OwnerClient(interface) as client:
        for op, args, why in [
            ("format_disk", {}, "unknown request 'format_disk'"),
            ("reg_read", {"position": 0, "address": 0x10000, "length": 2}, "address"),
            ("reg_read", {"position": 99, "address": 0x130, "length": 2}, "no slave at position"),
            ("upload", {"position": "0; rm -rf /", "index": 0x1018, "subindex": 1}, "position"),
        ]:
            with pytest.raises(Exception, match=why):
                client.request(op, **args)
        # The connection survives bad requests.
        assert client.request("who")["pid"] > 0
