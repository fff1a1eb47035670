"""SyncManager and FMMU register contents (ETG.1000.4 / ESC datasheet).

A SyncManager (8 bytes at 0x0800 + 8·n) guards a window of the slave's process RAM: the mailbox
SMs (0 master→slave, 1 slave→master) use the one-buffer handshake, the process-data SMs (2
outputs, 3 inputs) the three-buffer mode. An FMMU (16 bytes at 0x0600 + 16·n) maps a range of the
logical address space the LRW datagram travels through onto such a window.

The register records' byte layout is the protocol crate's (``reg::sm::Record``,
``reg::fmmu::Record``, the codec the simulator's ESC reads them with); these classes carry the
master's values and hand them to it.
"""

from __future__ import annotations

from dataclasses import dataclass

from ether_ros._native.protocol import (
    fmmu,
    fmmu_record,
    parse_fmmu_record,
    parse_sm_record,
    reg,
    sm,
    sm_record,
)

# The control bytes the master uses when the slave's SII/ESI gives none (the usual defaults;
# the bits are the protocol crate's, ``protocol.sm``).
MAILBOX_OUT_CONTROL = sm.MODE_MAILBOX | sm.DIR_WRITE | sm.PDI_EVENT  # 0x26, SM0
MAILBOX_IN_CONTROL = sm.MODE_MAILBOX | sm.DIR_READ | sm.PDI_EVENT  # 0x22, SM1
OUTPUTS_CONTROL = sm.MODE_BUFFERED | sm.DIR_WRITE | sm.PDI_EVENT | sm.WATCHDOG  # 0x64, SM2
INPUTS_CONTROL = sm.MODE_BUFFERED | sm.DIR_READ | sm.PDI_EVENT  # 0x20, SM3


@dataclass(frozen=True)
class SyncManager:
    index: int
    start: int
    length: int
    control: int
    enable: bool = True

    @property
    def register(self) -> int:
        return reg.SM0 + reg.SM_LEN * self.index

    def encode(self) -> bytes:
        """Start (u16), length (u16), control (u8), status (u8, read-only), activate (u8),
        PDI control (u8, read-only)."""
        return sm_record(self.start, self.length, self.control, self.enable)

    @classmethod
    def decode(cls, index: int, data: bytes) -> SyncManager:
        record = parse_sm_record(data)
        if record is None:
            raise ValueError(f"SyncManager {index}: {len(data)} bytes, the record is 8")
        start, length, control, _status, activate, _pdi = record
        return cls(index, start, length, control, bool(activate & sm.ACTIVATE_ENABLE))


@dataclass(frozen=True)
class Fmmu:
    index: int
    logical_start: int
    length: int
    physical_start: int
    direction: int  # protocol.fmmu.READ (inputs) or WRITE (outputs)
    logical_start_bit: int = 0
    logical_end_bit: int = 7
    physical_start_bit: int = 0
    enable: bool = True

    @property
    def register(self) -> int:
        return reg.FMMU0 + reg.FMMU_LEN * self.index

    def encode(self) -> bytes:
        """Logical start (u32), length (u16), start bit (u8), end bit (u8), physical start
        (u16), physical start bit (u8), type (u8), activate (u8), 3 reserved bytes."""
        return fmmu_record(
            self.logical_start,
            self.length,
            self.physical_start,
            self.direction,
            self.logical_start_bit,
            self.logical_end_bit,
            self.physical_start_bit,
            self.enable,
        )

    @classmethod
    def decode(cls, index: int, data: bytes) -> Fmmu:
        record = parse_fmmu_record(data)
        if record is None:
            raise ValueError(f"FMMU {index}: {len(data)} bytes, the record is 16")
        ls, length, lsb, leb, ps, psb, typ, act = record
        return cls(index, ls, length, ps, typ, lsb, leb, psb, bool(act & fmmu.ACTIVATE_ENABLE))


def mailbox_sms(rx_offset: int, rx_size: int, tx_offset: int, tx_size: int) -> list[SyncManager]:
    """SM0 (master → slave) and SM1 (slave → master) from the SII standard mailbox words."""
    return [
        SyncManager(0, rx_offset, rx_size, MAILBOX_OUT_CONTROL),
        SyncManager(1, tx_offset, tx_size, MAILBOX_IN_CONTROL),
    ]
