"""Per-slave configuration written during bring-up: mailbox SyncManagers (INIT → PREOP),
process-data SyncManagers and FMMUs (PREOP → SAFEOP).

Where a value comes from: the ESI when the configuration names a device for the slave, the
slave's own SII otherwise (standard mailbox words for SM0/SM1). SyncManager numbers follow the
ESI roles (normally 0 MBoxOut, 1 MBoxIn, 2 Outputs, 3 Inputs); a slave with outputs gets FMMU 0
for them, its inputs the next FMMU.
"""

from __future__ import annotations

from ether_ros._native.protocol import fmmu as fmmu_bits
from ether_ros._native.protocol import sm as sm_bits
from ether_ros.config.esi import EsiDevice
from ether_ros.config.sii import SiiInfo
from ether_ros.errors import BusError
from ether_ros.master.datagrams import Cmd, Datagram, DatagramService, fixed_address
from ether_ros.master.plan import SlaveArea
from ether_ros.master.sm_fmmu import (
    INPUTS_CONTROL,
    MAILBOX_IN_CONTROL,
    MAILBOX_OUT_CONTROL,
    OUTPUTS_CONTROL,
    Fmmu,
    SyncManager,
)

DEFAULT_OUTPUTS_SM = (2, 0x1100)
DEFAULT_INPUTS_SM = (3, 0x1400)


def mailbox_sync_managers(who: str, header: SiiInfo, device: EsiDevice | None) -> list[SyncManager]:
    """SM0/SM1 for the standard mailbox, or [] when the slave has no mailbox."""
    rx_offset, rx_size, tx_offset, tx_size = header.mailbox
    if rx_size and tx_size:
        out_ctl, in_ctl = MAILBOX_OUT_CONTROL, MAILBOX_IN_CONTROL
        out_no, in_no = 0, 1
        if device is not None:
            out_sm, in_sm = device.sm("MBoxOut"), device.sm("MBoxIn")
            if out_sm is not None and in_sm is not None:
                out_ctl, in_ctl = out_sm.control or out_ctl, in_sm.control or in_ctl
                out_no, in_no = out_sm.number, in_sm.number
        return [
            SyncManager(out_no, rx_offset, rx_size, out_ctl),
            SyncManager(in_no, tx_offset, tx_size, in_ctl),
        ]
    if device is not None and device.mailbox is not None:
        out_sm, in_sm = device.sm("MBoxOut"), device.sm("MBoxIn")
        if out_sm is None or in_sm is None or not out_sm.default_size or not in_sm.default_size:
            raise BusError(f"{who}: the ESI describes a mailbox without SyncManager sizes")
        return [
            SyncManager(out_sm.number, out_sm.start, out_sm.default_size, out_sm.control),
            SyncManager(in_sm.number, in_sm.start, in_sm.default_size, in_sm.control),
        ]
    return []


def process_sync_managers(
    device: EsiDevice | None, output_bytes: int, input_bytes: int
) -> list[SyncManager]:
    """The output (SM2) and input (SM3) SyncManagers sized to the assigned PDOs. A direction
    without data gets its SM disabled (length 0), which is what slaves expect then."""
    sms: list[SyncManager] = []
    for role, nbytes, (number, start), control in (
        ("Outputs", output_bytes, DEFAULT_OUTPUTS_SM, OUTPUTS_CONTROL),
        ("Inputs", input_bytes, DEFAULT_INPUTS_SM, INPUTS_CONTROL),
    ):
        desc = device.sm(role) if device is not None else None
        if desc is not None:
            number, start, control = desc.number, desc.start, desc.control or control
        elif nbytes == 0:
            continue
        sms.append(SyncManager(number, start, nbytes, control, enable=nbytes > 0))
    return sms


def process_fmmus(area: SlaveArea, sms: list[SyncManager], logical_base: int) -> list[Fmmu]:
    """FMMUs mapping the slave's output and input SyncManagers into the logical image."""
    fmmus: list[Fmmu] = []
    by_dir = {(sm.control & sm_bits.DIR_MASK): sm for sm in sms if sm.enable}
    # Outputs first, then inputs: the FMMU numbers follow this order.
    directions = (
        ("output", area.output_bytes, area.output_offset, by_dir.get(sm_bits.DIR_WRITE),
         fmmu_bits.WRITE),
        ("input", area.input_bytes, area.input_offset, by_dir.get(sm_bits.DIR_READ),
         fmmu_bits.READ),
    )  # fmt: skip
    for what, nbytes, offset, sm, access in directions:
        if not nbytes:
            continue
        if sm is None:
            raise BusError(f"slave {area.position} ({area.name}): {what}s but no {what} SM")
        fmmus.append(Fmmu(len(fmmus), logical_base + offset, nbytes, sm.start, access))
    return fmmus


def write_sync_managers(
    dg: DatagramService, station: int, who: str, sms: list[SyncManager]
) -> None:
    replies = dg.batch(
        [Datagram(Cmd.FPWR, fixed_address(station, sm.register), sm.encode()) for sm in sms]
    )
    for sm, r in zip(sms, replies, strict=True):
        if r.wkc != 1:
            raise BusError(f"{who}: writing SyncManager {sm.index} failed (wkc {r.wkc})")


def write_fmmus(dg: DatagramService, station: int, who: str, fmmus: list[Fmmu]) -> None:
    replies = dg.batch(
        [Datagram(Cmd.FPWR, fixed_address(station, f.register), f.encode()) for f in fmmus]
    )
    for f, r in zip(fmmus, replies, strict=True):
        if r.wkc != 1:
            raise BusError(f"{who}: writing FMMU {f.index} failed (wkc {r.wkc})")
