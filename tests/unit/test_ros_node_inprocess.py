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

from ether_ros.config import load_bus_config
from ether_ros.ros.client import EtherRosClient
from ether_ros.ros.node import EtherRosNode
from ether_ros.ros.rig import domain_for
from ether_ros.sim.network import build_network

pytestmark = [pytest.mark.ros]

CONFIG = Path(__file__).resolve().parents[2] / "config" / "laelaps.yaml"


@contextlib.contextmanager
def running_node(
    domain_offset: int, config: Path = CONFIG, **options: Any
) -> Iterator[tuple[EtherRosNode, EtherRosClient, object]]:
    """The node on the in-process simulator, spun by an executor thread, and a client; all in a
    ROS context of their own."""
    context = Context()
    rclpy.init(context=context, domain_id=domain_for(os.getpid(), domain_offset))
    net = build_network(load_bus_config(config))
    node = EtherRosNode(config, link=net, context=context, **options)
    executor = MultiThreadedExecutor(num_threads=4, context=context)
    executor.add_node(node)
    thread = threading.Thread(target=executor.spin, daemon=True)
    thread.start()
    client = EtherRosClient(context=context)
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
    assert client.command("clear_panic")[0]
    echo(client, 8000.0)
    assert net.slave_info(0)["al_state_name"] == "OP"  # type: ignore[attr-defined]
    assert client.command("stop")[0] and node.lifecycle_state() == "inactive"
    assert net.slave_info(0)["al_state_name"] != "OP"  # type: ignore[attr-defined]


def test_pdo_listener_served_by_python_when_asked() -> None:
    """``native_commands=False`` (``ether-ros run --python-commands``): the Python executor
    serves pdo_listener; writes still reach the slave and invalid ones are refused."""
    with running_node(7, native_commands=False) as (node, client, _net):
        assert client.command("start")[0]
        assert node.command_path_counters() == {}
        result = client.wait_result(client.publish_write("hind_right_leg", "Kp100_knee", 6000))
        assert result.success and result.message == "wrote hind_right_leg.Kp100_knee=6000"
        echo(client, 6000.0)
        result = client.wait_result(client.publish_write("hind_right_leg", "Kp100_knee", 1e6))
        assert not result.success and "outside" in result.message
