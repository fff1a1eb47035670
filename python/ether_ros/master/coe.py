"""CoE SDO client (ETG.1000.6): read and write object dictionary entries of one slave through its
mailbox, collect emergency messages, and browse the dictionary with the SDO Information service.

The transfer type is chosen from the data size: up to 4 bytes expedited, otherwise normal, and
segmented when the data does not fit into one mailbox message. A slave's abort is raised as
``SdoAbort`` carrying the slave, the object and the abort code (its text from the protocol
crate); a missing answer as ``MailboxTimeout``: callers decide by the class and the data.
"""

from __future__ import annotations

import contextlib
import struct
from collections import deque
from dataclasses import dataclass

from ether_ros._native.protocol import (
    coe,
    coe_header,
    emergency_text,
    format_address,
    object_code_name,
    parse_sdo_header,
    parse_sdo_segment,
    sdo_abort,
    sdo_abort_message,
    sdo_expedited,
    sdo_initiate,
    sdo_segment,
    sdo_toggle_message,
)
from ether_ros.errors import MailboxError, SdoAbort
from ether_ros.master.mailbox import Mailbox, MailboxType

# A segment: CoE header (2), command (1), then at least 7 data bytes; the codec is the protocol
# crate's (``coe::Segment``), the one the simulator's SDO server uses.
SEGMENT_HEADER_LEN = coe.SEGMENT_HEADER_LEN
MIN_SEGMENT_DATA = coe.MIN_SEGMENT_DATA


@dataclass(frozen=True)
class Emergency:
    """One CoE emergency message from a slave."""

    slave: str
    error_code: int
    error_register: int
    data: bytes

    @property
    def text(self) -> str:
        return (
            f"slave '{self.slave}': emergency 0x{self.error_code:04X} "
            f"{emergency_text(self.error_code)} (error register 0x{self.error_register:02X}, "
            f"data {self.data.hex(' ')})"
        )


@dataclass(frozen=True)
class ObjectDescription:
    index: int
    data_type: int
    max_subindex: int
    object_code: int
    name: str

    @property
    def object_code_name(self) -> str:
        return object_code_name(self.object_code) or f"code {self.object_code}"


@dataclass(frozen=True)
class EntryDescription:
    index: int
    subindex: int
    value_info: int
    data_type: int
    bit_length: int
    access: int
    name: str
    # Whatever the slave appended because value_info asked for unit, default, minimum, maximum.
    extra: bytes = b""

    @property
    def readable(self) -> bool:
        return bool(self.access & coe.ACCESS_READ)

    @property
    def writable(self) -> bool:
        return bool(self.access & coe.ACCESS_WRITE)

    @property
    def rx_mappable(self) -> bool:
        return bool(self.access & coe.ACCESS_RXPDO)

    @property
    def tx_mappable(self) -> bool:
        return bool(self.access & coe.ACCESS_TXPDO)

    @property
    def access_text(self) -> str:
        """ESI-style access: ro, rw, wo, or per state like ``rw(PREOP) ro``."""
        read, write = self.access & coe.ACCESS_READ, (self.access & coe.ACCESS_WRITE) >> 3
        if write == 0:
            return "ro" if read else "none"
        if write == coe.ACCESS_READ:  # written in all three states
            return "rw" if read == coe.ACCESS_READ else "wo"
        states = "/".join(n for bit, n in ((1, "PREOP"), (2, "SAFEOP"), (4, "OP")) if write & bit)
        return f"rw({states}) ro" if read else f"wo({states})"


def _service(payload: bytes) -> int:
    return payload[1] >> 4 if len(payload) >= 2 else -1


class SdoClient:
    """SDO transfers with one slave. Not thread safe: one transfer at a time per slave."""

    def __init__(self, mailbox: Mailbox, slave_name: str, timeout_s: float = 1.0) -> None:
        self.mailbox = mailbox
        self.slave_name = slave_name
        self.timeout_s = timeout_s
        self.emergencies: deque[Emergency] = deque(maxlen=1000)
        mailbox.emergency_handler = self._on_emergency

    # ---- emergencies ----------------------------------------------------------------------

    def _on_emergency(self, payload: bytes) -> None:
        self.record_emergency(payload)

    def record_emergency(self, payload: bytes) -> Emergency | None:
        """Keep the emergency of ``payload`` (the CoE payload, from the CoE header on) among
        the collected ones and return it (None: too short to be one)."""
        if len(payload) < 5:
            return None
        code, register = struct.unpack_from("<HB", payload, 2)
        em = Emergency(self.slave_name, code, register, payload[5:10])
        self.emergencies.append(em)
        return em

    def take_emergencies(self) -> list[Emergency]:
        """Return and forget the collected emergencies (no mailbox read)."""
        out = list(self.emergencies)
        self.emergencies.clear()
        return out

    def poll_emergencies(self) -> list[Emergency]:
        """Read pending mailbox messages, then return and forget the collected emergencies."""
        self.mailbox.poll_emergencies()
        return self.take_emergencies()

    # ---- helpers ----------------------------------------------------------------------------

    @staticmethod
    def _what(action: str, index: int, subindex: int, complete_access: bool) -> str:
        ca = " (complete access)" if complete_access else ""
        return f"SDO {action} {format_address(index, subindex)}{ca}"

    def _fail(self, what: str, reason: str) -> MailboxError:
        return MailboxError(reason, slave=self.slave_name, context=what)

    def _exchange(self, request: bytes, what: str, index: int, subindex: int) -> bytes:
        try:
            self.mailbox.send(MailboxType.COE, request, self.timeout_s)
            reply = self.mailbox.receive(MailboxType.COE, self.timeout_s)
        except MailboxError as e:
            raise e.in_context(what) from None
        header = parse_sdo_header(reply)
        if header is not None and header[1] == coe.CS_ABORT:
            raise SdoAbort(self.slave_name, index, subindex, header[6], context=what)
        if _service(reply) != coe.SERVICE_SDO_RESPONSE or len(reply) < coe.SDO_HEADER_LEN:
            raise self._fail(what, f"unexpected CoE reply {reply[:10].hex(' ')}")
        return reply

    def _abort(self, index: int, subindex: int, code: int) -> None:
        """Tell the slave the transfer is over; best effort, the caller raises anyway."""
        with contextlib.suppress(MailboxError):
            self.mailbox.send(
                MailboxType.COE,
                sdo_abort_message(coe.SERVICE_SDO_REQUEST, index, subindex, code),
                0.1,
            )

    def _check_echo(self, reply: bytes, scs: int, index: int, subindex: int, what: str) -> None:
        header = parse_sdo_header(reply)
        assert header is not None  # _exchange checked the length
        _service, specifier, _ca, got_index, got_sub, _data, _word = header
        if specifier != scs or (got_index, got_sub) != (index, subindex):
            self._abort(index, subindex, sdo_abort.ABORT_INVALID_COMMAND)
            raise self._fail(
                what,
                f"slave answered command 0x{reply[2]:02X} for {format_address(got_index, got_sub)}",
            )

    # ---- upload -----------------------------------------------------------------------------

    def upload(self, index: int, subindex: int, complete_access: bool = False) -> bytes:
        """Read an entry (or, with complete access, the whole object from ``subindex`` 0 or 1)."""
        what = self._what("upload", index, subindex, complete_access)
        self.mailbox.flush()
        request = sdo_initiate(
            coe.SERVICE_SDO_REQUEST, coe.CCS_UPLOAD_INITIATE, index, subindex, complete_access
        )
        reply = self._exchange(request, what, index, subindex)
        self._check_echo(reply, coe.SCS_UPLOAD_INITIATE, index, subindex, what)
        header = parse_sdo_header(reply)
        assert header is not None  # _exchange checked the length
        expedited, size = header[5], header[6]
        if expedited is not None:  # the data is in the 4 data bytes
            return expedited
        data = bytearray(reply[coe.SDO_HEADER_LEN : coe.SDO_HEADER_LEN + size])
        toggle = False
        while len(data) < size:
            request = sdo_toggle_message(coe.SERVICE_SDO_REQUEST, coe.CCS_UPLOAD_SEGMENT, toggle)
            segment = self._exchange(request, what, index, subindex)
            decoded = parse_sdo_segment(segment)
            if decoded is None or decoded[1] != coe.SCS_UPLOAD_SEGMENT:
                self._abort(index, subindex, sdo_abort.ABORT_INVALID_COMMAND)
                got = f"0x{segment[2]:02X}" if len(segment) > 2 else f"{len(segment)} bytes"
                raise self._fail(what, f"expected an upload segment, got {got}")
            _service, _specifier, seg_toggle, last, body = decoded
            if seg_toggle != toggle:
                self._abort(index, subindex, sdo_abort.ABORT_TOGGLE_BIT)
                raise self._fail(what, "slave did not alternate the toggle bit")
            data += body
            if last or not body:
                break
            toggle = not toggle
        if len(data) != size:
            raise self._fail(what, f"slave announced {size} bytes but sent {len(data)}")
        return bytes(data)

    # ---- download ---------------------------------------------------------------------------

    def download(
        self, index: int, subindex: int, data: bytes, complete_access: bool = False
    ) -> None:
        """Write an entry (or, with complete access, the object from ``subindex`` 0 or 1)."""
        what = self._what("download", index, subindex, complete_access)
        self.mailbox.flush()
        if 0 < len(data) <= 4:
            request = sdo_expedited(
                coe.SERVICE_SDO_REQUEST,
                coe.CCS_DOWNLOAD_INITIATE,
                index,
                subindex,
                data,
                complete_access,
            )
            reply = self._exchange(request, what, index, subindex)
            self._check_echo(reply, coe.SCS_DOWNLOAD_INITIATE, index, subindex, what)
            return
        room = self.mailbox.max_send_payload - coe.SDO_HEADER_LEN
        first = data[:room]
        request = (
            sdo_initiate(
                coe.SERVICE_SDO_REQUEST,
                coe.CCS_DOWNLOAD_INITIATE,
                index,
                subindex,
                complete_access,
                len(data),
            )
            + first
        )
        reply = self._exchange(request, what, index, subindex)
        self._check_echo(reply, coe.SCS_DOWNLOAD_INITIATE, index, subindex, what)
        sent = len(first)
        toggle = False
        segment_room = self.mailbox.max_send_payload - SEGMENT_HEADER_LEN
        while sent < len(data):
            chunk = data[sent : sent + segment_room]
            sent += len(chunk)
            segment = sdo_segment(
                coe.SERVICE_SDO_REQUEST,
                coe.CCS_DOWNLOAD_SEGMENT,
                toggle,
                sent == len(data),
                chunk,
            )
            reply = self._exchange(segment, what, index, subindex)
            answer = parse_sdo_segment(reply)
            if answer is None or answer[1] != coe.SCS_DOWNLOAD_SEGMENT:
                self._abort(index, subindex, sdo_abort.ABORT_INVALID_COMMAND)
                raise self._fail(what, f"expected a segment answer, got 0x{reply[2]:02X}")
            if answer[2] != toggle:
                self._abort(index, subindex, sdo_abort.ABORT_TOGGLE_BIT)
                raise self._fail(what, "slave did not alternate the toggle bit")
            toggle = not toggle

    # ---- SDO Information --------------------------------------------------------------------

    def _info(
        self, opcode: int, body: bytes, expect: int, what: str, index: int = 0, subindex: int = 0
    ) -> bytes:
        """One SDO Information exchange; the fragments of the answer put together. ``index``
        and ``subindex`` name the object an abort is about."""
        request = coe_header(coe.SERVICE_SDO_INFORMATION) + bytes([opcode, 0, 0, 0]) + body
        self.mailbox.flush()
        try:
            self.mailbox.send(MailboxType.COE, request, self.timeout_s)
        except MailboxError as e:
            raise e.in_context(what) from None
        data = bytearray()
        while True:
            try:
                reply = self.mailbox.receive(MailboxType.COE, self.timeout_s)
            except MailboxError as e:
                raise e.in_context(what) from None
            if _service(reply) != coe.SERVICE_SDO_INFORMATION or len(reply) < coe.INFO_HEADER_LEN:
                # An SDO abort in answer to an information request: the service is missing.
                header = parse_sdo_header(reply)
                if header is not None and header[1] == coe.CS_ABORT:
                    raise SdoAbort(
                        self.slave_name, index, subindex, header[6], context=what, verb="failed"
                    )
                raise self._fail(what, f"unexpected CoE reply {reply[:10].hex(' ')}")
            got = reply[2] & coe.INFO_OPCODE_MASK
            if got == coe.INFO_ERROR:
                code = struct.unpack_from("<I", reply.ljust(10, b"\x00"), 6)[0]
                raise SdoAbort(self.slave_name, index, subindex, code, context=what, verb="failed")
            if got != expect:
                raise self._fail(what, f"unexpected SDO information opcode {got}")
            data += reply[coe.INFO_HEADER_LEN :]
            fragments_left = struct.unpack_from("<H", reply, 4)[0]
            if not reply[2] & coe.INFO_INCOMPLETE or fragments_left == 0:
                return bytes(data)

    def object_list(self, list_type: int = coe.OD_LIST_ALL) -> list[int]:
        """Indices of the objects in the dictionary (list type 1: all; 2/3: RxPDO/TxPDO
        mappable; 4: backup; 5: settings). List type 0 returns the five list lengths."""
        what = "SDO information object list"
        body = self._info(
            coe.INFO_OD_LIST_REQ, struct.pack("<H", list_type), coe.INFO_OD_LIST_RESP, what
        )
        if len(body) < 2 or len(body) % 2:
            raise self._fail(what, f"malformed list of {len(body)} bytes")
        return [v for (v,) in struct.iter_unpack("<H", body[2:])]

    def object_description(self, index: int) -> ObjectDescription:
        what = f"SDO information object description 0x{index:04X}"
        body = self._info(
            coe.INFO_OBJECT_DESC_REQ, struct.pack("<H", index), coe.INFO_OBJECT_DESC_RESP, what,
            index,
        )  # fmt: skip
        if len(body) < 6:
            raise self._fail(what, f"description of {len(body)} bytes is too short")
        got_index, data_type, max_sub, code = struct.unpack_from("<HHBB", body)
        return ObjectDescription(got_index, data_type, max_sub, code, _text(body[6:]))

    def entry_description(self, index: int, subindex: int) -> EntryDescription:
        what = f"SDO information entry description {format_address(index, subindex)}"
        body = self._info(
            coe.INFO_ENTRY_DESC_REQ,
            struct.pack("<HBB", index, subindex, 0),
            coe.INFO_ENTRY_DESC_RESP,
            what,
            index,
            subindex,
        )
        if len(body) < 10:
            raise self._fail(what, f"description of {len(body)} bytes is too short")
        got_index, got_sub, value_info, data_type, bits, access = struct.unpack_from(
            "<HBBHHH", body
        )
        # We ask for no unit/default/min/max, so everything after the header is the name.
        return EntryDescription(
            got_index, got_sub, value_info, data_type, bits, access, _text(body[10:])
        )


def _text(raw: bytes) -> str:
    return raw.split(b"\x00", 1)[0].decode("utf-8", errors="replace")
