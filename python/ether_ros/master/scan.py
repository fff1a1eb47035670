"""Finding the slaves: count, reset, address, identify, and check against the configuration.

Order of work (all in INIT):
1. BRD 0x0000: the working counter is the number of slaves on the line.
2. Broadcast reset: every slave back to INIT with its error acknowledged, FMMUs, SyncManagers
   and DC SYNC outputs cleared, ports on automatic loop control, EEPROM owned by EtherCAT.
3. APWR 0x0010: station addresses 0x1001, 0x1002, ... by position, so later datagrams can
   address a slave by a name that no longer depends on the datagram's path.
4. Aliases (0x0012), ESC features (0x0008, DC support), DL status (0x0110: which ports have
   an open link), SII images.
5. The tree: which slave hangs on which port of which other slave, rebuilt from the open ports
   in auto-increment order (``bus_tree``; the frame visits slaves depth first in port order).
6. Checks against the configuration: the tree, when the configuration describes one
   (``connected_to``), naming the first position where bus and configuration differ; then the
   identities: vendor, product (and revision if configured), missing and extra slaves — each
   error names the slave by position and configured name.
"""

from __future__ import annotations

import struct
from collections.abc import Sequence
from dataclasses import dataclass

from ether_ros._native.protocol import al, reg
from ether_ros.config.sii import parse_sii
from ether_ros.errors import BusError, ConfigError, IdentityMismatch
from ether_ros.master.al import AlState
from ether_ros.master.datagrams import (
    Cmd,
    Datagram,
    DatagramService,
    auto_address,
    fixed_address,
    u16,
)
from ether_ros.master.found import FoundSlave
from ether_ros.master.sii import read_sii
from ether_ros.topology import Link, first_difference, tree_from_ports

FIRST_STATION = 0x1001

__all__ = ["Expected", "FoundSlave", "bus_tree", "match_configuration", "scan"]


def station_address(position: int) -> int:
    return FIRST_STATION + position


@dataclass(frozen=True)
class Expected:
    """What the configuration says should be found: at ``position``, or by ``alias``."""

    name: str
    vendor_id: int
    product_code: int
    revision: int | None = None
    position: int | None = None
    alias: int | None = None


def count_slaves(dg: DatagramService) -> int:
    _data, wkc = dg.brd(reg.TYPE, 2)
    return wkc


def reset_bus(dg: DatagramService) -> None:
    """Put every slave into a known state before addressing (broadcasts, one frame)."""
    dg.batch(
        [
            Datagram(Cmd.BWR, fixed_address(0, reg.DL_CONTROL_LOOP), b"\0"),
            Datagram(Cmd.BWR, fixed_address(0, reg.AL_CONTROL), u16(AlState.INIT | al.ERROR)),
            Datagram(Cmd.BWR, fixed_address(0, reg.FMMU0), bytes(reg.FMMU_LEN * reg.MAX_FMMUS)),
            Datagram(Cmd.BWR, fixed_address(0, reg.SM0), bytes(reg.SM_LEN * reg.MAX_SMS)),
            Datagram(Cmd.BWR, fixed_address(0, reg.DC_ACTIVATION), b"\0"),  # DC activation off
            Datagram(Cmd.BWR, fixed_address(0, reg.SII_CONFIG), b"\0"),  # EEPROM to EtherCAT
        ]
    )


def assign_stations(dg: DatagramService, count: int) -> list[int]:
    stations = [station_address(p) for p in range(count)]
    replies = dg.batch(
        [
            Datagram(Cmd.APWR, auto_address(p, reg.STATION_ADDRESS), u16(s))
            for p, s in enumerate(stations)
        ]
    )
    for p, r in enumerate(replies):
        if r.wkc != 1:
            raise BusError(f"slave {p}: setting station address 0x{stations[p]:04X} failed")
    return stations


def scan(dg: DatagramService, reset: bool = True) -> list[FoundSlave]:
    """Count, (reset), address and identify every slave on the line."""
    count = count_slaves(dg)
    if count == 0:
        return []
    if reset:
        reset_bus(dg)
    stations = assign_stations(dg, count)
    info = dg.batch(
        [Datagram(Cmd.FPRD, fixed_address(s, reg.STATION_ALIAS), 2) for s in stations]
        + [Datagram(Cmd.FPRD, fixed_address(s, reg.TYPE), 10) for s in stations]
        + [Datagram(Cmd.FPRD, fixed_address(s, reg.DL_STATUS), 2) for s in stations]
    )
    images = read_sii(dg, stations, [f"slave {p}" for p in range(count)])
    found: list[FoundSlave] = []
    for p, s in enumerate(stations):
        alias_r, esc_r, dl_r = info[p], info[count + p], info[2 * count + p]
        if alias_r.wkc != 1 or esc_r.wkc != 1 or dl_r.wkc != 1:
            raise BusError(f"slave {p}: no answer reading its registers")
        try:
            header = parse_sii(images[p])
        except ConfigError as exc:
            raise BusError(f"slave {p}: unreadable SII EEPROM: {exc}") from None
        (feature_bits,) = struct.unpack_from("<H", esc_r.data, reg.FEATURES)
        found.append(
            FoundSlave(
                position=p,
                station=s,
                alias=struct.unpack("<H", alias_r.data)[0],
                esc_type=esc_r.data[0],
                esc_features=feature_bits,
                sii=images[p],
                header=header,
                dl_status=struct.unpack("<H", dl_r.data)[0],
            )
        )
    return found


def bus_tree(found: Sequence[FoundSlave]) -> list[Link]:
    """Which slave hangs on which port of which other slave (by position), from the open ports
    of each slave (the frame enters every slave through port 0)."""
    try:
        return tree_from_ports([f.open_ports for f in found])
    except ValueError as exc:
        raise BusError(str(exc)) from None


def match_topology(found: Sequence[Link], expected: Sequence[Link], names: Sequence[str]) -> None:
    """Raise :class:`BusError` naming the first position where the bus's tree (``found``)
    differs from the configured one (``expected``; ``names``: configured names by position)."""
    difference = first_difference(expected, found, names)
    if difference is not None:
        raise BusError(f"the bus differs from the configuration: {difference}")


def match_configuration(found: Sequence[FoundSlave], expected: Sequence[Expected]) -> list[int]:
    """For each expected slave, the position it was found at; raises :class:`BusError` for
    missing, mismatching or unconfigured slaves."""
    positions: list[int] = []
    for i, exp in enumerate(expected):
        if exp.alias is not None:
            hits = [f for f in found if f.alias == exp.alias]
            where = f"alias {exp.alias}"
            if not hits:
                raise BusError(f"slave '{exp.name}' ({where}) is missing: no slave has that alias")
            slave = hits[0]
        else:
            pos = exp.position if exp.position is not None else i
            where = f"slave {pos}"
            if pos >= len(found):
                raise BusError(
                    f"slave {pos} ({exp.name}) is missing: the bus has only {len(found)} slave(s)"
                )
            slave = found[pos]
        label = f"slave {slave.position} ({exp.name})"
        mismatch = slave.vendor_id != exp.vendor_id or slave.product_code != exp.product_code
        if exp.revision is not None and slave.revision != exp.revision:
            mismatch = True
        if mismatch:
            raise IdentityMismatch(
                label,
                (exp.vendor_id, exp.product_code, exp.revision),
                (slave.vendor_id, slave.product_code, slave.revision),
            )
        positions.append(slave.position)
    if len(set(positions)) != len(positions):
        raise BusError("two configured slaves resolve to the same slave on the bus")
    extra = [f for f in found if f.position not in positions]
    if extra:
        f = extra[0]
        raise BusError(
            f"slave {f.position} ({f.identity()}) is on the bus but not in the configuration "
            f"({len(found)} found, {len(expected)} configured)"
        )
    return positions
