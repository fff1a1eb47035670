"""Simulator front: build a virtual EtherCAT network from a bus config and run it.

``build_network(cfg)`` turns a loaded bus configuration into a ``SimNetwork`` (the Rust virtual
ESCs); ``ether-ros sim CONFIG --interface IFACE`` runs one on a network interface.
"""

from ether_ros.sim.network import build_network

__all__ = ["build_network"]
