"""PDO selection from the ESI / the configuration override, and the CoE writes it needs."""

from __future__ import annotations

import struct
from pathlib import Path

import pytest

from ether_ros.config import ProcessLayout, ProcessValueError, load_esi
from ether_ros.config.esi import EsiDevice
from ether_ros.errors import BusError
from ether_ros.master.configure import (
    op_only_sync_managers,
    process_fmmus,
    process_sync_managers,
)
from ether_ros.master.pdo import (
    RX_ASSIGN,
    TX_ASSIGN,
    assignment_writes,
    select_pdos,
    sm_assignments,
)
from ether_ros.master.plan import layout_image

DEVICES = Path(__file__).resolve().parents[2] / "devices"


@pytest.fixture(scope="module")
def leg() -> EsiDevice:
    return load_esi(DEVICES / "laelaps_ii_leg.xml")[0]


def test_esi_default_assignment_sizes(leg: EsiDevice) -> None:
    sel = select_pdos("slave 0 (leg)", leg)
    assert sel.source == "esi"
    assert sel.output_bytes == 38 and sel.input_bytes == 22


def test_override_is_checked_against_the_esi(leg: EsiDevice) -> None:
    rx = [p.index for p in leg.rx_pdos if p.sm is not None]
    tx = [p.index for p in leg.tx_pdos if p.sm is not None]
    sel = select_pdos("slave 0 (leg)", leg, rx, tx)
    assert sel.source == "config"
    with pytest.raises(BusError, match=r"slave 0 \(leg\): PDO 0x1234 is not in the ESI"):
        select_pdos("slave 0 (leg)", leg, [0x1234], tx)
    with pytest.raises(BusError, match="is a TxPDO"):
        select_pdos("slave 0 (leg)", leg, tx, tx)


def test_assignment_writes_clear_fill_count(leg: EsiDevice) -> None:
    sel = select_pdos("s", leg)
    assignments = sm_assignments(leg, sel)
    assert [a.index for a in assignments] == [RX_ASSIGN, TX_ASSIGN]
    writes = assignment_writes(assignments)
    rx = [(w.index, w.subindex, w.data) for w in writes if w.index == RX_ASSIGN]
    assert rx[0] == (RX_ASSIGN, 0, b"\0")
    assert rx[-1] == (RX_ASSIGN, 0, bytes([len(sel.rx)]))
    assert [struct.unpack("<H", d)[0] for _i, s, d in rx[1:-1]] == [p.index for p in sel.rx]
    assert any(w.index == TX_ASSIGN for w in writes)
    first = sel.rx[0]
    with_mapping = assignment_writes(assignments, [first])
    mapping = [(w.index, w.subindex, w.data) for w in with_mapping if w.index == first.index]
    assert mapping[0] == (first.index, 0, b"\0")
    assert mapping[1] == (first.index, 1, struct.pack("<I", first.entries[0].mapping_value))
    assert mapping[-1] == (first.index, 0, bytes([len(first.entries)]))
    # The mapping goes after the assignment is cleared and before it is filled.
    order = [(w.index, w.subindex) for w in with_mapping]
    assert order.index((RX_ASSIGN, 0)) < order.index((first.index, 1)) < order.index((RX_ASSIGN, 1))


def test_process_sms_and_fmmus_from_esi(leg: EsiDevice) -> None:
    layout = layout_image([(0, 0x1001, "a", 38, 22), (1, 0x1002, "b", 38, 22)])
    segments = ProcessLayout.for_device(leg).segments
    sms = process_sync_managers(leg, segments)
    assert [(s.index, s.start, s.length, s.control, s.enable) for s in sms] == [
        (2, 0x1100, 38, 0x64, True),
        (3, 0x1400, 22, 0x20, True),
    ]
    fmmus = process_fmmus(layout.slaves[1], sms, 0, leg, segments)
    assert [(f.logical_start, f.length, f.physical_start, f.direction) for f in fmmus] == [
        (38, 38, 0x1100, 2),
        (76 + 22, 22, 0x1400, 1),
    ]


DIGITAL = """<?xml version="1.0"?>
<EtherCATInfo><Vendor><Id>2</Id></Vendor><Descriptions><Devices>
<Device><Type ProductCode="#x01000001" RevisionNo="1">Out32</Type><Name>32 outputs</Name>
  <Fmmu OpOnly="1">Outputs</Fmmu>
  <Sm StartAddress="#x0f00" ControlByte="#x44" Enable="1">Outputs</Sm>
  <Sm StartAddress="#x0f01" ControlByte="#x44" Enable="1" OpOnly="1">Outputs</Sm>
  <Sm StartAddress="#x0f02" ControlByte="#x44" Enable="1">Outputs</Sm>
  <Sm StartAddress="#x0981" Virtual="true">Outputs</Sm>
  <Sm StartAddress="#x1000" ControlByte="#x20" Enable="1">Inputs</Sm>
  <RxPdo Fixed="1" Sm="0"><Index>#x1600</Index><Name>Byte 0</Name>
    <Entry><Index>#x7000</Index><SubIndex>1</SubIndex><BitLen>1</BitLen><Name>Out0</Name><DataType>BOOL</DataType></Entry></RxPdo>
  <RxPdo Fixed="1" Sm="1"><Index>#x1601</Index><Name>Byte 1</Name>
    <Entry><Index>#x7000</Index><SubIndex>2</SubIndex><BitLen>8</BitLen><Name>Out1</Name><DataType>USINT</DataType></Entry></RxPdo>
  <RxPdo Fixed="1" Sm="2"><Index>#x1602</Index><Name>Byte 2</Name>
    <Entry><Index>#x7000</Index><SubIndex>3</SubIndex><BitLen>8</BitLen><Name>Out2</Name><DataType>USINT</DataType></Entry></RxPdo>
  <RxPdo Fixed="1" Sm="3" Virtual="true"><Index>#x1602</Index><Name>DC activation</Name>
    <Entry><Index>#x1d09</Index><SubIndex>#x81</SubIndex><BitLen>8</BitLen><Name>Activate</Name><DataType>USINT</DataType></Entry></RxPdo>
  <TxPdo Fixed="1" Sm="4"><Index>#x1a00</Index><Name>In</Name>
    <Entry><Index>#x6000</Index><SubIndex>1</SubIndex><BitLen>8</BitLen><Name>Out0</Name><DataType>USINT</DataType></Entry></TxPdo>
</Device></Devices></Descriptions></EtherCATInfo>
"""


def test_several_sms_of_a_direction_digital_io_virtual_and_op_only(tmp_path: Path) -> None:
    """Outputs in three SMs at the ESC's digital output registers 0x0F00..0x0F02 (one of them
    OpOnly) and a virtual SM on a DC register: each SM's data starts on a byte, the three
    adjacent SMs share one FMMU, the virtual one gets an FMMU onto the register and no SM, and
    the OpOnly SM is enabled only for OP."""
    p = tmp_path / "digital.xml"
    p.write_text(DIGITAL)
    (dev,) = load_esi(p)
    sel = select_pdos("s", dev)
    assert [(p.index, p.virtual) for p in sel.rx] == [
        (0x1600, False), (0x1601, False), (0x1602, False), (0x1602, True)
    ]  # fmt: skip
    layout = ProcessLayout.for_device(dev, sel.rx, sel.tx)
    assert [(s.sm, s.byte_offset, s.byte_length) for s in layout.segments] == [
        (0, 0, 1), (1, 1, 1), (2, 2, 1), (3, 3, 1), (4, 0, 1)
    ]  # fmt: skip
    assert layout.variable("Out1").bit_offset == 8
    # One name in both directions: a write takes the output, the keys tell them apart.
    assert layout.variable("Out0", "output").direction == "output"
    with pytest.raises(ProcessValueError, match=r"use one of 0x7000:01, 0x6000:01"):
        layout.variable("Out0")
    sms = process_sync_managers(dev, layout.segments)
    assert [(s.index, s.start, s.length, s.enable) for s in sms] == [
        (0, 0x0F00, 1, True), (1, 0x0F01, 1, False), (2, 0x0F02, 1, True), (4, 0x1000, 1, True)
    ]  # fmt: skip
    assert [(s.index, s.enable) for s in op_only_sync_managers(dev, layout.segments)] == [(1, True)]
    area = layout_image([(0, 0x1001, "d", 4, 1)]).slaves[0]
    fmmus = process_fmmus(area, sms, 0, dev, layout.segments)
    assert [(f.logical_start, f.length, f.physical_start, f.direction) for f in fmmus] == [
        (0, 3, 0x0F00, 2),
        (3, 1, 0x0981, 2),
        (4, 1, 0x1000, 1),
    ]


def test_an_entry_mapped_in_both_directions_is_addressable(tmp_path: Path) -> None:
    """EtherBerry maps 0x0005:01 (named Byte0) as an output and as an input: each gets a key
    naming its PDO, and a write by name takes the output."""
    text = DIGITAL.replace("#x6000</Index><SubIndex>1", "#x7000</Index><SubIndex>1", 1).replace(
        "<BitLen>1</BitLen><Name>Out0</Name><DataType>BOOL",
        "<BitLen>8</BitLen><Name>Out0</Name><DataType>USINT",
        1,
    )
    p = tmp_path / "both.xml"
    p.write_text(text)
    (dev,) = load_esi(p)
    layout = ProcessLayout.for_device(dev)
    keys = sorted(v.key for v in layout.variables if v.name == "Out0")
    assert keys == ["0x1600/0x7000:01", "0x1a00/0x7000:01"]
    assert layout.variable("0x1a00/0x7000:01").direction == "input"
    assert layout.variable("0x1600/0x7000:01").direction == "output"
    out = layout.pack_outputs({"Out0": 7})
    assert out[0] == 7
