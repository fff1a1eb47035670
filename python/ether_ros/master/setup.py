"""The configured bus, compiled once from the YAML configuration and the ESI devices it names:
``BusSetup`` and one ``SlaveSetup`` per configured slave, frozen (IgH's ``ec_slave_config_t``).

Everything the master needs of the configuration is read here, once, with its default — the
rest of the master reads these objects, never the configuration: the identity expected at each
place (vendor, product, revision; position or alias), the ESI device, the PDO selection and
process layout, the slave's group and whether it may take LRW, its safe outputs; the cycle, the
groups' cycles and watchdogs, DC (reference, mode, SYNC0 shift), the real-time thread's plan,
the cycle order, the command watchdog and the CiA 402 axes. What is found on the wire is kept
apart (``found.py``) and matched against this (``bind.py``).
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from types import MappingProxyType
from typing import Any

from ether_ros.config.bus import DEFAULT_GROUP
from ether_ros.config.cia402 import AxisSpec
from ether_ros.config.esi import EsiDevice
from ether_ros.config.process import ProcessLayout
from ether_ros.errors import BusError, ConfigError
from ether_ros.master.pdo import PdoSelection, select_pdos
from ether_ros.master.plan import RtPlan
from ether_ros.master.scan import Expected
from ether_ros.topology import Link

#: Defaults of what the configuration may leave out (the configuration models have their own
#: for what they validate; these cover a configuration object that lacks the attribute).
DEFAULT_CYCLE_ORDER = "send_at_wake"
DEFAULT_DC_MODE = "ref_follows_master"
DEFAULT_DEADLINE_RUNTIME_US = 100
#: How often the acyclic worker polls idle mailboxes while the bus runs (emergencies read
#: within this; ``worker.py``).
DEFAULT_MAILBOX_POLL_S = 0.02


@dataclass(frozen=True)
class SlaveSetup:
    """One configured slave: where it is expected and what it is, and what the master makes
    of it (PDOs, process layout, group)."""

    name: str
    index: int  # in the configuration's list
    config: Any  # the slave's entry of the bus configuration (for the bring-up steps)
    expected: Expected
    device: EsiDevice | None
    selection: PdoSelection
    layout: ProcessLayout | None
    group: str
    group_every: int  # base cycles per cycle of its group
    lrw: bool  # the configuration allows LRW for it (its group's and its own setting)
    safe_outputs: Mapping[str, Any]


@dataclass(frozen=True)
class BusSetup:
    """The configured bus (module doc)."""

    config: Any
    slaves: tuple[SlaveSetup, ...]
    cycle_ns: int
    group_cycles: tuple[tuple[str, int], ...]
    group_watchdog_ns: Mapping[str, int]
    declares_topology: bool
    tree: tuple[Link, ...]
    dc_enabled: bool
    dc_reference: int | None  # the configured reference position (None: the first DC slave)
    dc_mode: str
    sync0_shift_ns: int
    rt: RtPlan
    cycle_order: str
    watchdog_ns: int
    axes: tuple[AxisSpec, ...]
    mailbox_poll_s: float = DEFAULT_MAILBOX_POLL_S

    @classmethod
    def compile(cls, config: Any) -> BusSetup:
        """The setup of ``config`` (a ``BusConfig``, or a path to its YAML)."""
        if isinstance(config, str | Path):
            from ether_ros.config import load_bus_config

            config = load_bus_config(config)
        bus = config.bus
        cycles_of = getattr(config, "group_cycles", None)
        group_cycles = tuple(cycles_of()) if cycles_of is not None else ((DEFAULT_GROUP, 1),)
        every = dict(group_cycles)
        group_of = getattr(config, "group_of", None)
        slaves = []
        for i, cfg in enumerate(config.slaves):
            group = group_of(cfg.name) if group_of is not None else None
            slaves.append(_slave_setup(cfg, i, group, every))
        rt = getattr(bus, "realtime", None)
        rt_plan = RtPlan()
        if rt is not None:
            rt_plan = RtPlan(
                policy=str(rt.policy),
                priority=int(rt.priority),
                cpu=rt.cpu,
                runtime_ns=int(
                    getattr(rt, "deadline_runtime_us", DEFAULT_DEADLINE_RUNTIME_US) * 1000
                ),
                lock_memory=bool(rt.lock_memory),
            )
        dc = getattr(bus, "dc", None)
        declares = bool(getattr(config, "declares_topology", False))
        specs = getattr(config, "axis_specs", None)
        return cls(
            config=config,
            slaves=tuple(slaves),
            cycle_ns=int(bus.cycle_us * 1000),
            group_cycles=group_cycles,
            group_watchdog_ns=MappingProxyType(
                {
                    g.name: int(g.watchdog_ms) * 1_000_000
                    for g in getattr(config, "groups", None) or []
                    if g.watchdog_ms
                }
            ),
            declares_topology=declares,
            tree=tuple(config.tree()) if declares else (),
            dc_enabled=bool(dc is not None and dc.enabled),
            dc_reference=getattr(dc, "reference", None),
            dc_mode=str(getattr(dc, "mode", DEFAULT_DC_MODE)),
            sync0_shift_ns=round(float(getattr(dc, "sync0_shift_us", 0) or 0) * 1000),
            rt=rt_plan,
            cycle_order=str(getattr(bus, "cycle_order", DEFAULT_CYCLE_ORDER)),
            watchdog_ns=int(float(getattr(bus, "watchdog_ms", 0) or 0) * 1_000_000),
            axes=tuple(specs()) if callable(specs) else (),
        )

    def slave(self, name: str) -> SlaveSetup:
        for s in self.slaves:
            if s.name == name:
                return s
        raise BusError(f"no configured slave {name!r}")


def device_of(slave_cfg: Any) -> EsiDevice | None:
    """The ESI device of a configured slave, as resolved by ``load_bus_config``."""
    dev = getattr(slave_cfg, "resolved_esi", None)
    return dev if isinstance(dev, EsiDevice) else None


def expected_of(cfg: Any, index: int) -> Expected:
    """What the configuration says should be found for slave ``cfg``."""
    device = device_of(cfg)
    vendor = cfg.vendor_id if cfg.vendor_id is not None else getattr(device, "vendor_id", None)
    product = cfg.product_code
    if product is None:
        product = getattr(device, "product_code", None)
    if vendor is None or product is None:
        raise ConfigError(f"slaves.{cfg.name}: no vendor_id/product_code and no ESI device")
    return Expected(
        name=cfg.name,
        vendor_id=int(vendor),
        product_code=int(product),
        revision=getattr(cfg, "revision", None),
        position=getattr(cfg, "position", None),
        alias=getattr(cfg, "alias", None),
    )


def _slave_setup(cfg: Any, index: int, group: Any, every: Mapping[str, int]) -> SlaveSetup:
    position = getattr(cfg, "position", None)
    who = f"slave {position if position is not None else index} ({cfg.name})"
    device = device_of(cfg)
    assign = getattr(cfg, "pdo_assign", None)
    rx = list(assign.rx) if assign is not None and assign.rx is not None else None
    tx = list(assign.tx) if assign is not None and assign.tx is not None else None
    selection = select_pdos(who, device, rx, tx)
    layout = None
    if device is not None:
        try:
            layout = ProcessLayout.for_device(device, selection.rx, selection.tx)
        except ConfigError as exc:
            raise BusError(f"{who}: {exc}") from None
    return SlaveSetup(
        name=cfg.name,
        index=index,
        config=cfg,
        expected=expected_of(cfg, index),
        device=device,
        selection=selection,
        layout=layout,
        group=group.name if group is not None else DEFAULT_GROUP,
        group_every=every[group.name] if group is not None else 1,
        lrw=bool(getattr(cfg, "lrw", True)) and (group is None or bool(group.lrw)),
        safe_outputs=MappingProxyType(dict(getattr(cfg, "safe_outputs", None) or {})),
    )
