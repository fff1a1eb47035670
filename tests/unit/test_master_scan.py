"""Scan, SII reading and the identity check against register-level fake ESCs (one layer down:
datagrams in, register memory out; the SII images come from the real ESI via build_sii)."""

from __future__ import annotations

import struct
from collections.abc import Sequence
from pathlib import Path

import pytest

from ether_ros.config import build_sii, load_esi
from ether_ros.errors import BusError, IdentityMismatch, SiiReadError
from ether_ros.master.datagrams import Cmd, DatagramService
from ether_ros.master.scan import Expected, match_configuration, scan

DEVICES = Path(__file__).resolve().parents[2] / "devices"


class FakeEsc:
    def __init__(
        self, sii: bytes, alias: int = 0, read_bytes: int = 8, fail: bool = False,
        status: int = 0,
    ) -> None:  # fmt: skip
        self.mem = bytearray(0x1000)
        self.sii = sii
        self.read_bytes = read_bytes
        self.fail = fail
        # Status bits the EEPROM interface shows with every answer (e.g. a checksum error).
        self.status = status
        struct.pack_into("<H", self.mem, 0x0502, status)
        self.mem[0x0008] = 0x04  # DC supported
        struct.pack_into("<H", self.mem, 0x0012, alias)
        self.mem[0x0130] = 0x01

    @property
    def station(self) -> int:
        return int(struct.unpack_from("<H", self.mem, 0x0010)[0])

    def read(self, ado: int, n: int) -> bytes:
        return bytes(self.mem[ado : ado + n])

    def write(self, ado: int, data: bytes) -> None:
        self.mem[ado : ado + len(data)] = data
        if ado <= 0x0502 < ado + len(data):
            control = struct.unpack_from("<H", self.mem, 0x0502)[0]
            if control & 0x0100:  # read command: 4 or 8 bytes from the word address
                word = struct.unpack_from("<I", self.mem, 0x0504)[0]
                n = self.read_bytes
                chunk = self.sii[2 * word : 2 * word + n].ljust(n, b"\xff")
                self.mem[0x0508 : 0x0508 + n] = chunk
                status = (0x0040 if n == 8 else 0) | (0x2000 if self.fail else 0) | self.status
                struct.pack_into("<H", self.mem, 0x0502, status)


class FakeLine:
    def __init__(self, escs: Sequence[FakeEsc]) -> None:
        self.escs = list(escs)

    def transact(
        self, datagrams: Sequence[tuple[int, int, bytes | int]], timeout_us: int = 0,
        retries: int = 0,
    ) -> list[tuple[bytes, int]]:  # fmt: skip
        replies = []
        for cmd, address, payload in datagrams:
            adp, ado = address & 0xFFFF, address >> 16
            n = payload if isinstance(payload, int) else len(payload)
            data, wkc = bytes(n), 0
            for pos, esc in enumerate(self.escs):
                hit = {
                    Cmd.APRD: adp == (-pos & 0xFFFF), Cmd.APWR: adp == (-pos & 0xFFFF),
                    Cmd.FPRD: adp == esc.station, Cmd.FPWR: adp == esc.station,
                    Cmd.BRD: True, Cmd.BWR: True,
                }.get(Cmd(cmd), False)  # fmt: skip
                if not hit:
                    continue
                wkc += 1
                if isinstance(payload, bytes):
                    esc.write(ado, payload)
                else:
                    data = esc.read(ado, n)
            replies.append((data, wkc))
        return replies


@pytest.fixture(scope="module")
def leg_sii() -> bytes:
    (leg,) = load_esi(DEVICES / "laelaps_ii_leg.xml")
    return build_sii(leg)


def test_scan_addresses_and_identifies(leg_sii: bytes) -> None:
    line = FakeLine([FakeEsc(leg_sii), FakeEsc(leg_sii, alias=7)])
    found = scan(DatagramService(line))
    assert [f.station for f in found] == [0x1001, 0x1002]
    assert [f.alias for f in found] == [0, 7]
    assert found[0].vendor_id == 0x00000A12 and found[0].product_code == 0x00A986FD
    assert found[0].dc_supported
    assert found[0].name  # from the SII general/strings categories
    assert found[0].header.mailbox[1] > 0


def test_identity_mismatch_names_slave_expected_and_found(leg_sii: bytes) -> None:
    found = scan(DatagramService(FakeLine([FakeEsc(leg_sii) for _ in range(3)])))
    expected = [
        Expected("hind_right_leg", 0xA12, 0x00A986FD, position=0),
        Expected("hind_left_leg", 0xA12, 0x00A986FD, position=1),
        Expected("front_left_leg", 0xA12, 0x0BADBEEF, position=2),
    ]
    with pytest.raises(IdentityMismatch) as err:
        match_configuration(found, expected)
    assert err.value.expected == (0xA12, 0x0BADBEEF, None)
    assert err.value.found[:2] == (0xA12, 0x00A986FD)
    assert str(err.value).startswith(
        "slave 2 (front_left_leg): expected vendor 0x00000A12 product 0x0BADBEEF, found vendor "
        "0x00000A12 product 0x00A986FD"
    )


def test_missing_and_extra_slaves(leg_sii: bytes) -> None:
    found = scan(DatagramService(FakeLine([FakeEsc(leg_sii), FakeEsc(leg_sii)])))
    one = [Expected("a", 0xA12, 0x00A986FD, position=0)]
    three = [*one, Expected("b", 0xA12, 0x00A986FD), Expected("c", 0xA12, 0x00A986FD)]
    with pytest.raises(BusError, match=r"slave 2 \(c\) is missing: the bus has only 2"):
        match_configuration(found, three)
    with pytest.raises(BusError, match=r"slave 1 .* is on the bus but not in the configuration"):
        match_configuration(found, one)
    by_alias = [Expected("x", 0xA12, 0x00A986FD, alias=9)]
    with pytest.raises(BusError, match="alias 9"):
        match_configuration(found, by_alias)


def test_empty_bus() -> None:
    assert scan(DatagramService(FakeLine([]))) == []


def test_sii_with_4_byte_reads_gives_the_same_image(leg_sii: bytes) -> None:
    eight = scan(DatagramService(FakeLine([FakeEsc(leg_sii)])))[0]
    four = scan(DatagramService(FakeLine([FakeEsc(leg_sii, read_bytes=4)])))[0]
    assert four.header == eight.header
    assert four.sii[: len(leg_sii)] == eight.sii[: len(leg_sii)]


def test_sii_read_error_names_the_slave(leg_sii: bytes) -> None:
    line = FakeLine([FakeEsc(leg_sii), FakeEsc(leg_sii, fail=True)])
    with pytest.raises(SiiReadError, match=r"slave 1: SII read at word 0x0000 failed") as err:
        scan(DatagramService(line))
    # Bit 13 of 0x0502: no acknowledge or invalid command (not the checksum, that is bit 11).
    assert err.value.word == 0 and err.value.status & 0x2000


def test_sii_checksum_error_is_reported_not_taken_for_a_failed_read(
    leg_sii: bytes, caplog: pytest.LogCaptureFixture
) -> None:
    # ET1100 datasheet section II, register 0x0502: bit 11 is the checksum error of the
    # configuration area, bit 13 a missing acknowledge or invalid command (the failed read of
    # the test above), bit 14 a write without write enable. The master used to call bit 13 the
    # checksum error and never looked at bit 11; now bit 11 is reported and the EEPROM is read.
    line = FakeLine([FakeEsc(leg_sii, status=0x0800 | 0x1000)])
    with caplog.at_level("WARNING", logger="ether_ros.master.sii"):
        (found,) = scan(DatagramService(line))
    assert found.vendor_id == 0x00000A12
    assert "checksum error in the SII configuration area" in caplog.text
