"""Reading the slaves' SII EEPROM through the ESC's EEPROM interface (0x0500..0x050F).

The master takes the EEPROM from the PDI (0x0500 = 2, "force ECAT access", which resets the
PDI's access bit 0x0501.0; then 0x0500 = 0), then for each read writes the word
address (0x0504) and the read command (0x0502 = 0x0100), polls until the busy bit (15) clears and
takes 4 or 8 bytes from 0x0508 (bit 6 of 0x0502 says which). All slaves are read at the same time,
one datagram each per frame, and each stops at the end marker of its category list (decoded by
``ether_ros.config.sii.parse_sii``), so a scan
costs about two round trips per 8 bytes of the longest EEPROM. Afterwards the EEPROM is
offered back to the PDI (0x0500 = 1), as SOEM does: a slave application that keeps its own
data there may use it again (ESC datasheet, 0x0500/0x0501 "EEPROM access").
"""

from __future__ import annotations

import struct
import time
from collections.abc import Sequence

from ether_ros.errors import BusError
from ether_ros.master.datagrams import Cmd, Datagram, DatagramService, fixed_address, u16, u32

SII_CONFIG = 0x0500
# 0x0500 bits: 0 EEPROM control offered to the PDI, 1 force ECAT access (resets 0x0501.0).
EEPROM_TO_PDI = 0x01
FORCE_ECAT_ACCESS = 0x02
SII_CONTROL = 0x0502
SII_ADDRESS = 0x0504
SII_DATA = 0x0508

READ_COMMAND = 0x0100
BUSY = 0x8000
READ_8_BYTES = 0x0040
ERROR_BITS = 0x6000  # bit 13 checksum error, bit 14 error command
ERROR_ACK_NACK = 0x2000

FIRST_CATEGORY_WORD = 0x40
CATEGORY_END = 0xFFFF
MAX_SII_BYTES = 64 * 1024


def sii_complete(image: bytes) -> bool:
    """True once ``image`` holds the whole category list up to its end marker."""
    word = FIRST_CATEGORY_WORD
    while True:
        pos = 2 * word
        if pos + 2 > len(image):
            return False
        (kind,) = struct.unpack_from("<H", image, pos)
        if kind == CATEGORY_END:
            return True
        if pos + 4 > len(image):
            return False
        (size,) = struct.unpack_from("<H", image, pos + 2)
        word += 2 + size
        if 2 * word > MAX_SII_BYTES:
            return True  # a broken list: stop here and let the parser complain


def _who(names: Sequence[str], i: int) -> str:
    return names[i] if names else f"slave #{i}"


def read_sii(
    dg: DatagramService,
    stations: Sequence[int],
    names: Sequence[str] = (),
    timeout_s: float = 1.0,
) -> list[bytes]:
    """The SII images of the slaves at ``stations`` (each up to its category end marker)."""
    n = len(stations)
    if n == 0:
        return []
    take = dg.batch(
        [
            Datagram(Cmd.FPWR, fixed_address(s, SII_CONFIG), bytes([FORCE_ECAT_ACCESS]))
            for s in stations
        ]
        + [Datagram(Cmd.FPWR, fixed_address(s, SII_CONFIG), b"\0") for s in stations]
        + [Datagram(Cmd.FPRD, fixed_address(s, SII_CONTROL), 2) for s in stations]
    )
    for i, reply in enumerate(take[2 * n :]):
        if reply.wkc != 1:
            raise BusError(f"{_who(names, i)}: no answer from the SII EEPROM interface")
        if struct.unpack("<H", reply.data)[0] & ERROR_BITS:
            # Clear a stale error from before (e.g. a read interrupted by a reset).
            dg.fpwr(stations[i], SII_CONTROL, u16(0))
    images = [bytearray() for _ in stations]
    active = list(range(n))
    while active:
        words = {i: len(images[i]) // 2 for i in active}
        requests: list[Datagram] = []
        for i in active:
            requests.append(
                Datagram(Cmd.FPWR, fixed_address(stations[i], SII_ADDRESS), u32(words[i]))
            )
            requests.append(
                Datagram(Cmd.FPWR, fixed_address(stations[i], SII_CONTROL), u16(READ_COMMAND))
            )
        for k, reply in enumerate(dg.batch(requests)):
            if reply.wkc != 1:
                raise BusError(f"{_who(names, active[k // 2])}: SII read command not accepted")
        pending = list(active)
        deadline = time.monotonic() + timeout_s
        while pending:
            replies = dg.batch(
                [Datagram(Cmd.FPRD, fixed_address(stations[i], SII_CONTROL), 14) for i in pending]
            )
            still: list[int] = []
            for i, reply in zip(pending, replies, strict=True):
                if reply.wkc != 1:
                    raise BusError(f"{_who(names, i)}: no answer while reading the SII")
                (control,) = struct.unpack_from("<H", reply.data)
                if control & BUSY:
                    still.append(i)
                    continue
                if control & ERROR_BITS:
                    raise BusError(
                        f"{_who(names, i)}: SII read at word 0x{words[i]:04X} failed "
                        f"(EEPROM control 0x{control:04X})"
                    )
                size = 8 if control & READ_8_BYTES else 4
                images[i].extend(reply.data[6 : 6 + size])
            if still and time.monotonic() > deadline:
                raise BusError(f"{_who(names, still[0])}: SII EEPROM stays busy")
            pending = still
        done: list[int] = []
        for i in active:
            img = bytes(images[i])
            if len(img) >= 2 * FIRST_CATEGORY_WORD and (
                sii_complete(img) or len(img) >= MAX_SII_BYTES
            ):
                done.append(i)
        active = [i for i in active if i not in done]
    dg.batch(
        [Datagram(Cmd.FPWR, fixed_address(s, SII_CONFIG), bytes([EEPROM_TO_PDI])) for s in stations]
    )
    return [bytes(img) for img in images]
