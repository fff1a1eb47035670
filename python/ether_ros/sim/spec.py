"""Slave specs for the simulator: one dict per slave, built from the bus config and the ESI.

The keys are the contract with ``SimNetwork.add_slave`` (documented at the top of
``crates/py/src/sim_bindings.rs``): identity, the SII EEPROM image, the CoE dictionary
(objects and entries with their default values), the firmware model and its parameters, clock
drift and propagation delay, where the slave is connected (``upstream``), DC capability, and
the standard mailbox.
"""

from __future__ import annotations

from typing import Any

from ether_ros._native.protocol import coe
from ether_ros.config.bus import BusConfig, SlaveConfig
from ether_ros.config.esi import EsiDevice, Pdo, PdoEntry
from ether_ros.config.sii import build_sii
from ether_ros.errors import ConfigError

# Serial numbers of simulated slaves when the config gives none: recognisable, and unique
# along the bus (0x5E000000 + position).
SERIAL_BASE = 0x5E00_0000


def mailbox_spec(device: EsiDevice) -> dict[str, int] | None:
    """Standard mailbox placement from the ESI's mailbox SyncManagers (None without mailbox)."""
    out, inp = device.sm("MBoxOut"), device.sm("MBoxIn")
    if device.mailbox is None or out is None or inp is None:
        return None
    return {
        "rx_offset": out.start,
        "rx_size": out.default_size,
        "tx_offset": inp.start,
        "tx_size": inp.default_size,
    }


def loopback_pairs(device: EsiDevice) -> list[tuple[int, int, int, int]]:
    """Output → input links of the ``loopback`` model: each output entry (of any RxPDO, in the
    ESI's order, each entry once) with the first input entry not yet taken (of any TxPDO) of
    the same data type and bit length."""
    outputs = _pdo_entries(device.rx_pdos)
    free = _pdo_entries(device.tx_pdos)
    pairs: list[tuple[int, int, int, int]] = []
    for out in outputs:
        for k, inp in enumerate(free):
            if (inp.data_type, inp.bit_length) == (out.data_type, out.bit_length):
                pairs.append((out.index, out.subindex, inp.index, inp.subindex))
                del free[k]
                break
    return pairs


def _pdo_entries(pdos: tuple[Pdo, ...]) -> list[PdoEntry]:
    seen: set[tuple[int, int]] = set()
    out: list[PdoEntry] = []
    for p in pdos:
        for e in p.entries:
            if not e.is_padding and (e.index, e.subindex) not in seen:
                seen.add((e.index, e.subindex))
                out.append(e)
    return out


def _process_entries(device: EsiDevice) -> list[tuple[Any, ...]]:
    """Dictionary entries for PDO entries the ESI's dictionary lacks (a device without CoE has
    no dictionary at all): the simulated slave needs a place to keep their values."""
    rows: list[tuple[Any, ...]] = []
    for e in _pdo_entries((*device.rx_pdos, *device.tx_pdos)):
        if device.od_entry(e.index, e.subindex) is None:
            rows.append((e.index, e.subindex, e.name, e.data_type, e.bit_length, "rw", True, None))
    return rows


def _dictionary(device: EsiDevice) -> tuple[list[tuple[Any, ...]], list[tuple[Any, ...]]]:
    """The CoE objects and entries (with their ESI defaults) a slave running ``device``
    starts with: the same for every slave of that device, so built once per device
    (``_DICTIONARIES``; a thousand-slave bus has three devices)."""
    cached = _DICTIONARIES.get(id(device))
    if cached is not None and cached[0] is device:
        return cached[1], cached[2]
    objects = [(o.index, o.name, o.object_code) for o in device.objects]
    entries = [
        (
            e.index,
            e.subindex,
            e.name,
            e.data_type,
            e.bit_length,
            e.access,
            e.pdo_mappable,
            bytes(e.default),
        )
        for o in device.objects
        for e in o.entries
    ]
    entries += _process_entries(device)
    known = {o[0] for o in objects}
    objects += sorted(
        {(r[0], f"Process data {r[0]:#06x}", 7) for r in entries if r[0] not in known}
    )
    _DICTIONARIES[id(device)] = (device, objects, entries)
    return objects, entries


# id(device) -> (device, objects, entries); the device is kept so its id stays its own.
_DICTIONARIES: dict[int, tuple[EsiDevice, list[tuple[Any, ...]], list[tuple[Any, ...]]]] = {}

# The identity object's serial number (0x1018:4): the ESI can't know it, each slave has its own.
_SERIAL_ENTRY = (coe.IDENTITY, 4)


def device_spec(
    device: EsiDevice,
    *,
    name: str,
    sim_device: str = "none",
    params: dict[str, float] | None = None,
    alias: int = 0,
    serial: int = 0,
    drift_ppm: float = 0.0,
    delay_ns: int = 500,
    esc: str = "et1100",
    lrw: bool = True,
) -> dict[str, Any]:
    """The ``add_slave`` spec of one slave running ``device``."""
    objects, entries = _dictionary(device)
    entries = [
        (*e[:7], _default(e[7], serial, e[4])) if (e[0], e[1]) == _SERIAL_ENTRY else e
        for e in entries
    ]
    return {
        "name": name,
        "vendor_id": device.vendor_id,
        "product_code": device.product_code,
        "revision": device.revision,
        "serial": serial,
        "alias": alias,
        "sii": build_sii(device, alias=alias, serial=serial),
        "objects": list(objects),
        "entries": entries,
        "device": sim_device,
        "params": {k: float(v) for k, v in (params or {}).items()},
        "drift_ppm": float(drift_ppm),
        "delay_ns": int(delay_ns),
        "dc_supported": device.dc_supported,
        "dc_required": device.dc_required,
        "mailbox": mailbox_spec(device),
        "esc": esc,
        "lrw": lrw,
        "loopback_links": loopback_pairs(device) if sim_device == "loopback" else [],
        "safeop_op_timeout_ms": device.timeouts.safeop_op_ms,
    }


def _default(esi_default: bytes, override: int | None, bit_length: int) -> bytes:
    if override is None:
        return bytes(esi_default)
    return override.to_bytes((bit_length + 7) // 8, "little")


def slave_spec(slave: SlaveConfig, position: int) -> dict[str, Any]:
    """The spec of a configured slave at ``position`` on the simulated bus."""
    serial = slave.sim.serial if slave.sim.serial is not None else SERIAL_BASE + position
    return device_spec(
        slave.esi,
        name=slave.name,
        sim_device=slave.sim_device,
        params=slave.sim.params,
        alias=slave.alias or 0,
        serial=serial,
        drift_ppm=slave.sim.drift_ppm,
        delay_ns=slave.sim.delay_ns,
        esc=slave.sim.esc,
        lrw=slave.sim.lrw,
    )


def bus_order(cfg: BusConfig) -> list[SlaveConfig]:
    """The slaves in the order they sit on the wire: by position; slaves addressed by alias
    only keep their place in the list relative to the others."""
    if all(s.position is not None for s in cfg.slaves):
        ordered = sorted(cfg.slaves, key=lambda s: s.position or 0)
        positions = [s.position for s in ordered]
        if positions != list(range(len(ordered))):
            raise ConfigError(
                f"{cfg.source}: the simulator needs slave positions 0..{len(ordered) - 1} without"
                f" gaps, got {positions}"
            )
        return ordered
    return list(cfg.slaves)


def network_specs(cfg: BusConfig) -> list[dict[str, Any]]:
    """Specs for every slave of ``cfg`` in bus order, each connected where ``connected_to``
    says (default: port 1 of the slave before it)."""
    specs = [slave_spec(s, i) for i, s in enumerate(bus_order(cfg))]
    if cfg.declares_topology:
        for spec, link in zip(specs, cfg.tree(), strict=True):
            if link.parent is not None:
                spec["upstream"] = (link.parent, link.port)
    return specs
