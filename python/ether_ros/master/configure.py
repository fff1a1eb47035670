"""Per-slave configuration written during bring-up: mailbox SyncManagers (INIT → PREOP),
process-data SyncManagers and FMMUs (PREOP → SAFEOP), ``OpOnly`` SyncManagers (SAFEOP → OP).

Where a value comes from: the ESI when the configuration names a device for the slave, the
slave's own SII otherwise (standard mailbox words for SM0/SM1). SyncManager numbers follow the
ESI (normally 0 MBoxOut, 1 MBoxIn, 2 Outputs, 3 Inputs, but a device may have several of a
direction, none, or SMs in the ESC's digital I/O registers at 0x0F00); a slave's output FMMUs
come first, then its input FMMUs.
"""

from __future__ import annotations

from collections.abc import Sequence

from ether_ros._native.protocol import fmmu as fmmu_bits
from ether_ros._native.protocol import sm as sm_bits
from ether_ros.config.esi import EsiDevice
from ether_ros.config.process import SmSegment
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
    device: EsiDevice | None,
    segments: Sequence[SmSegment] | int,
    input_bytes: int | None = None,
    *,
    op: bool = False,
) -> list[SyncManager]:
    """The process-data SyncManagers of a slave, each as long as its segment of the slave's
    area. Every real process-data SM of the ESI is written: one without PDOs disabled (length
    0), as slaves expect then; an ``OpOnly`` SM stays disabled until ``op`` (SAFEOP → OP);
    a virtual SM is no hardware SM and is not written (an FMMU maps its memory directly).

    Without an ESI, ``segments`` is the output byte count and ``input_bytes`` the input one,
    laid out as the usual SM2 (outputs at 0x1100) and SM3 (inputs at 0x1400)."""
    if device is None or isinstance(segments, int):
        return _default_process_sms(
            device, int(segments) if isinstance(segments, int) else 0, input_bytes or 0
        )
    length = {seg.sm: seg.byte_length for seg in segments}
    sms: list[SyncManager] = []
    for desc in device.sync_managers:
        if not desc.is_process_data or desc.virtual:
            continue
        nbytes = length.get(desc.number, 0)
        default = OUTPUTS_CONTROL if desc.role == "Outputs" else INPUTS_CONTROL
        enable = nbytes > 0 and (op or not desc.op_only)
        sms.append(SyncManager(desc.number, desc.start, nbytes, desc.control or default, enable))
    return sms


def op_only_sync_managers(
    device: EsiDevice | None, segments: Sequence[SmSegment]
) -> list[SyncManager]:
    """The ``OpOnly`` SyncManagers with data, enabled: written on SAFEOP → OP."""
    if device is None:
        return []
    ops = {d.number for d in device.sync_managers if d.op_only and not d.virtual}
    return [
        sm
        for sm in process_sync_managers(device, segments, op=True)
        if sm.index in ops and sm.enable
    ]


def _default_process_sms(
    device: EsiDevice | None, output_bytes: int, input_bytes: int
) -> list[SyncManager]:
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


def process_fmmus(
    area: SlaveArea,
    sms: Sequence[SyncManager],
    logical_base: int,
    device: EsiDevice | None = None,
    segments: Sequence[SmSegment] = (),
) -> list[Fmmu]:
    """FMMUs mapping the slave's areas into the logical image: outputs first, then inputs
    (the FMMU numbers follow this order). With the layout's ``segments``, each SM segment —
    of a hardware SM or of a virtual one, whose FMMU maps the ESC memory at its start
    address — is mapped where it sits in the area, and segments adjacent both in the area and
    in the ESC memory share one FMMU (4 output SMs at 0x0F00..0x0F03 take one FMMU)."""
    if device is None or not segments:
        return _simple_fmmus(area, sms, logical_base)
    fmmus: list[Fmmu] = []
    for direction, base, access in (
        ("output", area.output_offset, fmmu_bits.WRITE),
        ("input", area.input_offset, fmmu_bits.READ),
    ):
        runs: list[list[int]] = []  # [logical start, length, physical start]
        for seg in sorted(
            (s for s in segments if s.direction == direction and s.byte_length),
            key=lambda s: s.byte_offset,
        ):
            desc = device.sm_number(seg.sm)
            if desc is None:
                raise BusError(f"slave {area.position} ({area.name}): no SyncManager {seg.sm}")
            logical = logical_base + base + seg.byte_offset
            if (
                runs
                and runs[-1][0] + runs[-1][1] == logical
                and (runs[-1][2] + runs[-1][1] == desc.start)
            ):
                runs[-1][1] += seg.byte_length
            else:
                runs.append([logical, seg.byte_length, desc.start])
        for logical, length, physical in runs:
            fmmus.append(Fmmu(len(fmmus), logical, length, physical, access))
    return fmmus


def _simple_fmmus(area: SlaveArea, sms: Sequence[SyncManager], logical_base: int) -> list[Fmmu]:
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
