"""devices/servo_drive.xml: our CiA 402 servo drives (1 and 2 axes) as the ESI parser sees them,
and the file is what its generator (scripts/gen_servo_drive_esi.py) writes."""

from __future__ import annotations

import importlib.util
import sys
from pathlib import Path

import pytest

from ether_ros.config import load_esi
from ether_ros.config import types as dt
from ether_ros.config.esi import EsiDevice

REPO = Path(__file__).resolve().parents[2]
SERVO = REPO / "devices" / "servo_drive.xml"
AXIS_OFFSET = 0x800

# IEC 61800-7-201 objects every axis must carry: (index at axis 1, data type code, access).
AXIS_OBJECTS = {
    0x6040: (dt.UINT16.code, "rw"),
    0x6041: (dt.UINT16.code, "ro"),
    0x6060: (dt.INT8.code, "rw"),
    0x6061: (dt.INT8.code, "ro"),
    0x607A: (dt.INT32.code, "rw"),
    0x60FF: (dt.INT32.code, "rw"),
    0x6071: (dt.INT16.code, "rw"),
    0x6064: (dt.INT32.code, "ro"),
    0x606C: (dt.INT32.code, "ro"),
    0x6077: (dt.INT16.code, "ro"),
    0x603F: (dt.UINT16.code, "ro"),
    0x60F4: (dt.INT32.code, "ro"),
    0x6065: (dt.UINT32.code, "rw"),
    0x6066: (dt.UINT16.code, "rw"),
    0x6067: (dt.UINT32.code, "rw"),
    0x606D: (dt.UINT16.code, "rw"),
    0x6502: (dt.UINT32.code, "ro"),
    0x6076: (dt.UINT32.code, "rw"),
    0x6072: (dt.UINT16.code, "rw"),
    0x6080: (dt.UINT32.code, "rw"),
    0x605A: (dt.INT16.code, "rw"),
    0x6085: (dt.UINT32.code, "rw"),
    0x6081: (dt.UINT32.code, "rw"),
    0x6083: (dt.UINT32.code, "rw"),
    0x6084: (dt.UINT32.code, "rw"),
    0x6098: (dt.INT8.code, "rw"),
    0x609A: (dt.UINT32.code, "rw"),
    0x607C: (dt.INT32.code, "rw"),
}
# Records: index -> subindex -> data type code.
AXIS_RECORDS = {
    0x607D: {1: dt.INT32.code, 2: dt.INT32.code},
    0x608F: {1: dt.UINT32.code, 2: dt.UINT32.code},
    0x6091: {1: dt.UINT32.code, 2: dt.UINT32.code},
    0x6099: {1: dt.UINT32.code, 2: dt.UINT32.code},
    0x60C2: {1: dt.UINT8.code, 2: dt.INT8.code},
}
RX_LAYOUT = [(0x6040, 16), (0x6060, 8), (0, 8), (0x607A, 32), (0x60FF, 32), (0x6071, 16)]
TX_LAYOUT = [(0x6041, 16), (0x6061, 8), (0, 8), (0x6064, 32), (0x606C, 32), (0x6077, 16)]
TX_LAYOUT += [(0x603F, 16), (0x60F4, 32)]
# PP, PV, HM, CSP, CSV, CST (0x6502 bits 0, 2, 5, 7, 8, 9).
SUPPORTED_MODES = 0b11_1010_0101


@pytest.fixture(scope="module")
def drives() -> dict[str, EsiDevice]:
    return {d.type_name: d for d in load_esi(SERVO)}


def _value(device: EsiDevice, index: int, subindex: int = 0) -> int:
    entry = device.od_entry(index, subindex)
    assert entry is not None, f"{device.type_name} lacks {index:#06x}:{subindex}"
    signed = entry.data_type in (dt.INT8.code, dt.INT16.code, dt.INT32.code)
    return int.from_bytes(entry.default, "little", signed=signed)


def test_two_devices_with_identity(drives: dict[str, EsiDevice]) -> None:
    assert set(drives) == {"ServoDrive1", "ServoDrive2"}
    for name, product in (("ServoDrive1", 0x00020001), ("ServoDrive2", 0x00020002)):
        d = drives[name]
        assert (d.vendor_id, d.product_code) == (0x00000A12, product)
        assert _value(d, 0x1018, 1) == 0x00000A12
        assert _value(d, 0x1018, 2) == product
        assert _value(d, 0x1000) & 0xFFFF == 402


@pytest.mark.parametrize(("name", "axes"), [("ServoDrive1", 1), ("ServoDrive2", 2)])
def test_profile_402_per_axis(drives: dict[str, EsiDevice], name: str, axes: int) -> None:
    assert drives[name].profile_numbers == (402,) * axes


@pytest.mark.parametrize(("name", "axes"), [("ServoDrive1", 1), ("ServoDrive2", 2)])
def test_every_axis_has_the_cia402_objects(
    drives: dict[str, EsiDevice], name: str, axes: int
) -> None:
    d = drives[name]
    for axis in range(axes):
        off = axis * AXIS_OFFSET
        for index, (code, access) in AXIS_OBJECTS.items():
            e = d.od_entry(index + off, 0)
            assert e is not None, f"{name} axis {axis + 1} lacks {index + off:#06x}"
            assert (e.data_type, e.access) == (code, access), f"{index + off:#06x}"
        for index, subs in AXIS_RECORDS.items():
            obj = d.od_object(index + off)
            assert obj is not None, f"{name} axis {axis + 1} lacks {index + off:#06x}"
            assert _value(d, index + off, 0) == len(subs)
            assert {e.subindex: e.data_type for e in obj.entries if e.subindex} == subs
        assert _value(d, 0x6502 + off) == SUPPORTED_MODES
        assert _value(d, 0x608F + off, 1) > 0 and _value(d, 0x6091 + off, 1) > 0
        assert _value(d, 0x605A + off) == 2, "quick stop: ramp, then Switch on disabled"
        assert _value(d, 0x607D + off, 1) < _value(d, 0x607D + off, 2)
    # No third axis.
    assert d.od_entry(0x6040 + axes * AXIS_OFFSET, 0) is None
    for index in (0x1000, 0x1001, 0x1018, 0x1C00, 0x1C12, 0x1C13, 0x1C32, 0x1C33):
        assert d.od_object(index) is not None, f"{name} lacks {index:#06x}"
    # ETG.1020 sync manager parameters: sync type writable, DC SYNC0 supported.
    assert d.od_entry(0x1C32, 1) is not None and d.od_entry(0x1C32, 1).access == "rw"  # type: ignore[union-attr]
    assert _value(d, 0x1C32, 4) & 0b1100 == 0b0100
    assert d.od_entry(0x1C33, 32) is not None


@pytest.mark.parametrize(("name", "axes"), [("ServoDrive1", 1), ("ServoDrive2", 2)])
def test_default_pdos_per_axis_and_remappable(
    drives: dict[str, EsiDevice], name: str, axes: int
) -> None:
    d = drives[name]
    assert d.default_rx_pdos() == tuple(0x1600 + 0x10 * a for a in range(axes))
    assert d.default_tx_pdos() == tuple(0x1A00 + 0x10 * a for a in range(axes))
    assert d.mailbox is not None
    assert (d.mailbox.coe, d.mailbox.sdo_info, d.mailbox.pdo_assign, d.mailbox.pdo_config) == (
        True,
        True,
        True,
        True,
    )
    for axis in range(axes):
        off = axis * AXIS_OFFSET
        for pdo_index, layout in ((0x1600, RX_LAYOUT), (0x1A00, TX_LAYOUT)):
            pdo = d.pdo(pdo_index + 0x10 * axis)
            assert pdo is not None
            assert not pdo.fixed, "a master may remap"
            want = [(i + off if i else 0, bits) for i, bits in layout]
            assert [(e.index, e.bit_length) for e in pdo.entries] == want
            # The mapping object carries the same entries, writable.
            mapping = d.od_object(pdo.index)
            assert mapping is not None
            assert _value(d, pdo.index, 0) == len(pdo.entries)
            assert all(e.access == "rw" for e in mapping.entries)
            for k, e in enumerate(pdo.entries, 1):
                assert _value(d, pdo.index, k) == e.mapping_value
            # Every mapped object is mappable in that direction.
            for e in pdo.entries:
                if not e.is_padding:
                    od = d.od_entry(e.index, e.subindex)
                    assert od is not None
                    assert ("R" if pdo.direction == "rx" else "T") in od.pdo_mapping
        # Even alignment: 32-bit values on 4-byte boundaries within the PDO.
        for pdo_index in (0x1600, 0x1A00):
            pdo = d.pdo(pdo_index + 0x10 * axis)
            assert pdo is not None
            bit = 0
            for e in pdo.entries:
                if e.bit_length == 32:
                    assert bit % 32 == 0, f"{e.name} at bit {bit}"
                bit += e.bit_length
    assert _value(d, 0x1C12, 0) == axes and _value(d, 0x1C13, 0) == axes
    assert [_value(d, 0x1C12, k) for k in range(1, axes + 1)] == list(d.default_rx_pdos())
    out_sm, in_sm = d.sm("Outputs"), d.sm("Inputs")
    assert out_sm is not None and in_sm is not None
    assert (out_sm.default_size, in_sm.default_size) == (14 * axes, 20 * axes)


def test_dc_sync0_and_free_run(drives: dict[str, EsiDevice]) -> None:
    for d in drives.values():
        modes = {m.name: m.assign_activate for m in d.dc_opmodes}
        assert modes == {"DC": 0x0300, "FreeRun": 0x0000}
        assert d.dc_supported and not d.dc_required


def test_file_is_what_the_generator_writes(monkeypatch: pytest.MonkeyPatch) -> None:
    spec = importlib.util.spec_from_file_location(
        "gen_servo_drive_esi", REPO / "scripts" / "gen_servo_drive_esi.py"
    )
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    monkeypatch.setitem(sys.modules, spec.name, module)  # dataclasses look their module up
    spec.loader.exec_module(module)
    assert module.render() == SERVO.read_text(encoding="utf-8")
