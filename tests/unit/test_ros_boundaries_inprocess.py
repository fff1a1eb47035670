"""Hostile and clumsy ROS commands against the node (issue 19), with the simulator in the same
process: each is refused with the reason, names the field, and changes nothing.

- raw CDR with a NUL inside a name (``Kp100_knee\\0junk``): rclpy would hand Python the name
  cut at the NUL and apply it; the native decoder refuses it on the native and on the Python
  path;
- ``slave`` together with ``all_slaves``;
- a Laelaps II trajectory outside the leg's workspace, on every path to the outputs: the
  topic (native path), ``write_variables``, the Python API; the answer says what to set first.
"""

from __future__ import annotations

from collections.abc import Iterator
from typing import Any

import pytest
from ether_ros_msgs.msg import WriteVariable
from rclpy.serialization import serialize_message
from test_ros_node_inprocess import CONFIG, running_node

from ether_ros.config.process import ProcessValueError
from ether_ros.ros.client import EtherRosClient, make_write
from ether_ros.ros.node import QOS_COMMANDS, EtherRosNode
from ether_ros.testing.configs import config_without_lease

# netns: the bus runs with its configuration's realtime section (SCHED_FIFO, locked memory).
pytestmark = [pytest.mark.ros, pytest.mark.netns]

LEG = "front_left_leg"


@pytest.fixture(scope="module", params=[True, False], ids=["native", "python"])
def laelaps(
    request: Any, tmp_path_factory: pytest.TempPathFactory
) -> Iterator[tuple[EtherRosNode, EtherRosClient]]:
    """The Laelaps bus, active, with pdo_listener served natively or by Python. Python cannot
    tell a message's publisher, so with its lease on it refuses every topic message
    (docs/security.md): the Python path runs a copy with the lease off."""
    config = (
        CONFIG
        if request.param
        else config_without_lease("laelaps.yaml", tmp_path_factory.mktemp("cfg"))
    )
    with running_node(11 + request.param, config, native_commands=request.param) as (
        node,
        client,
        _n,
    ):
        ok, message = client.command("start")
        assert ok, message
        yield node, client


def with_nul(variable_with_hash: str, slave: str = LEG, request_id: int = 1) -> bytes:
    """A WriteVariable serialized by rclpy with every ``#`` of the variable made a NUL: what a
    client writing CDR itself can send (rclpy cuts Python strings at a NUL)."""
    msg = WriteVariable(slave=slave, variable=variable_with_hash, value=1.0, request_id=request_id)
    data = serialize_message(msg)
    return data.replace(variable_with_hash.encode(), variable_with_hash.replace("#", "\0").encode())


def publish_raw(client: EtherRosClient, data: bytes) -> None:
    publisher = getattr(client, "_raw_writes", None)
    if publisher is None:
        publisher = client.node.create_publisher(WriteVariable, "pdo_listener", QOS_COMMANDS)
        client._raw_writes = publisher  # type: ignore[attr-defined]
        client.wait_for(lambda _l: publisher.get_subscription_count() > 0)
    publisher.publish(data)


def output(node: EtherRosNode, variable: str) -> Any:
    bus = node._bus
    assert bus is not None
    return bus.outputs(LEG)[variable]


def test_a_nul_inside_a_name_is_refused_not_cut(laelaps: tuple[EtherRosNode, Any]) -> None:
    node, client = laelaps
    before = output(node, "Kp100_knee")
    publish_raw(client, with_nul("Kp100_knee#junk", request_id=101))
    result = client.wait_result(101)
    assert not result.success
    assert result.message == "pdo_listener refused: field 'variable' holds a NUL at byte 10"
    publish_raw(client, with_nul("x", slave="front#left_leg", request_id=102).replace(
        b"front#left_leg", b"front\0left_leg"))  # fmt: skip
    result = client.wait_result(102)
    assert not result.success and "field 'slave' holds a NUL at byte 5" in result.message
    assert output(node, "Kp100_knee") == before
    # The same name without the NUL goes through.
    result = client.wait_result(client.publish_write(LEG, "Kp100_knee", before + 7))
    assert result.success, result.message


def test_a_slave_and_all_slaves_together_are_refused(laelaps: tuple[EtherRosNode, Any]) -> None:
    node, client = laelaps
    before = output(node, "Kd1000_knee")
    msg = make_write(LEG, "Kd1000_knee", before + 3)
    msg.all_slaves = True
    msg.request_id = 103
    client._write_pub.publish(msg)
    result = client.wait_result(103)
    assert not result.success
    assert "all_slaves is true and slave 'front_left_leg' is given" in result.message
    msg.slave, msg.position = "", 2
    ok, message = client.write_many([msg])
    assert not ok and "all_slaves is true and position 2 is given" in message
    assert output(node, "Kd1000_knee") == before


def test_the_leg_workspace_is_checked_on_every_path(laelaps: tuple[EtherRosNode, Any]) -> None:
    node, client = laelaps
    if output(node, "y_cntr_traj1000") == 0:
        # A fresh leg: the centre is 0, no ellipse is valid; the answer says what to set.
        ok, message = client.write(LEG, "a_ellipse100", 5)
        assert not ok
        assert message.endswith(
            "a_ellipse100=5 makes an invalid ellipse: y_cntr_traj1000 is 0: set the centre "
            "first, e.g. y_cntr_traj1000=599"
        )
        ok, message = client.write(LEG, "y_cntr_traj1000", 599)
        assert ok, message
    invalid = "a_ellipse100=20 makes an invalid ellipse: toe point (200.0, 599.0) mm"
    # The topic (the native path defers the trajectory record to Python) ...
    result = client.wait_result(client.publish_write(LEG, "a_ellipse100", 20))
    assert not result.success and invalid in result.message
    result = client.wait_result(client.publish_write("all", "a_ellipse100", 20))
    assert not result.success and "a_ellipse100=20 makes an invalid ellipse" in result.message
    # ... the service, all or nothing ...
    ok, message = client.write_many(
        [make_write(LEG, "Kp100_knee", 8001), make_write(LEG, "a_ellipse100", 20)]
    )
    assert not ok and invalid in message and output(node, "Kp100_knee") != 8001
    # ... and the Python API.
    bus = node._bus
    assert bus is not None
    with pytest.raises(ProcessValueError, match=r"toe point \(200\.0, 599\.0\) mm"):
        bus.write(LEG, "a_ellipse100", 20)
    assert output(node, "a_ellipse100") == 0
    ok, message = client.write(LEG, "a_ellipse100", 5)
    assert ok, message
    assert output(node, "a_ellipse100") == 5
