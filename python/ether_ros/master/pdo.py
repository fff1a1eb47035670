"""Which PDOs a slave exchanges, and the CoE writes that tell the slave.

Sources, first that applies:
1. the bus configuration's ``pdo_assign`` override (PDO indices; their contents from the ESI),
2. the ESI's default assignment (PDOs with an ``Sm`` attribute),
3. the PDO categories of the slave's SII (for slaves without an ESI file).

When the configuration overrides the assignment and the slave has CoE, the master writes it in
PREOP: 0x1C12 (RxPDOs, SM2) and 0x1C13 (TxPDOs, SM3) — subindex 0 to 0, the PDO indices, then
subindex 0 to their count — and, for PDOs the ESI does not mark fixed, the mapping objects
(0x16xx/0x1Axx) the same way with one 32-bit entry (index<<16 | subindex<<8 | bits) each.
"""

from __future__ import annotations

import struct
from collections.abc import Sequence
from dataclasses import dataclass, field

from ether_ros._native.protocol import coe, format_address
from ether_ros.config.esi import EsiDevice, Pdo, PdoEntry
from ether_ros.errors import BusError

RX_ASSIGN = coe.RXPDO_ASSIGN
TX_ASSIGN = coe.TXPDO_ASSIGN


@dataclass(frozen=True)
class SdoWrite:
    """One SDO download the PDO configuration needs, in order."""

    index: int
    subindex: int
    data: bytes
    why: str


@dataclass
class PdoSelection:
    rx: list[Pdo] = field(default_factory=list)  # outputs (master → slave)
    tx: list[Pdo] = field(default_factory=list)  # inputs (slave → master)
    source: str = "esi"  # 'config' | 'esi' | 'sii'

    @property
    def output_bits(self) -> int:
        return sum(p.bit_length for p in self.rx)

    @property
    def input_bits(self) -> int:
        return sum(p.bit_length for p in self.tx)

    @property
    def output_bytes(self) -> int:
        return (self.output_bits + 7) // 8

    @property
    def input_bytes(self) -> int:
        return (self.input_bits + 7) // 8

    def output_entries(self) -> list[PdoEntry]:
        return [e for p in self.rx for e in p.entries]

    def input_entries(self) -> list[PdoEntry]:
        return [e for p in self.tx for e in p.entries]


def select_pdos(
    who: str,
    device: EsiDevice | None,
    override_rx: Sequence[int] | None = None,
    override_tx: Sequence[int] | None = None,
    sii_rx: Sequence[Pdo] = (),
    sii_tx: Sequence[Pdo] = (),
) -> PdoSelection:
    """The PDOs of one slave; ``who`` names it in errors."""
    if device is None:
        if override_rx is not None or override_tx is not None:
            by_index = {p.index: p for p in (*sii_rx, *sii_tx)}
            rx = [_lookup(who, by_index, i, "SII") for i in (override_rx or [])]
            tx = [_lookup(who, by_index, i, "SII") for i in (override_tx or [])]
            return PdoSelection(rx, tx, "config")
        return PdoSelection(
            [p for p in sii_rx if p.sm is not None], [p for p in sii_tx if p.sm is not None], "sii"
        )
    by_index = {p.index: p for p in (*device.rx_pdos, *device.tx_pdos)}
    source = "esi"
    rx_ids: Sequence[int] = device.default_rx_pdos()
    tx_ids: Sequence[int] = device.default_tx_pdos()
    if override_rx is not None:
        rx_ids, source = override_rx, "config"
    if override_tx is not None:
        tx_ids, source = override_tx, "config"
    rx = [_lookup(who, by_index, i, "ESI") for i in rx_ids]
    tx = [_lookup(who, by_index, i, "ESI") for i in tx_ids]
    for p in rx:
        if p.direction != "rx":
            raise BusError(f"{who}: PDO 0x{p.index:04X} is a TxPDO (input), assigned as output")
    for p in tx:
        if p.direction != "tx":
            raise BusError(f"{who}: PDO 0x{p.index:04X} is an RxPDO (output), assigned as input")
    chosen = {p.index for p in (*rx, *tx)}
    for p in (*rx, *tx):
        clash = chosen.intersection(p.excludes)
        if clash:
            other = min(clash)
            raise BusError(f"{who}: PDO 0x{p.index:04X} excludes PDO 0x{other:04X}")
    return PdoSelection(rx, tx, source)


def _lookup(who: str, by_index: dict[int, Pdo], index: int, where: str) -> Pdo:
    pdo = by_index.get(index)
    if pdo is None:
        known = ", ".join(f"0x{i:04X}" for i in sorted(by_index)) or "none"
        raise BusError(f"{who}: PDO 0x{index:04X} is not in the {where} (known: {known})")
    return pdo


def assignment_writes(selection: PdoSelection, write_mapping: bool) -> list[SdoWrite]:
    """The SDO downloads that make the slave use ``selection`` (see module doc)."""
    writes: list[SdoWrite] = []
    if write_mapping:
        for pdo in (*selection.rx, *selection.tx):
            if pdo.fixed:
                continue
            writes.append(SdoWrite(pdo.index, 0, b"\0", f"clear mapping 0x{pdo.index:04X}"))
            for sub, entry in enumerate(pdo.entries, start=1):
                writes.append(
                    SdoWrite(
                        pdo.index,
                        sub,
                        struct.pack("<I", entry.mapping_value),
                        f"mapping {format_address(pdo.index, sub)}",
                    )
                )
            writes.append(
                SdoWrite(pdo.index, 0, bytes([len(pdo.entries)]), f"mapping 0x{pdo.index:04X}")
            )
    for assign, pdos in ((RX_ASSIGN, selection.rx), (TX_ASSIGN, selection.tx)):
        writes.append(SdoWrite(assign, 0, b"\0", f"clear assignment 0x{assign:04X}"))
        for sub, pdo in enumerate(pdos, start=1):
            writes.append(
                SdoWrite(assign, sub, struct.pack("<H", pdo.index), f"assignment 0x{assign:04X}")
            )
        writes.append(SdoWrite(assign, 0, bytes([len(pdos)]), f"assignment 0x{assign:04X}"))
    return writes
