"""Typed acyclic datagrams on top of the engine's ``transact``.

The engine sends one frame per ``transact`` call and returns each datagram's data and working
counter. This module gives the bring-up code named commands (``fprd``, ``apwr``, ...), packs a
batch of datagrams into as few frames as fit, and checks working counters where the caller says
how many slaves must answer. It is also the ``Datagrams`` transport the CoE mailbox runs over.
"""

from __future__ import annotations

import struct
from collections.abc import Sequence
from dataclasses import dataclass
from enum import IntEnum
from typing import Protocol

from ether_ros._native import protocol
from ether_ros._native.protocol import cmd, frame
from ether_ros.errors import (
    BusError,
    EtherRosError,
    FrameTimeout,
    LinkError,
    WorkingCounterError,
)

# Frame budget: the Ethernet payload minus the EtherCAT header; every datagram adds its header
# and a working counter to its data (the layout is the protocol crate's).
FRAME_PAYLOAD = frame.MAX_PAYLOAD - frame.ECAT_HEADER_LEN
DATAGRAM_OVERHEAD = frame.DATAGRAM_HEADER_LEN + frame.WKC_LEN
MAX_DATAGRAM_DATA = frame.MAX_DATAGRAM_DATA


class Cmd(IntEnum):
    """EtherCAT datagram command codes (ETG.1000.4), as the protocol crate has them."""

    NOP = cmd.NOP
    APRD = cmd.APRD
    APWR = cmd.APWR
    APRW = cmd.APRW
    FPRD = cmd.FPRD
    FPWR = cmd.FPWR
    FPRW = cmd.FPRW
    BRD = cmd.BRD
    BWR = cmd.BWR
    BRW = cmd.BRW
    LRD = cmd.LRD
    LWR = cmd.LWR
    LRW = cmd.LRW
    ARMW = cmd.ARMW
    FRMW = cmd.FRMW


def auto_address(position: int, offset: int) -> int:
    """Auto-increment address: ADP is minus the position (each slave increments it)."""
    return protocol.auto_increment_address(position & 0xFFFF, offset & 0xFFFF)


def fixed_address(station: int, offset: int) -> int:
    """Configured-station address: ADP is the station address, ADO the register."""
    return protocol.fixed_address(station & 0xFFFF, offset & 0xFFFF)


class Transport(Protocol):
    """What the master needs from the engine: one frame of datagrams out, replies back."""

    def transact(
        self,
        datagrams: Sequence[tuple[int, int, bytes | int]],
        timeout_us: int = ...,
        retries: int = ...,
    ) -> list[tuple[bytes, int]]: ...


@dataclass(frozen=True)
class Datagram:
    """One datagram to send: ``payload`` is the data to write, or the number of bytes to read."""

    cmd: Cmd
    address: int
    payload: bytes | int

    @property
    def length(self) -> int:
        return self.payload if isinstance(self.payload, int) else len(self.payload)


@dataclass(frozen=True)
class Reply:
    data: bytes
    wkc: int


def u16(value: int) -> bytes:
    return struct.pack("<H", value & 0xFFFF)


def u32(value: int) -> bytes:
    return struct.pack("<I", value & 0xFFFFFFFF)


def u64(value: int) -> bytes:
    return struct.pack("<Q", value & 0xFFFFFFFFFFFFFFFF)


def le(data: bytes) -> int:
    """Little-endian unsigned integer from register bytes."""
    return int.from_bytes(data, "little")


class DatagramService:
    """Named datagrams, batching and working-counter checks over a :class:`Transport`.

    Reads return ``(data, wkc)``, writes return ``wkc`` — the shape the CoE mailbox expects from
    its ``Datagrams`` transport (``fprd``/``fpwr``).
    """

    def __init__(self, transport: Transport, timeout_us: int = 20_000, retries: int = 3) -> None:
        self.transport = transport
        self.timeout_us = timeout_us
        self.retries = retries

    # -- frames ----------------------------------------------------------------------------
    def batch(self, datagrams: Sequence[Datagram]) -> list[Reply]:
        """Send datagrams in order, as few frames as they fit in; replies in the same order."""
        replies: list[Reply] = []
        frame: list[Datagram] = []
        used = 0
        for dg in datagrams:
            size = dg.length + DATAGRAM_OVERHEAD
            if dg.length > MAX_DATAGRAM_DATA:
                raise BusError(f"{dg.cmd.name} of {dg.length} bytes does not fit in one frame")
            if frame and used + size > FRAME_PAYLOAD:
                replies.extend(self._send(frame))
                frame, used = [], 0
            frame.append(dg)
            used += size
        if frame:
            replies.extend(self._send(frame))
        return replies

    def _send(self, frame: Sequence[Datagram]) -> list[Reply]:
        request = [(int(d.cmd), d.address, d.payload) for d in frame]
        try:
            raw = self.transport.transact(request, timeout_us=self.timeout_us, retries=self.retries)
        except EtherRosError:
            raise
        except TimeoutError as exc:
            names = tuple(d.cmd.name for d in frame)
            err = FrameTimeout(
                f"no answer to a frame ({', '.join(names)}) after {self.retries} retries"
            )
            err.commands, err.attempts, err.timeout_us = names, self.retries + 1, self.timeout_us
            raise err from exc
        except OSError as exc:
            raise LinkError(f"sending a frame failed: {exc}") from exc
        return [Reply(bytes(data), int(wkc)) for data, wkc in raw]

    def one(self, cmd: Cmd, address: int, payload: bytes | int) -> Reply:
        return self.batch([Datagram(cmd, address, payload)])[0]

    # -- named commands (the ``Datagrams`` protocol of the mailbox) --------------------------
    def fprd(self, station: int, ado: int, length: int) -> tuple[bytes, int]:
        r = self.one(Cmd.FPRD, fixed_address(station, ado), length)
        return r.data, r.wkc

    def fpwr(self, station: int, ado: int, data: bytes) -> int:
        return self.one(Cmd.FPWR, fixed_address(station, ado), bytes(data)).wkc

    def aprd(self, position: int, ado: int, length: int) -> tuple[bytes, int]:
        r = self.one(Cmd.APRD, auto_address(position, ado), length)
        return r.data, r.wkc

    def apwr(self, position: int, ado: int, data: bytes) -> int:
        return self.one(Cmd.APWR, auto_address(position, ado), bytes(data)).wkc

    def brd(self, ado: int, length: int) -> tuple[bytes, int]:
        r = self.one(Cmd.BRD, fixed_address(0, ado), length)
        return r.data, r.wkc

    def bwr(self, ado: int, data: bytes) -> int:
        return self.one(Cmd.BWR, fixed_address(0, ado), bytes(data)).wkc

    def frmw(self, station: int, ado: int, length: int) -> tuple[bytes, int]:
        r = self.one(Cmd.FRMW, fixed_address(station, ado), length)
        return r.data, r.wkc

    def lrw(self, logical: int, data: bytes) -> tuple[bytes, int]:
        r = self.one(Cmd.LRW, logical, bytes(data))
        return r.data, r.wkc

    def lrd(self, logical: int, length: int) -> tuple[bytes, int]:
        r = self.one(Cmd.LRD, logical, length)
        return r.data, r.wkc

    def lwr(self, logical: int, data: bytes) -> int:
        return self.one(Cmd.LWR, logical, bytes(data)).wkc

    # -- checked helpers ---------------------------------------------------------------------
    def write_checked(self, station: int, ado: int, data: bytes, what: str, who: str) -> None:
        """FPWR that must reach exactly one slave; ``what``/``who`` name it in the error."""
        wkc = self.fpwr(station, ado, data)
        if wkc != 1:
            raise WorkingCounterError(f"writing {what} (0x{ado:04X})", 1, wkc, slave=who)

    def read_checked(self, station: int, ado: int, length: int, what: str, who: str) -> bytes:
        data, wkc = self.fprd(station, ado, length)
        if wkc != 1:
            raise WorkingCounterError(f"reading {what} (0x{ado:04X})", 1, wkc, slave=who)
        return data
