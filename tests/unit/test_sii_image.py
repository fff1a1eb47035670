"""SII images: build from ESI, decode, round trip, checksum, and malformed images."""

from __future__ import annotations

import re
import struct
from pathlib import Path

import pytest

from ether_ros._native.protocol import sii_checksum as crc8
from ether_ros.config import build_sii, load_esi, parse_sii
from ether_ros.config.sii import SiiFormatError
from ether_ros.errors import ConfigError

REPO = Path(__file__).resolve().parents[2]


def test_crc8_is_poly_07_init_ff() -> None:
    # CRC-8 poly 0x07 init 0xFF, no reflection, no final xor: the SII header checksum.
    assert crc8(b"") == 0xFF
    assert crc8(b"\x00") == 0xF3  # 0xFF shifted through x^8 + x^2 + x + 1 eight times
    assert crc8(b"123456789") == 0xFB


@pytest.mark.parametrize("name", ["laelaps_ii_leg.xml", "generic_io.xml"])
def test_round_trip(name: str) -> None:
    (dev,) = load_esi(REPO / "devices" / name)
    image = build_sii(dev, alias=0x1234, serial=0xDEADBEEF)
    assert len(image) == dev.eeprom.byte_size
    info = parse_sii(image)
    assert info.checksum_ok
    assert (info.vendor_id, info.product_code, info.revision) == (
        dev.vendor_id,
        dev.product_code,
        dev.revision,
    )
    assert (info.alias, info.serial) == (0x1234, 0xDEADBEEF)
    assert info.pdi_control == int.from_bytes(dev.eeprom.config_data[0:2], "little")
    assert info.eeprom_bytes == dev.eeprom.byte_size and info.version == 1
    assert info.has_coe
    assert info.mailbox == (0x1000, 128, 0x1080, 128)
    assert info.general is not None
    assert (info.general.name, info.general.order, info.general.group) == (
        dev.name,
        dev.type_name,
        dev.group_type,
    )
    assert info.general.coe_details & 0x03 == 0x03  # SDO + SDO info
    assert info.fmmus == dev.fmmus
    assert [(s.role, s.start, s.length, s.control) for s in info.sync_managers] == [
        (s.role, s.start, s.default_size, s.control) for s in dev.sync_managers
    ]
    for sii_pdos, esi_pdos in ((info.rx_pdos, dev.rx_pdos), (info.tx_pdos, dev.tx_pdos)):
        assert [(p.index, p.sm, p.name) for p in sii_pdos] == [
            (p.index, p.sm, p.name) for p in esi_pdos
        ]
        for sp, ep in zip(sii_pdos, esi_pdos, strict=True):
            assert [
                (e.index, e.subindex, e.name, e.data_type, e.bit_length) for e in sp.entries
            ] == [(e.index, e.subindex, e.name, e.data_type, e.bit_length) for e in ep.entries]
    assert [(d.assign_activate, d.name) for d in info.dc] == [
        (m.assign_activate, m.name) for m in dev.dc_opmodes
    ]


def test_laelaps_header_words() -> None:
    (leg,) = load_esi(REPO / "devices" / "laelaps_ii_leg.xml")
    image = build_sii(leg)
    words = struct.unpack_from("<64H", image, 0)
    assert words[7] == crc8(image[:14])
    assert (words[8] | words[9] << 16) == 0x0A12
    assert (words[10] | words[11] << 16) == 0x00A986FD
    assert words[0x18:0x1C] == (0x1000, 128, 0x1080, 128)
    assert words[0x1C] == 0x0004  # CoE
    assert words[0x3E] == 15  # 2048 bytes = 16 Kibit, stored minus one
    assert struct.unpack_from("<H", image, 128)[0] == 10  # STRINGS first
    info = parse_sii(image)
    assert info.categories == (10, 30, 40, 41, 50, 51, 60)
    assert sum(p.bit_length for p in info.rx_pdos) == 38 * 8
    assert sum(p.bit_length for p in info.tx_pdos) == 22 * 8


def test_corrupted_checksum_is_reported_not_hidden() -> None:
    (leg,) = load_esi(REPO / "devices" / "laelaps_ii_leg.xml")
    image = bytearray(build_sii(leg))
    image[2] ^= 0x01
    assert not parse_sii(bytes(image)).checksum_ok


def test_partial_image_decodes_header_only() -> None:
    (leg,) = load_esi(REPO / "devices" / "laelaps_ii_leg.xml")
    info = parse_sii(build_sii(leg)[:130])
    assert info.vendor_id == 0x0A12 and info.general is None


def test_malformed_images() -> None:
    with pytest.raises(SiiFormatError, match="too short: 10 bytes"):
        parse_sii(bytes(10))
    head = bytearray(128)
    # STRINGS category claiming 3 strings but holding one byte of text.
    bad = bytes(head) + struct.pack("<HH", 10, 2) + bytes([3, 5, 65, 66]) + b"\xff\xff"
    with pytest.raises(SiiFormatError, match="string 1 truncated"):
        parse_sii(bad)


def test_bad_alias_and_too_small_eeprom(tmp_path: Path) -> None:
    (leg,) = load_esi(REPO / "devices" / "laelaps_ii_leg.xml")
    with pytest.raises(ConfigError, match=r"alias must be 0\.\.65535"):
        build_sii(leg, alias=70000)
    small = tmp_path / "small.xml"
    text = (REPO / "devices" / "laelaps_ii_leg.xml").read_text()
    small.write_text(text.replace("<ByteSize>2048</ByteSize>", "<ByteSize>256</ByteSize>"))
    (tiny,) = load_esi(small)
    # The content needs more than the ESI's 256 bytes even without what a CoE device's
    # vendor tool leaves out (the PDO categories: masters read the PDOs over CoE): the EEPROM
    # grows (a power of two).
    image = build_sii(tiny)
    assert len(image) == 512
    info = parse_sii(image)
    assert info.eeprom_bytes == 512 and info.general is not None
    assert len(info.sync_managers) == 4 and not info.tx_pdos and not info.rx_pdos


def _fitted(tmp_path: Path, size: int) -> tuple[object, object]:
    text = (REPO / "devices" / "laelaps_ii_leg.xml").read_text()
    p = tmp_path / f"fit{size}.xml"
    p.write_text(text.replace("<ByteSize>2048</ByteSize>", f"<ByteSize>{size}</ByteSize>"))
    (dev,) = load_esi(p)
    return dev, parse_sii(build_sii(dev))


def test_the_sii_fits_the_esi_eeprom_as_the_vendor_tool_makes_it(tmp_path: Path) -> None:
    """An ESI's EEPROM too small for every PDO with its names holds less, in this order: the
    default-assigned PDOs only, then without entry names, then (CoE) no PDO categories."""
    dev, full = _fitted(tmp_path, 2048)
    assert len(full.tx_pdos) == len(dev.tx_pdos)  # type: ignore[attr-defined]
    sizes = [512, 1024]
    for size in sizes:
        _, info = _fitted(tmp_path, size)
        assert info.eeprom_bytes == size  # type: ignore[attr-defined]
        assert info.general is not None and info.sync_managers  # type: ignore[attr-defined]


def test_sync_managers_within_the_4k_soem_reads(tmp_path: Path) -> None:
    """SOEM reads the first 4 KiB of an EEPROM: when the strings would push General and
    SyncM past them (an ESI with a big EEPROM and long names), those go first."""
    text = (REPO / "devices" / "generic_io.xml").read_text()
    # Names of 250 characters for the entries of the first PDOs (the category holds 255).
    text = re.sub(
        r"<Name>(Digital|Analog)(Output|Input)(\d)</Name>",
        lambda m: f"<Name>{m.group(0)[6:-7] + 'x' * 240}</Name>",
        text,
    )
    p = tmp_path / "long.xml"
    p.write_text(text.replace("<ByteSize>2048</ByteSize>", "<ByteSize>16384</ByteSize>"))
    (dev,) = load_esi(p)
    info = parse_sii(build_sii(dev))
    order = list(info.categories)
    assert order.index(0x29) < order.index(0x0A), order  # SyncM before the strings
    image = build_sii(dev)
    assert image.index(bytes([0x29, 0x00])) < 4096


def test_strings_are_ascii_every_master_decodes(tmp_path: Path) -> None:
    """pysoem decodes SII strings as UTF-8 and fails on a Latin-1 "µ": the SII holds ASCII."""
    text = (REPO / "devices" / "generic_io.xml").read_text()
    p = tmp_path / "micro.xml"
    p.write_text(
        text.replace('<Name LcId="1033">GenericIO', '<Name LcId="1033">Générique 8 µs ±10 V', 1)
    )
    (dev,) = load_esi(p)
    info = parse_sii(build_sii(dev))
    assert info.general is not None and info.general.name.startswith("Generique 8 us +/-10 V")
    assert all(s.isascii() for s in info.strings)


def test_device_name_is_string_one() -> None:
    # SOEM names a slave by SII string 1; IgH by the GENERAL category's name index.
    (gio,) = load_esi(REPO / "devices" / "generic_io.xml")
    info = parse_sii(build_sii(gio))
    assert info.strings[0] == gio.name
    assert info.general is not None and info.general.name == gio.name
