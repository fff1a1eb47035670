"""The record codecs moved into the protocol crate (SyncManager and FMMU registers, SII
categories and their records, SDO segments and initiate headers) give the bytes the Python code
gave before, and the errors of the Rust core arrive as the classes of ``ether_ros.errors``.

The references below are the removed Python encoders, kept here as the specification of the
bytes; ``tests/data/sii_golden.json`` holds digests of the SII images (and of their decoding)
built by the code before the move for the shipped devices and the vendor ESI corpus.
"""

from __future__ import annotations

import hashlib
import json
import logging
import struct
from pathlib import Path

import pytest

from ether_ros import _native
from ether_ros._native import protocol
from ether_ros._native.protocol import coe, sdo_abort, sii_word
from ether_ros.config.esi import load_esi
from ether_ros.config.sii import build_sii, parse_sii
from ether_ros.errors import EtherRosError, InvalidRequest, LinkError
from ether_ros.master.sii import MAX_SII_BYTES, sii_complete
from ether_ros.master.sm_fmmu import Fmmu, SyncManager

REPO = Path(__file__).resolve().parents[2]
GOLDEN = REPO / "tests" / "data" / "sii_golden.json"
VENDOR = REPO.parent / "shared" / "esi-vendor"


def _old_sm(start: int, length: int, control: int, enable: bool) -> bytes:
    return struct.pack("<HHBBBB", start, length, control, 0, 1 if enable else 0, 0)


def _old_fmmu(
    ls: int, length: int, lsb: int, leb: int, ps: int, psb: int, typ: int, en: bool
) -> bytes:
    return struct.pack("<IHBBHBBB3x", ls, length, lsb, leb, ps, psb, typ, 1 if en else 0)


@pytest.mark.parametrize("enable", [True, False])
def test_sync_manager_records_are_the_bytes_of_before(enable: bool) -> None:
    for index, (start, length, control) in enumerate(
        [(0x1000, 128, 0x26), (0x1080, 128, 0x22), (0x1100, 0, 0x64), (0xFFFF, 0xFFFF, 0xFF)]
    ):
        sm = SyncManager(index, start, length, control, enable)
        assert sm.encode() == _old_sm(start, length, control, enable)
        assert SyncManager.decode(index, sm.encode()) == sm
    with pytest.raises(ValueError, match="SyncManager 2: 7 bytes"):
        SyncManager.decode(2, bytes(7))


def test_fmmu_records_are_the_bytes_of_before() -> None:
    cases = [
        (0x0001_0000, 2, 0, 7, 0x1000, 0, 2, True),
        (0xFFFF_FFFF, 0xFFFF, 3, 5, 0x1F00, 6, 1, True),
        (0, 1, 0, 0, 0x080D, 0, 1, False),
    ]
    for i, (ls, length, lsb, leb, ps, psb, typ, en) in enumerate(cases):
        f = Fmmu(i, ls, length, ps, typ, lsb, leb, psb, en)
        assert f.encode() == _old_fmmu(ls, length, lsb, leb, ps, psb, typ, en)
        assert Fmmu.decode(i, f.encode()) == f
    with pytest.raises(ValueError, match="FMMU 1"):
        Fmmu.decode(1, bytes(12))


def _old_download_segment(toggle: int, last: bool, chunk: bytes) -> bytes:
    unused = 7 - len(chunk) if len(chunk) < 7 else 0
    command = (
        coe.CCS_DOWNLOAD_SEGMENT << coe.SPECIFIER_SHIFT
        | toggle
        | unused << coe.SEGMENT_UNUSED_SHIFT
        | (coe.LAST_SEGMENT if last else 0)
    )
    return (
        struct.pack("<H", coe.SERVICE_SDO_REQUEST << 12) + bytes([command]) + chunk.ljust(7, b"\0")
    )


def _old_upload_body(segment: bytes) -> bytes:
    body = segment[3:]
    if len(body) <= 7:
        body = body[: 7 - ((segment[2] >> coe.SEGMENT_UNUSED_SHIFT) & 0x07)]
    return body


def test_sdo_segments_are_the_bytes_of_before() -> None:
    data = bytes(range(40))
    for n in range(len(data)):
        for toggle in (0, coe.TOGGLE):
            for last in (False, True):
                chunk = data[:n]
                new = protocol.sdo_segment(
                    coe.SERVICE_SDO_REQUEST, coe.CCS_DOWNLOAD_SEGMENT, bool(toggle), last, chunk
                )
                assert new == _old_download_segment(toggle, last, chunk)
                parsed = protocol.parse_sdo_segment(new)
                assert parsed == (
                    coe.SERVICE_SDO_REQUEST,
                    coe.CCS_DOWNLOAD_SEGMENT,
                    bool(toggle),
                    last,
                    _old_upload_body(new),
                )
    for toggle in (0, coe.TOGGLE):
        old_request = (
            struct.pack("<H", coe.SERVICE_SDO_REQUEST << 12)
            + bytes([coe.CCS_UPLOAD_SEGMENT << coe.SPECIFIER_SHIFT | toggle])
            + bytes(7)
        )
        assert (
            protocol.sdo_toggle_message(
                coe.SERVICE_SDO_REQUEST, coe.CCS_UPLOAD_SEGMENT, bool(toggle)
            )
            == old_request
        )
    assert protocol.coe_header(coe.SERVICE_SDO_INFORMATION) == struct.pack("<H", 8 << 12)
    assert protocol.parse_sdo_segment(b"\x00\x20") is None


def _old_sdo(command: int, index: int, subindex: int, data: bytes = bytes(4)) -> bytes:
    """The master's SDO initiate builder before the move (``master/coe.py``)."""
    return (
        struct.pack("<H", coe.SERVICE_SDO_REQUEST << 12)
        + struct.pack("<BHB", command, index, subindex)
        + data
    )


def test_sdo_initiate_headers_are_the_bytes_of_before() -> None:
    """Every kind of initiate header: built, compared with the old bit-fiddling, parsed back."""
    request, ccs_up, ccs_down = (
        coe.SERVICE_SDO_REQUEST,
        coe.CCS_UPLOAD_INITIATE,
        coe.CCS_DOWNLOAD_INITIATE,
    )
    for ca in (False, True):
        ca_bit = coe.COMPLETE_ACCESS if ca else 0
        # Upload initiate request: no flags, zero data.
        new = protocol.sdo_initiate(request, ccs_up, 0x1C12, 1, ca)
        assert new == _old_sdo(ccs_up << coe.SPECIFIER_SHIFT | ca_bit, 0x1C12, 1)
        assert protocol.parse_sdo_header(new) == (request, ccs_up, ca, 0x1C12, 1, None, 0)
        # Normal download initiate: size indicated, the size in the data field.
        new = protocol.sdo_initiate(request, ccs_down, 0x7000, 0, ca, 300)
        command = ccs_down << coe.SPECIFIER_SHIFT | ca_bit | coe.SIZE_INDICATED
        assert new == _old_sdo(command, 0x7000, 0, struct.pack("<I", 300))
        assert protocol.parse_sdo_header(new) == (request, ccs_down, ca, 0x7000, 0, None, 300)
        # Expedited download of 1 to 4 bytes.
        for n in range(1, 5):
            data = bytes(range(1, n + 1))
            new = protocol.sdo_expedited(request, ccs_down, 0x6040, 0, data, ca)
            command = (
                ccs_down << coe.SPECIFIER_SHIFT
                | ca_bit
                | (4 - n) << coe.EXPEDITED_UNUSED_SHIFT
                | coe.EXPEDITED
                | coe.SIZE_INDICATED
            )
            assert new == _old_sdo(command, 0x6040, 0, data.ljust(4, b"\x00"))
            parsed = protocol.parse_sdo_header(new)
            assert parsed is not None
            assert parsed[5] == data
    # Abort: the code in the data field.
    new = protocol.sdo_abort_message(request, 0x1008, 0, sdo_abort.ABORT_TOGGLE_BIT)
    assert new == _old_sdo(
        coe.CS_ABORT << coe.SPECIFIER_SHIFT, 0x1008, 0, struct.pack("<I", 0x05030000)
    )
    assert protocol.parse_sdo_header(new) == (
        request,
        coe.CS_ABORT,
        False,
        0x1008,
        0,
        None,
        sdo_abort.ABORT_TOGGLE_BIT,
    )
    # An expedited transfer carries 1 to 4 bytes; a short message is no header.
    for bad in (b"", bytes(5)):
        with pytest.raises(ValueError, match="1 to 4 bytes"):
            protocol.sdo_expedited(request, ccs_down, 0x6040, 0, bad)
    assert protocol.parse_sdo_header(new[:9]) is None


def _old_sii_complete(image: bytes) -> bool:
    word = sii_word.FIRST_CATEGORY
    while True:
        pos = 2 * word
        if pos + 2 > len(image):
            return False
        (kind,) = struct.unpack_from("<H", image, pos)
        if kind == 0xFFFF:
            return True
        if pos + 4 > len(image):
            return False
        (size,) = struct.unpack_from("<H", image, pos + 2)
        word += 2 + size
        if 2 * word > MAX_SII_BYTES:
            return True


def _esi_files() -> list[Path]:
    files = sorted((REPO / "devices").glob("*.xml"))
    if VENDOR.is_dir():
        files += sorted(VENDOR.rglob("*.xml"))
    return files


def test_sii_images_and_their_decoding_are_those_of_before() -> None:
    golden: dict[str, object] = json.loads(GOLDEN.read_text())
    logging.disable(logging.CRITICAL)
    seen: dict[str, object] = {}
    try:
        for path in _esi_files():
            try:
                devices = load_esi(path)
            except Exception:  # the golden file skipped these too
                continue
            for i, device in enumerate(devices):
                key = f"{path.name}#{i}:{device.type_name}"
                image = build_sii(device, alias=3, serial=7)
                info = parse_sii(image)
                seen[key] = [
                    hashlib.sha256(image).hexdigest()[:16],
                    hashlib.sha256(repr(info).encode()).hexdigest()[:16],
                ]
                if path.parent.name != "devices":
                    continue
                # Every prefix of a shipped device's image: the walk says complete exactly
                # where it did.
                for cut in range(2 * sii_word.FIRST_CATEGORY, min(len(image), 2048) + 1, 2):
                    assert sii_complete(image[:cut]) == _old_sii_complete(image[:cut])
    finally:
        logging.disable(logging.NOTSET)
    assert seen, "no ESI found"
    for key, digests in seen.items():
        assert golden.get(key) == digests, key
    present = {p.name for p in _esi_files()}
    expected = {k for k in golden if k.split("#")[0] in present}
    assert expected <= set(seen), "a device of the golden file no longer loads"


def test_sii_records_round_trip() -> None:
    syncm = protocol.sii_syncm_record(0x1100, 4, 0x64, 1, 3)
    assert syncm == bytes([0x00, 0x11, 0x04, 0x00, 0x64, 0x00, 0x01, 0x03])
    assert protocol.parse_sii_syncms(syncm + syncm[:7]) == [(0x1100, 4, 0x64, 0, 1, 3)]
    pdo = protocol.sii_pdo_record(0x1A00, 1, 3, 2, protocol.sii_pdo.FLAG_DEFAULT)
    entry = protocol.sii_pdo_entry_record(0x6000, 1, 4, 0x07, 32)
    assert protocol.parse_sii_pdos(pdo + entry) == (
        [(0x1A00, 3, 2, 2, [(0x6000, 1, 4, 0x07, 32)])],
        None,
    )
    assert protocol.parse_sii_pdos(pdo + entry[:4]) == ([], 0x1A00)
    dc = protocol.sii_dc_record(1_000_000, -5, 7, 1, 0x0300, 1, 2, 3)
    assert len(dc) == 24 and protocol.parse_sii_dcs(dc) == [(1_000_000, -5, 7, 1, 0x0300, 1, 2, 3)]
    cat = protocol.sii_category_bytes(protocol.sii_category.FMMU, b"\x01\x02\x03")
    assert cat == b"\x28\x00\x02\x00\x01\x02\x03\x00"


def test_rust_errors_arrive_as_the_errors_of_the_hierarchy() -> None:
    # One definition: the extension re-exports the classes of ether_ros.errors.
    from ether_ros import errors

    assert _native.EngineError is errors.EngineError
    assert _native.EngineTimeout is errors.EngineTimeout
    assert issubclass(_native.EngineError, LinkError)
    engine = _native.Engine.open_sim(_native.SimNetwork())
    try:
        # More data than a frame holds: refused by the engine before anything is sent.
        with pytest.raises(InvalidRequest) as err:
            engine.transact([("BRD", 0, 1400), ("BRD", 0, 1400)])
        assert isinstance(err.value, ValueError) and isinstance(err.value, EtherRosError)
    finally:
        engine.close()
