"""Which PDOs a slave exchanges, and the CoE writes that tell the slave — as TwinCAT and the
IgH master do it.

Sources, first that applies:
1. the bus configuration's ``pdo_assign`` override (PDO indices; their contents from the ESI),
2. the ESI's default assignment (PDOs with an ``Sm`` attribute; modules placed in slots),
3. the PDO categories of the slave's SII (for slaves without an ESI file).

Whichever it is, a slave with CoE is told in PREOP: for every process-data SyncManager n that
carries PDOs, the assignment object 0x1C10 + n (0x1C12 for SM2, 0x1C13 for SM3) holds the PDO
indices when the ESI allows PDO assignment (``<CoE PdoAssign>``), and the mapping objects
(0x16xx/0x1Axx) of the PDOs the ESI does not mark ``Fixed`` hold their entries when it allows
PDO configuration (``<CoE PdoConfig>``). The master reads what the slave has first and writes
only what differs (as the IgH master does), so a device whose objects are read-only but
already right is fine, and one whose stored assignment differs from its ESI is set right.
A write goes: assignment subindex 0 to 0, the mapping of each changed PDO (subindex 0 to 0,
the entries as index<<16 | subindex<<8 | bits, subindex 0 to their count), the assignment's
PDO indices, assignment subindex 0 to their count.
"""

from __future__ import annotations

import struct
from collections.abc import Sequence
from dataclasses import dataclass, field

from ether_ros._native.protocol import coe, format_address
from ether_ros.config.esi import EsiDevice, Pdo, PdoEntry
from ether_ros.config.process import pdo_sync_manager
from ether_ros.errors import BusError

#: PDO assignment object of SyncManager n: 0x1C10 + n (0x1C12 for SM2, 0x1C13 for SM3).
SM_ASSIGN_BASE = coe.SM_PDO_ASSIGN
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
    source = "esi"
    rx = list(device.default_rx())
    tx = list(device.default_tx())
    by_index = {p.index: p for p in (*device.rx_pdos, *device.tx_pdos) if not p.virtual}
    for p in (*device.rx_pdos, *device.tx_pdos):
        by_index.setdefault(p.index, p)
    if override_rx is not None:
        rx, source = [_lookup(who, by_index, i, "ESI") for i in override_rx], "config"
    if override_tx is not None:
        tx, source = [_lookup(who, by_index, i, "ESI") for i in override_tx], "config"
    for p in rx:
        if p.direction != "rx":
            raise BusError(f"{who}: PDO 0x{p.index:04X} is a TxPDO (input), assigned as output")
    for p in tx:
        if p.direction != "tx":
            raise BusError(f"{who}: PDO 0x{p.index:04X} is an RxPDO (output), assigned as input")
    chosen = {p.index for p in (*rx, *tx)}
    for p in (*rx, *tx):
        clash = chosen.intersection(p.excludes) - {p.index}
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


@dataclass(frozen=True)
class SmAssignment:
    """The PDOs one process-data SyncManager carries, and its assignment object."""

    sm: int
    pdos: tuple[Pdo, ...]

    @property
    def index(self) -> int:
        return SM_ASSIGN_BASE + self.sm

    @property
    def pdo_indices(self) -> list[int]:
        return [p.index for p in self.pdos]


def sm_assignments(device: EsiDevice, selection: PdoSelection) -> list[SmAssignment]:
    """The selection split by SyncManager, for every real (not virtual) process-data SM of the
    device — also those left without PDOs, whose assignment is then empty."""
    by_sm: dict[int, list[Pdo]] = {
        sm.number: [] for sm in device.sync_managers if sm.is_process_data and not sm.virtual
    }
    for pdo in (*selection.rx, *selection.tx):
        sm = pdo_sync_manager(device, pdo)
        if sm in by_sm:
            by_sm[sm].append(pdo)
    return [SmAssignment(sm, tuple(pdos)) for sm, pdos in sorted(by_sm.items())]


def assignment_writes(
    assignments: Sequence[SmAssignment], mapped: Sequence[Pdo] = ()
) -> list[SdoWrite]:
    """The SDO downloads that give ``assignments`` their PDOs and ``mapped`` their entries
    (see module doc): per SyncManager, clear the assignment, write the mappings of its PDOs
    that are in ``mapped``, then the assignment."""
    writes: list[SdoWrite] = []
    for a in assignments:
        writes.append(SdoWrite(a.index, 0, b"\0", f"clear assignment 0x{a.index:04X}"))
        for pdo in a.pdos:
            if pdo in mapped:
                writes.extend(mapping_writes(pdo))
        for sub, index in enumerate(a.pdo_indices, start=1):
            writes.append(
                SdoWrite(a.index, sub, struct.pack("<H", index), f"assignment 0x{a.index:04X}")
            )
        writes.append(SdoWrite(a.index, 0, bytes([len(a.pdos)]), f"assignment 0x{a.index:04X}"))
    return writes


def mapping_writes(pdo: Pdo) -> list[SdoWrite]:
    """Clear the mapping object of ``pdo``, write its entries, then their count."""
    writes = [SdoWrite(pdo.index, 0, b"\0", f"clear mapping 0x{pdo.index:04X}")]
    for sub, entry in enumerate(pdo.entries, start=1):
        writes.append(
            SdoWrite(
                pdo.index,
                sub,
                struct.pack("<I", entry.mapping_value),
                f"mapping {format_address(pdo.index, sub)}",
            )
        )
    writes.append(SdoWrite(pdo.index, 0, bytes([len(pdo.entries)]), f"mapping 0x{pdo.index:04X}"))
    return writes


def mapping_values(pdo: Pdo) -> list[int]:
    """The 32-bit mapping entries of ``pdo`` as the slave stores them."""
    return [e.mapping_value for e in pdo.entries]
