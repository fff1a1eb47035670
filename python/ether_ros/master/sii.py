"""Reading the slaves' SII EEPROM through the ESC's EEPROM interface (0x0500..0x050F).

The master takes the EEPROM from the PDI (0x0500 = 2, "force ECAT access", which resets the
PDI's access bit 0x0501.0; then 0x0500 = 0), then for each read writes the word
address (0x0504) and the read command (0x0502 = 0x0100), polls until the busy bit (15) clears and
takes 4 or 8 bytes from 0x0508 (bit 6 of 0x0502 says which). A read failed when the EEPROM did
not acknowledge or the command was refused (bits 13 and 14). Bit 11 is the ESC's checksum error
of the configuration area (words 0..6): the EEPROM still reads, but the ESC did not load those
words, so the slave runs without its configured PDI and alias settings: the master says so once.
The register's bits are the protocol crate's (``ether_ros._native.protocol.sii``).

All slaves are read at the same time, one datagram each per frame, and each stops at the end
marker of its category list (decoded by ``ether_ros.config.sii.parse_sii``), so a scan costs
about two round trips per 8 bytes of the longest EEPROM. Afterwards the EEPROM is offered back
to the PDI (0x0500 = 1), as SOEM does: a slave application that keeps its own data there may
use it again (ESC datasheet, 0x0500/0x0501 "EEPROM access").
"""

from __future__ import annotations

import logging
import struct
import time
from collections.abc import Sequence

from ether_ros._native.protocol import reg, sii, sii_list_complete, sii_word
from ether_ros.errors import BusError, SiiReadError
from ether_ros.master.datagrams import Cmd, Datagram, DatagramService, fixed_address, u16, u32

log = logging.getLogger(__name__)

# 0x0500: take the EEPROM from the PDI at once, and offer it back.
FORCE_ECAT_ACCESS = bytes([sii.CONFIG_RESET_PDI_ACCESS])
TO_PDI = bytes([sii.CONFIG_PDI])

MAX_SII_BYTES = 64 * 1024


def sii_complete(image: bytes) -> bool:
    """True once ``image`` holds the whole category list up to its end marker (or a broken
    list runs past :data:`MAX_SII_BYTES`: the reader stops there and the parser complains).
    The walk is the protocol crate's (``sii::list_complete``)."""
    return sii_list_complete(image, MAX_SII_BYTES)


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
        [Datagram(Cmd.FPWR, fixed_address(s, reg.SII_CONFIG), FORCE_ECAT_ACCESS) for s in stations]
        + [Datagram(Cmd.FPWR, fixed_address(s, reg.SII_CONFIG), b"\0") for s in stations]
        + [Datagram(Cmd.FPRD, fixed_address(s, reg.SII_CONTROL), 2) for s in stations]
    )
    for i, reply in enumerate(take[2 * n :]):
        if reply.wkc != 1:
            raise BusError(f"{_who(names, i)}: no answer from the SII EEPROM interface")
        status = struct.unpack("<H", reply.data)[0]
        if status & sii.CHECKSUM_ERROR:
            log.warning(
                "%s: the ESC reports a checksum error in the SII configuration area (words "
                "0..6): it did not load them and runs with its defaults",
                _who(names, i),
            )
        if status & sii.COMMAND_ERRORS:
            # Clear a stale error from before (e.g. a read interrupted by a reset).
            dg.fpwr(stations[i], reg.SII_CONTROL, u16(0))
    images = [bytearray() for _ in stations]
    active = list(range(n))
    while active:
        words = {i: len(images[i]) // 2 for i in active}
        requests: list[Datagram] = []
        for i in active:
            requests.append(
                Datagram(Cmd.FPWR, fixed_address(stations[i], reg.SII_ADDRESS), u32(words[i]))
            )
            requests.append(
                Datagram(Cmd.FPWR, fixed_address(stations[i], reg.SII_CONTROL), u16(sii.CMD_READ))
            )
        for k, reply in enumerate(dg.batch(requests)):
            if reply.wkc != 1:
                raise BusError(f"{_who(names, active[k // 2])}: SII read command not accepted")
        pending = list(active)
        deadline = time.monotonic() + timeout_s
        while pending:
            replies = dg.batch(
                [
                    Datagram(Cmd.FPRD, fixed_address(stations[i], reg.SII_CONTROL), 14)
                    for i in pending
                ]
            )
            still: list[int] = []
            for i, reply in zip(pending, replies, strict=True):
                if reply.wkc != 1:
                    raise BusError(f"{_who(names, i)}: no answer while reading the SII")
                (control,) = struct.unpack_from("<H", reply.data)
                if control & sii.BUSY:
                    still.append(i)
                    continue
                if control & sii.COMMAND_ERRORS:
                    raise SiiReadError(_who(names, i), words[i], control)
                size = 8 if control & sii.READ_8_BYTES else 4
                images[i].extend(reply.data[6 : 6 + size])
            if still and time.monotonic() > deadline:
                raise BusError(f"{_who(names, still[0])}: SII EEPROM stays busy")
            pending = still
        done: list[int] = []
        for i in active:
            img = bytes(images[i])
            if len(img) >= 2 * sii_word.FIRST_CATEGORY and (
                sii_complete(img) or len(img) >= MAX_SII_BYTES
            ):
                done.append(i)
        active = [i for i in active if i not in done]
    dg.batch([Datagram(Cmd.FPWR, fixed_address(s, reg.SII_CONFIG), TO_PDI) for s in stations])
    return [bytes(img) for img in images]
