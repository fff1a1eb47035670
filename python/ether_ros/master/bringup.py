"""The per-state configuration steps of bring-up, shared by ``Bus.start`` (all slaves) and the
supervisor (one slave that dropped out and came back).

INIT   : mailbox SyncManagers (SM0/SM1)                           → request PREOP
PREOP  : sdo_init list, PDO assignment/mapping over CoE (if the configuration overrides it),
         process-data SyncManagers (SM2/SM3) and FMMUs, DC SYNC0    → request SAFEOP
SAFEOP : (the cyclic frame runs, so outputs are valid)             → request OP
"""

from __future__ import annotations

import logging
from collections.abc import Sequence
from typing import Any

from ether_ros._native.protocol import format_address
from ether_ros.config import types as dt
from ether_ros.errors import BusError, EtherRosError
from ether_ros.master.configure import (
    mailbox_sync_managers,
    process_fmmus,
    process_sync_managers,
    write_fmmus,
    write_sync_managers,
)
from ether_ros.master.datagrams import DatagramService
from ether_ros.master.pdo import assignment_writes
from ether_ros.master.plan import LOGICAL_BASE
from ether_ros.master.shared_frames import run_in_parallel
from ether_ros.master.slave import Slave

log = logging.getLogger(__name__)


def setup_mailbox(dg: DatagramService, slave: Slave) -> None:
    """INIT: SM0/SM1 and the Mailbox/SdoClient objects (if the slave has a mailbox)."""
    sms = mailbox_sync_managers(str(slave), slave.found.header, slave.device)
    if not sms:
        slave.mailbox = slave.sdo = None
        return
    write_sync_managers(dg, slave.station, str(slave), sms)
    from ether_ros.master.mailbox import Mailbox

    out_sm, in_sm = sms
    slave.mailbox = Mailbox(
        dg, slave.station, slave.name, out_sm.start, out_sm.length, in_sm.start, in_sm.length
    )
    slave.sdo = None
    if slave.has_coe:
        slave.sdo = make_sdo_client(slave)


def make_sdo_client(slave: Slave) -> Any:
    from ether_ros.master import coe

    return coe.SdoClient(slave.mailbox, slave.name)


def sdo_download(slave: Slave, index: int, subindex: int, data: bytes, why: str) -> None:
    if slave.sdo is None:
        raise BusError(
            f"{slave}: has no CoE mailbox, cannot write {format_address(index, subindex)} ({why})"
        )
    try:
        slave.sdo.download(index, subindex, data)
    except EtherRosError as exc:
        raise BusError(f"{slave}: {why} failed: {exc}") from None


def encode_sdo_value(slave: Slave, index: int, subindex: int, value: object,
                     type_name: str | None = None) -> bytes:  # fmt: skip
    """Bytes for an SDO value: typed by ``type_name`` or the ESI dictionary entry."""
    if isinstance(value, bytes | bytearray):
        return bytes(value)
    dtype: dt.DataType | None = None
    bits = 0
    if type_name:
        dtype = dt.config_type(type_name)
        if dtype is None:
            raise BusError(
                f"{slave}: unknown data type {type_name!r} for {format_address(index, subindex)}"
            )
        bits = dtype.bit_length
    elif slave.device is not None:
        entry = slave.device.od_entry(index, subindex)
        if entry is not None:
            dtype = dt.BY_CODE.get(entry.data_type)
            bits = entry.bit_length
    if dtype is None:
        raise BusError(
            f"{slave}: the type of {format_address(index, subindex)} is unknown (not in the ESI "
            "dictionary); give its type"
        )
    if not bits:
        bits = 8 * len(str(value).encode()) if dtype.kind == "string" else bits
    try:
        return dt.encode_value(dtype, value, bits)
    except ValueError as exc:
        raise BusError(f"{slave}: value for {format_address(index, subindex)}: {exc}") from None


def configure_preop(dg: DatagramService, slave: Slave) -> None:
    """PREOP: sdo_init, PDO assignment, process SMs and FMMUs."""
    cfg = slave.config
    for item in getattr(cfg, "sdo_init", None) or []:
        index, sub = int(item.index), int(item.subindex)
        # The configuration loader encodes the value against the ESI dictionary already.
        data = getattr(item, "data", b"") or encode_sdo_value(
            slave, index, sub, item.value, getattr(item, "type", None)
        )
        sdo_download(slave, index, sub, data, f"sdo_init {format_address(index, sub)}")
    if slave.selection.source == "config":
        write_pdo_assignment(slave)
    area = slave.area
    if area is None:
        return
    sms = process_sync_managers(slave.device, area.output_bytes, area.input_bytes)
    write_sync_managers(dg, slave.station, str(slave), sms)
    write_fmmus(dg, slave.station, str(slave), process_fmmus(area, sms, LOGICAL_BASE))


def write_pdo_assignment(slave: Slave) -> None:
    """Tell the slave the configuration's PDO assignment (0x1C12/0x1C13, and the mapping
    objects when it supports PDO configuration). A slave that cannot change its assignment is
    fine as long as the configuration asks for what it has anyway."""
    device = slave.device
    mailbox = device.mailbox if device is not None else None
    can_assign = slave.has_coe and mailbox is not None and mailbox.pdo_assign
    chosen = ([p.index for p in slave.selection.rx], [p.index for p in slave.selection.tx])
    if not can_assign:
        if device is not None and chosen == (
            list(device.default_rx_pdos()),
            list(device.default_tx_pdos()),
        ):
            return
        wanted = ", ".join(f"0x{i:04X}" for i in (*chosen[0], *chosen[1]))
        raise BusError(
            f"{slave}: the configuration assigns PDOs {wanted}, but the device cannot change "
            "its PDO assignment (no CoE PdoAssign in its ESI)"
        )
    pdo_config = mailbox is not None and mailbox.pdo_config
    for w in assignment_writes(slave.selection, write_mapping=pdo_config):
        sdo_download(slave, w.index, w.subindex, w.data, w.why)


def configure_all_preop(dg: DatagramService, slaves: Sequence[Slave]) -> None:
    """``configure_preop`` of every slave at once, their datagrams (SDO init, PDO assignment,
    SyncManagers, FMMUs) sharing frames (``shared_frames.py``)."""
    run_in_parallel(dg, slaves, _configure_preop_over)


def _configure_preop_over(dg: DatagramService, slave: Slave) -> None:
    """``configure_preop`` with the slave's mailbox on ``dg`` for the time of it."""
    mailbox = slave.mailbox
    before = mailbox.dg if mailbox is not None else None
    if mailbox is not None:
        mailbox.dg = dg
    try:
        configure_preop(dg, slave)
    finally:
        if mailbox is not None:
            mailbox.dg = before
