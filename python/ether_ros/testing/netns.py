"""Veth pairs and network namespaces for tests and benchmarks: ``ether_ros.netns`` (the product
uses them too — the demo, the ROS rig), re-exported here where the tests have always found them."""

from __future__ import annotations

from ether_ros.netns import (
    VethPair,
    can_create_veth,
    netns_command,
    thread_in_netns,
    unique_name,
)

__all__ = ["VethPair", "can_create_veth", "netns_command", "thread_in_netns", "unique_name"]
