"""The EtherCAT mailbox of one slave over acyclic datagrams (ETG.1000.4/.6).

The master writes a request into the slave's write mailbox (SyncManager 0) and polls the read
mailbox (SyncManager 1) for the answer. Every message starts with a 6-byte mailbox header:
length (u16, bytes after the header), address (u16), channel/priority (u8) and type/counter (u8:
bits 0..=3 type, bits 4..=6 counter 1..7). A SyncManager in mailbox mode accepts a write only
when it is empty and signals a full buffer in bit 3 of its status register, so the master always
writes and reads the whole configured mailbox length: the last byte hands the buffer over.
"""

from __future__ import annotations

import struct
import time
from collections.abc import Callable
from enum import IntEnum
from typing import Protocol

from ether_ros._native.protocol import (
    coe,
    mailbox,
    mailbox_header,
    mailbox_type_name,
    parse_mailbox_header,
    sm,
)
from ether_ros._native.protocol import reg as registers
from ether_ros.errors import MailboxError, MailboxErrorReply, MailboxTimeout

MAILBOX_HEADER_LEN = mailbox.HEADER_LEN

# The mailbox SyncManagers' registers: SM0 is the write mailbox (master -> slave), SM1 the read
# mailbox. SM1's activate register carries the master's repeat request, its PDI control
# register the slave's repeat acknowledge.
SM0_STATUS = registers.SM0 + sm.STATUS
SM1_STATUS = registers.SM0 + registers.SM_LEN + sm.STATUS
SM1_ACTIVATE = registers.SM0 + registers.SM_LEN + sm.ACTIVATE
SM1_PDI_CONTROL = registers.SM0 + registers.SM_LEN + sm.PDI_CONTROL


class MailboxType(IntEnum):
    ERROR = mailbox.TYPE_ERR
    AOE = mailbox.TYPE_AOE
    EOE = mailbox.TYPE_EOE
    COE = mailbox.TYPE_COE
    FOE = mailbox.TYPE_FOE
    SOE = mailbox.TYPE_SOE
    VOE = mailbox.TYPE_VOE


class Datagrams(Protocol):
    """The two datagrams the mailbox needs; ``ether_ros.master.datagrams.DatagramService``
    implements them."""

    def fprd(self, station: int, ado: int, length: int) -> tuple[bytes, int]: ...  # (data, wkc)

    def fpwr(self, station: int, ado: int, data: bytes) -> int: ...  # wkc


class Mailbox:
    """Send and receive mailbox messages of one slave.

    Emergency messages (CoE service 1) can arrive at any time; they are handed to
    ``emergency_handler`` (the CoE payload, starting with the CoE header) and never end a wait.
    A message of another type that nobody waits for goes to ``message_handler`` (type, payload;
    it returns whether it took it), else it is counted in ``discarded``.
    """

    def __init__(
        self,
        dg: Datagrams,
        station: int,
        slave_name: str,
        rx_offset: int,
        rx_size: int,
        tx_offset: int,
        tx_size: int,
    ) -> None:
        if rx_size <= MAILBOX_HEADER_LEN or tx_size <= MAILBOX_HEADER_LEN:
            raise MailboxError(
                f"mailbox too small (write {rx_size} bytes, read {tx_size} bytes; both must "
                f"exceed the {MAILBOX_HEADER_LEN}-byte header)",
                slave=slave_name,
            )
        self.dg = dg
        self.station = station
        self.slave_name = slave_name
        self.rx_offset = rx_offset  # write mailbox (master -> slave), SM0
        self.rx_size = rx_size
        self.tx_offset = tx_offset  # read mailbox (slave -> master), SM1
        self.tx_size = tx_size
        self._counter: int | None = None
        self.emergency_handler: Callable[[bytes], None] | None = None
        self.message_handler: Callable[[int, bytes], bool] | None = None
        # Messages of other types that arrived while waiting for something else.
        self.discarded = 0
        # Repeat requests sent because a read mailbox answer got lost.
        self.repeats = 0

    @property
    def max_send_payload(self) -> int:
        """Largest payload one message to the slave can carry."""
        return self.rx_size - MAILBOX_HEADER_LEN

    @property
    def max_receive_payload(self) -> int:
        return self.tx_size - MAILBOX_HEADER_LEN

    def _next_counter(self) -> int:
        # Slaves drop a message whose counter equals the previous one (a retried write). A new
        # Mailbox cannot know the counter another master process used last, so its first message
        # carries 0, which slaves never treat as a repeat; after that 1..7 cycling.
        if self._counter is None:
            self._counter = 0
        else:
            self._counter = self._counter % 7 + 1
        return self._counter

    @staticmethod
    def _sleep(attempt: int) -> None:
        # Poll at once a few times (an in-process simulator answers immediately), then back off
        # to at most 1 ms so a slow slave does not cost a busy loop.
        if attempt > 3:
            time.sleep(min(0.001, 0.00005 * (1 << min(attempt - 4, 5))))

    def send(self, mbx_type: int, payload: bytes, timeout_s: float) -> None:
        if len(payload) > self.max_send_payload:
            raise MailboxError(
                f"mailbox message of {len(payload)} bytes exceeds the write mailbox "
                f"({self.max_send_payload} bytes of data)",
                slave=self.slave_name,
            )
        header = mailbox_header(len(payload), mbx_type, self._next_counter())
        message = (header + payload).ljust(self.rx_size, b"\x00")
        deadline = time.monotonic() + timeout_s
        attempt = 0
        while True:
            status, wkc = self.dg.fprd(self.station, SM0_STATUS, 1)
            # A full mailbox (or a lost frame) leaves the write unacknowledged: retry.
            empty = wkc == 1 and status and not status[0] & sm.STATUS_MAILBOX_FULL
            if empty and self.dg.fpwr(self.station, self.rx_offset, message) == 1:
                return
            if time.monotonic() >= deadline:
                raise MailboxTimeout(
                    self.slave_name,
                    timeout_s,
                    "the write mailbox to accept a message (it stays full)",
                )
            attempt += 1
            self._sleep(attempt)

    def receive(self, mbx_type: int, timeout_s: float) -> bytes:
        """The payload of the next message of ``mbx_type`` (without the mailbox header)."""
        deadline = time.monotonic() + timeout_s
        attempt = 0
        while True:
            message = self._poll()
            if message is not None:
                got_type, payload = message
                if got_type == mbx_type and not self._is_emergency(got_type, payload):
                    return payload
                self._dispatch(got_type, payload)
                attempt = 0
            elif time.monotonic() >= deadline:
                raise MailboxTimeout(
                    self.slave_name,
                    timeout_s,
                    f"a {_type_name(mbx_type)} reply in the read mailbox",
                )
            else:
                attempt += 1
                self._sleep(attempt)

    def flush(self, limit: int = 16) -> int:
        """Empty the read mailbox before a new request, so a late reply to an earlier request
        that timed out cannot be taken for the new answer. Emergencies are dispatched; anything
        else is dropped. Returns the number of dropped messages."""
        dropped = 0
        for _ in range(limit):
            message = self._poll()
            if message is None:
                break
            mbx_type, payload = message
            if self._is_emergency(mbx_type, payload) and self.emergency_handler is not None:
                self.emergency_handler(payload)
            else:
                dropped += 1
                self.discarded += 1
        return dropped

    def poll_emergencies(self) -> None:
        """Read whatever the slave has put into its read mailbox and dispatch it."""
        while (message := self._poll()) is not None:
            self._dispatch(*message)

    def _poll(self) -> tuple[int, bytes] | None:
        status, wkc = self.dg.fprd(self.station, SM1_STATUS, 1)
        if wkc != 1 or not status or not status[0] & sm.STATUS_MAILBOX_FULL:
            return None
        data, wkc = self.dg.fprd(self.station, self.tx_offset, self.tx_size)
        if wkc != 1:
            # The mailbox was full a moment ago and nobody else reads it: our read reached the
            # slave (which emptied the mailbox) but the answer got lost. Ask for the message again.
            self._request_repeat()
            return None
        header = parse_mailbox_header(data)
        if header is None:
            return None
        length, _address, _channel, mbx_type, _counter = header
        if length > len(data) - MAILBOX_HEADER_LEN:
            raise MailboxError(
                f"read mailbox message says {length} bytes but the mailbox holds only "
                f"{len(data) - MAILBOX_HEADER_LEN}",
                slave=self.slave_name,
            )
        return mbx_type, data[MAILBOX_HEADER_LEN : MAILBOX_HEADER_LEN + length]

    def _request_repeat(self) -> None:
        """Repeat request (ETG.1000.4): toggle the repeat bit of SM1's activate register; the
        slave puts its last message into the read mailbox again and toggles its repeat
        acknowledge to match. The caller's poll loop then finds the mailbox full again."""
        activate, wkc = self.dg.fprd(self.station, SM1_ACTIVATE, 1)
        if wkc != 1 or not activate:
            return
        wanted = (activate[0] ^ sm.REPEAT) & sm.REPEAT
        if self.dg.fpwr(self.station, SM1_ACTIVATE, bytes([activate[0] ^ sm.REPEAT])) != 1:
            return
        self.repeats += 1
        for attempt in range(20):
            ack, wkc = self.dg.fprd(self.station, SM1_PDI_CONTROL, 1)
            if wkc == 1 and ack and ack[0] & sm.REPEAT == wanted:
                return
            self._sleep(attempt)

    @staticmethod
    def _is_emergency(mbx_type: int, payload: bytes) -> bool:
        return (
            mbx_type == MailboxType.COE
            and len(payload) >= 2
            and payload[1] >> 4 == coe.SERVICE_EMERGENCY
        )

    def _dispatch(self, mbx_type: int, payload: bytes) -> None:
        if mbx_type == MailboxType.ERROR:
            code = struct.unpack_from("<H", payload, 2)[0] if len(payload) >= 4 else 0
            raise MailboxErrorReply(self.slave_name, code)
        if self._is_emergency(mbx_type, payload):
            if self.emergency_handler is not None:
                self.emergency_handler(payload)
                return
        elif self.message_handler is not None and self.message_handler(mbx_type, payload):
            return
        self.discarded += 1


def _type_name(mbx_type: int) -> str:
    return mailbox_type_name(mbx_type) or f"type {mbx_type}"
