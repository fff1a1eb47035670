"""The configuration work of the steps of a slave's state machine (``slave_fsm.py``), the same
for bring-up (every slave in parallel) and recovery (one slave that dropped out and came back).

INIT   : mailbox SyncManagers (SM0/SM1)                           → request PREOP
PREOP  : ESI init commands (IP, PS), sdo_init list, PDO assignment/mapping over CoE (read
         first, written where the slave differs), process-data SyncManagers and FMMUs,
         DC SYNC0                                                   → request SAFEOP
SAFEOP : ESI init commands (SO), OpOnly SyncManagers enabled; the cyclic frame runs, so
         outputs are valid                                          → request OP
"""

from __future__ import annotations

import logging
from collections.abc import Sequence
from typing import Any

from ether_ros._native.protocol import format_address
from ether_ros.config import types as dt
from ether_ros.config.esi import Pdo
from ether_ros.errors import BusError, EtherRosError, MailboxError
from ether_ros.master.configure import (
    mailbox_sync_managers,
    op_only_sync_managers,
    process_fmmus,
    process_sync_managers,
    write_fmmus,
    write_sync_managers,
)
from ether_ros.master.datagrams import DatagramService
from ether_ros.master.pdo import (
    PdoSelection,
    SmAssignment,
    assignment_writes,
    mapping_values,
    sm_assignments,
)
from ether_ros.master.plan import LOGICAL_BASE
from ether_ros.master.slave import Slave

log = logging.getLogger(__name__)


def setup_mailbox(dg: DatagramService, slave: Slave, write: bool = True) -> None:
    """INIT: SM0/SM1 and the Mailbox/SdoClient objects (if the slave has a mailbox).
    ``write`` False: the slave's mailbox SyncManagers are live already (a slave found in PREOP
    or above by an inspection), only the objects are made."""
    sms = mailbox_sync_managers(str(slave), slave.found.header, slave.device)
    if not sms:
        slave.mailbox = slave.sdo = slave.sdo_client = None
        return
    if write:
        write_sync_managers(dg, slave.station, str(slave), sms)
    from ether_ros.master.mailbox import Mailbox

    out_sm, in_sm = sms
    slave.mailbox = Mailbox(
        dg, slave.station, slave.name, out_sm.start, out_sm.length, in_sm.start, in_sm.length
    )
    slave.sdo = slave.sdo_client = None
    if slave.has_coe:
        slave.sdo = slave.sdo_client = make_sdo_client(slave)


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
    """PREOP: the ESI's CoE init commands of INIT → PREOP and PREOP → SAFEOP, the
    configuration's sdo_init (after them: the configuration wins), the PDO assignment and
    mapping, process-data SMs and FMMUs."""
    configure_coe(slave)
    configure_process_data(dg, slave)


def configure_coe(slave: Slave) -> None:
    """PREOP over the mailbox: the ESI's init commands (IP, PS), the configuration's sdo_init
    (after them: the configuration wins), the PDO assignment and mapping."""
    run_init_cmds(slave, ("IP", "PS"))
    cfg = slave.config
    for item in getattr(cfg, "sdo_init", None) or []:
        index, sub = int(item.index), int(item.subindex)
        # The configuration loader encodes the value against the ESI dictionary already.
        data = getattr(item, "data", b"") or encode_sdo_value(
            slave, index, sub, item.value, getattr(item, "type", None)
        )
        sdo_download(slave, index, sub, data, f"sdo_init {format_address(index, sub)}")
    configure_pdos(slave)


def configure_process_data(dg: DatagramService, slave: Slave) -> None:
    """PREOP: the process-data SyncManagers and FMMUs of the slave's image area."""
    area = slave.area
    if area is None:
        return
    segments = slave.layout.segments if slave.layout is not None else ()
    if slave.device is not None and slave.layout is not None:
        sms = process_sync_managers(slave.device, segments)
    else:
        sms = process_sync_managers(slave.device, area.output_bytes, area.input_bytes)
    write_sync_managers(dg, slave.station, str(slave), sms)
    fmmus = process_fmmus(area, sms, LOGICAL_BASE, slave.device, segments)
    write_fmmus(dg, slave.station, str(slave), fmmus)


def configure_safeop(dg: DatagramService, slave: Slave) -> None:
    """SAFEOP, before OP is requested: the init commands of SAFEOP → OP, and the ``OpOnly``
    SyncManagers enabled."""
    run_init_cmds(slave, ("SO",))
    if slave.device is None or slave.layout is None:
        return
    sms = op_only_sync_managers(slave.device, slave.layout.segments)
    if sms:
        write_sync_managers(dg, slave.station, str(slave), sms)


def run_init_cmds(slave: Slave, transitions: Sequence[str]) -> None:
    """The ESI's CoE init commands of ``transitions``, in ESI order (as TwinCAT sends them)."""
    device = slave.device
    if device is None or not slave.has_coe:
        return
    for cmd in device.init_cmds:
        if not any(t in cmd.transitions for t in transitions):
            continue
        why = f"ESI init command {format_address(cmd.index, cmd.subindex)}"
        if cmd.comment:
            why += f" ({cmd.comment})"
        if slave.sdo is None:
            raise BusError(f"{slave}: has no CoE mailbox for the {why}")
        try:
            slave.sdo.download(cmd.index, cmd.subindex, cmd.data, cmd.complete_access)
        except EtherRosError as exc:
            raise BusError(f"{slave}: {why} failed: {exc}") from None


def configure_pdos(slave: Slave) -> None:
    """Tell a CoE slave its PDO assignment and mapping (module doc of ``master/pdo.py``): what
    the slave has is read first, and only what differs is written. A slave that cannot change
    its assignment is fine as long as it has what the configuration asks for."""
    device = slave.device
    if device is None or slave.layout is None:
        return
    mailbox = device.mailbox
    override = slave.selection.source == "config"
    can_assign = slave.has_coe and mailbox is not None and mailbox.pdo_assign
    can_map = slave.has_coe and mailbox is not None and mailbox.pdo_config
    assignments = sm_assignments(device, slave.selection)
    if not can_assign:
        if override and [a.pdo_indices for a in assignments] != [
            a.pdo_indices
            for a in sm_assignments(device, PdoSelection(list(device.default_rx()),
                                                         list(device.default_tx())))
        ]:  # fmt: skip
            wanted = ", ".join(f"0x{p.index:04X}" for a in assignments for p in a.pdos)
            raise BusError(
                f"{slave}: the configuration assigns PDOs {wanted}, but the device cannot change "
                "its PDO assignment (no CoE PdoAssign in its ESI)"
            )
        return
    changed: list[SmAssignment] = []
    remap: list[Pdo] = []
    for a in assignments:
        current = _read_list(slave, a.index, 2)
        if current is None:
            if override:
                raise BusError(
                    f"{slave}: the configuration assigns PDOs to SM{a.sm}, but the slave has no "
                    f"assignment object 0x{a.index:04X}"
                )
            log.info("%s: no PDO assignment object 0x%04X: the slave's own assignment is used",
                     slave, a.index)  # fmt: skip
            continue
        stale = [
            p
            for p in a.pdos
            if can_map and not p.fixed and not p.virtual
            and _read_list(slave, p.index, 4) != mapping_values(p)
        ]  # fmt: skip
        if stale or current != a.pdo_indices:
            changed.append(a)
            remap.extend(stale)
    for w in assignment_writes(changed, remap):
        sdo_download(slave, w.index, w.subindex, w.data, w.why)


def _read_list(slave: Slave, index: int, width: int) -> list[int] | None:
    """Subindex 0 (a count) and the entries of an assignment (``width`` 2) or mapping (4)
    object of the slave; None when the slave has no such object."""
    if slave.sdo is None:
        return None
    try:
        count = int.from_bytes(slave.sdo.upload(index, 0)[:1] or b"\0", "little")
        return [
            int.from_bytes(slave.sdo.upload(index, sub)[:width], "little")
            for sub in range(1, count + 1)
        ]
    except MailboxError:
        return None


def write_pdo_assignment(slave: Slave) -> None:
    """Compatibility name of :func:`configure_pdos`."""
    configure_pdos(slave)


def sdo_type(
    slave: Slave, index: int, subindex: int, type_name: str | None
) -> tuple[dt.DataType | None, int]:
    """The type and bit length of an object of ``slave``: by ``type_name``, else the ESI
    dictionary's (None: unknown)."""
    if type_name:
        t = dt.config_type(type_name)
        if t is None:
            raise BusError(f"unknown data type {type_name!r}")
        return t, t.bit_length
    if slave.device is not None:
        e = slave.device.od_entry(index, subindex)
        if e is not None:
            return dt.BY_CODE.get(e.data_type), e.bit_length
    return None, 0


def sdo_read(slave: Slave, index: int, subindex: int, type_name: str | None) -> object:
    """Upload an object, typed by ``type_name`` or the ESI dictionary (raw bytes when neither
    knows the type), through the slave's mailbox owner."""
    if slave.sdo is None:
        raise BusError(f"{slave}: has no CoE mailbox (start the bus first)")
    data: bytes = slave.sdo.upload(index, subindex)
    t, bits = sdo_type(slave, index, subindex, type_name)
    if t is None:
        return data
    bits = 8 * len(data) if not bits or t.kind in ("string", "bytes") else bits
    return dt.decode_value(t, data[: (bits + 7) // 8], bits)


def sdo_write(slave: Slave, index: int, subindex: int, value: object,
              type_name: str | None) -> None:  # fmt: skip
    if slave.sdo is None:
        raise BusError(f"{slave}: has no CoE mailbox (start the bus first)")
    slave.sdo.download(index, subindex, encode_sdo_value(slave, index, subindex, value, type_name))
