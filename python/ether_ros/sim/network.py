"""Build a simulated EtherCAT network from a bus config, and answer control requests on it."""

from __future__ import annotations

from typing import Any

from ether_ros.config.bus import BusConfig
from ether_ros.errors import ConfigError
from ether_ros.sim.spec import bus_order, network_specs


def build_network(cfg: BusConfig, seed: int = 1) -> Any:
    """A ``SimNetwork`` with one virtual slave per configured slave, in bus order; ``seed``
    seeds the fault-injection random generator (same seed, same faults)."""
    from ether_ros._native import SimNetwork

    net = SimNetwork(seed=seed)
    for spec in network_specs(cfg):
        try:
            net.add_slave(spec)
        except ValueError as exc:  # the simulator cannot emulate this device: say why
            raise ConfigError(f"{cfg.source}: {exc}") from None
    return net


def slave_names(cfg: BusConfig) -> list[str]:
    """Slave names in bus order (index = position on the simulated bus)."""
    return [s.name for s in bus_order(cfg)]


def _plain(value: Any) -> Any:
    """JSON-friendly copy of what the simulator returns (bytes become hex)."""
    if isinstance(value, dict):
        return {str(k): _plain(v) for k, v in value.items()}
    if isinstance(value, list | tuple):
        return [_plain(v) for v in value]
    if isinstance(value, bytes | bytearray):
        return bytes(value).hex()
    return value


def handle_request(net: Any, op: str, kind: str, arg: Any) -> Any:
    """Carry out a validated control request (see :mod:`ether_ros.sim.control`): ``arg`` is
    the fault to inject or the position of the slave a query asks about."""
    if op == "fault":
        net.inject(arg)
        return None
    if op == "stats":
        return _plain(net.stats())
    if op == "slave_info":
        return _plain(net.slave_info(arg))
    if op == "probe":
        return _plain(net.probe(arg))
    raise ValueError(f"unknown op {op!r}")
