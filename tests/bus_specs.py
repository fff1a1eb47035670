"""The layout (``BusSpec``) of a shipped bus configuration as the ROS side sees it, built from
the config file alone: for tests of the console and the ROS bridge that need no running bus."""

from __future__ import annotations

from pathlib import Path

from ether_ros.config import load_bus_config
from ether_ros.ros import bridge
from ether_ros.ros.layout import BusSpec

CONFIG_DIR = Path(__file__).resolve().parent.parent / "config"


def spec_of(config: str) -> BusSpec:
    """The layout of ``config/<config>``: its slaves in file order, positions counted from 0."""
    cfg = load_bus_config(CONFIG_DIR / config)
    slaves = tuple(
        bridge.slave_spec(s.name, i, s.esi.type_name, s.layout) for i, s in enumerate(cfg.slaves)
    )
    return BusSpec(cfg.bus.name, cfg.bus.cycle_us, slaves)
