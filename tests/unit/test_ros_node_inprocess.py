"""The node with the simulator in the same process (in-process link, no veth, no second
process): the quickest whole path — lifecycle, layout, a checked write reaching the slave's
firmware and its echo, panic — for development. The acceptance tests do the same over a veth
pair with separate processes."""

from __future__ import annotations

import contextlib
import os
import threading
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest
import rclpy
from rclpy.context import Context
from rclpy.executors import MultiThreadedExecutor

from ether_ros._native import Link
from ether_ros.config import load_bus_config
from ether_ros.ros.client import EtherRosClient
from ether_ros.ros.node import EtherRosNode
from ether_ros.ros.rig import domain_for
from ether_ros.sim.network import build_network
from ether_ros.testing.configs import config_without_lease

# netns: the bus runs with its configuration's realtime section (SCHED_FIFO, locked memory).
pytestmark = [pytest.mark.ros, pytest.mark.netns]

CONFIG = Path(__file__).resolve().parents[2] / "config" / "laelaps.yaml"
BRANCHED = CONFIG.with_name("branched.yaml")


@contextlib.contextmanager
def running_node(
    domain_offset: int,
    config: Path = CONFIG,
    client_options: dict[str, Any] | None = None,
    **options: Any,
) -> Iterator[tuple[EtherRosNode, EtherRosClient, object]]:
    """The node on the in-process simulator, spun by an executor thread, and a client (with
    ``client_options``); all in a ROS context of their own."""
    context = Context()
    rclpy.init(context=context, domain_id=domain_for(os.getpid(), domain_offset))
    net = build_network(load_bus_config(config))
    node = EtherRosNode(config, link=net, context=context, **options)
    executor = MultiThreadedExecutor(num_threads=4, context=context)
    executor.add_node(node)
    thread = threading.Thread(target=executor.spin, daemon=True)
    thread.start()
    client = EtherRosClient(context=context, **(client_options or {}))
    try:
        yield node, client, net
    finally:
        client.close()
        executor.shutdown(timeout_sec=2)
        node.destroy_node()
        context.try_shutdown()
        thread.join(5)


@pytest.fixture(scope="module")
def setup() -> Iterator[tuple[EtherRosNode, EtherRosClient, object]]:
    with running_node(2) as running:
        yield running


def echo(client: EtherRosClient, value: float) -> None:
    client.wait_for(
        lambda latest: latest.outputs.get("hind_right_leg", {}).get("Kp100_knee") == value
    )


def test_start_write_echo_and_panic(setup: tuple[EtherRosNode, EtherRosClient, object]) -> None:
    node, client, net = setup
    assert client.get_state() == "unconfigured"
    assert client.command("start") == (True, "running: slaves in OP")
    assert node.lifecycle_state() == "active"
    assert client.layout().slaves[0].name == "hind_right_leg"
    ok, message = client.write("hind_right_leg", "Kp100_knee", 8000)
    assert ok, message
    echo(client, 8000.0)
    ok, message = client.write("hind_right_leg", "Kp100_knee", 8000.5)
    assert not ok and "not an integer" in message
    assert client.panic()[0]
    echo(client, 0.0)
    ok, message = client.command("clear_panic")
    assert ok and "stay at their safe values" in message, message
    # Clearing does not restart: the outputs stay safe until commanded again.
    echo(client, 0.0)
    assert client.write("hind_right_leg", "Kp100_knee", 8000)[0]
    echo(client, 8000.0)
    assert net.slave_info(0)["al_state_name"] == "OP"  # type: ignore[attr-defined]
    assert client.command("stop")[0] and node.lifecycle_state() == "inactive"
    assert net.slave_info(0)["al_state_name"] != "OP"  # type: ignore[attr-defined]


def test_pdo_listener_served_by_python_when_asked(tmp_path: Path) -> None:
    """``native_commands=False`` (``ether-ros run --python-commands``): the Python executor
    serves pdo_listener; writes still reach the slave and invalid ones are refused. (With the
    lease off: rclpy does not tell who published a message, so with the lease on a topic
    served by Python is refused, see test_python_served_topics_are_refused_under_a_lease.)"""
    config = config_without_lease("laelaps.yaml", tmp_path)
    with running_node(7, config, native_commands=False) as (node, client, _net):
        assert client.command("start")[0]
        assert node.command_path_counters() == {}
        result = client.wait_result(client.publish_write("hind_right_leg", "Kp100_knee", 6000))
        assert result.success and result.message == "wrote hind_right_leg.Kp100_knee=6000"
        echo(client, 6000.0)
        result = client.wait_result(client.publish_write("hind_right_leg", "Kp100_knee", 1e6))
        assert not result.success and "outside" in result.message


def test_python_served_topics_are_refused_under_a_lease() -> None:
    with running_node(8, native_commands=False) as (_node, client, _net):
        assert client.command("start")[0]  # the service carries the lease token
        result = client.wait_result(client.publish_write("hind_right_leg", "Kp100_knee", 6000))
        assert not result.success and "native command path" in result.message


def test_a_cable_pulled_on_a_branch_shows_in_the_diagnostics() -> None:
    """config/branched.yaml: the cable on the coupler's port 2 is pulled; the node's
    diagnostics name where, and the slaves cut off say why they are lost."""
    message = (
        "link lost behind slave 'coupler' port 2: slaves junction, leg, io_3, io_4 unreachable"
    )
    with running_node(9, config=BRANCHED) as (_node, client, net):
        assert client.command("start")[0]
        net.inject(Link(up=False, at=0, port=2))  # type: ignore[attr-defined]

        def reported(latest: Any) -> Any:
            diag = latest.diagnostics
            if diag is None:
                return None
            by_name = {s.name.rsplit(": ", 1)[-1]: s for s in diag.status}
            master, io_4 = by_name.get("master"), by_name.get("slave io_4")
            if master is None or io_4 is None or master.message != message:
                return None
            return io_4

        io_4 = client.wait_for(reported, timeout=15.0)
        assert io_4.message == message
        net.inject(Link(up=True, at=0, port=2))  # type: ignore[attr-defined]
