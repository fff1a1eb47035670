"""ESI parsing: the shipped Laelaps II leg and generic I/O descriptions, and bad files."""
# ruff: noqa: E501  (tables of bad inputs read best one case per line)

from __future__ import annotations

import re
from pathlib import Path

import pytest

from ether_ros.config import ProcessLayout, load_esi
from ether_ros.config import types as dt
from ether_ros.config.esi import load_esi_file
from ether_ros.errors import ConfigError

REPO = Path(__file__).resolve().parents[2]
LEG = REPO / "devices" / "laelaps_ii_leg.xml"
GIO = REPO / "devices" / "generic_io.xml"

# Thesis Table 4.1 (outputs) and Table 4.2 (inputs): (index, subindex, name, type code).
TABLE_4_1 = [
    (0x7000, 1, "State_Machine", dt.BOOL.code),
    (0x7000, 2, "Initialize_clock", dt.BOOL.code),
    (0x7000, 3, "Initialize_angles", dt.BOOL.code),
    (0x7000, 4, "Inverse_Kinematics", dt.BOOL.code),
    (0x7000, 5, "Blue_LED", dt.BOOL.code),
    (0x7000, 6, "Red_LED", dt.BOOL.code),
    (0x7000, 7, "Button1", dt.BOOL.code),
    (0x7000, 8, "Button2", dt.BOOL.code),
    (0x7000, 9, "Transition_time", dt.INT8.code),
    (0x7010, 1, "Desired_x_value", dt.INT32.code),
    (0x7012, 1, "FilterBandwidth", dt.UINT16.code),
    (0x7014, 1, "Desired_y_value", dt.INT32.code),
    *[(0x7020, i + 1, n, dt.INT16.code) for i, n in enumerate(
        ["Kp100_knee", "Kd1000_knee", "Ki100_knee", "Kp100_hip", "Kd1000_hip", "Ki100_hip"])],
    *[(0x7030, i + 1, n, dt.INT16.code) for i, n in enumerate(
        ["x_cntr_traj1000", "y_cntr_traj1000", "a_ellipse100", "b_ellipse100", "traj_freq100",
         "phase_deg", "FlatnessParam100"])],
]  # fmt: skip
TABLE_4_2 = [
    (0x6010, 1, "hip_angle", dt.INT16.code),
    (0x6010, 2, "desired_hip_angle", dt.INT16.code),
    (0x6012, 1, "Time", dt.UINT16.code),
    (0x6014, 1, "knee_angle", dt.INT16.code),
    (0x6014, 2, "desired_knee_angle", dt.INT16.code),
    (0x6020, 1, "PWM10000_knee", dt.INT16.code),
    (0x6020, 2, "PWM10000_hip", dt.INT16.code),
    (0x6030, 1, "velocity_knee1000", dt.INT32.code),
    (0x6030, 2, "velocity_hip1000", dt.INT32.code),
]


def test_laelaps_leg_identity_sm_dc() -> None:
    (leg,) = load_esi(LEG)
    assert (leg.vendor_id, leg.product_code, leg.type_name) == (0x0A12, 0x00A986FD, "LaelapsII_Leg")
    assert leg.dc_required and leg.assign_activate == 0x0700
    roles = [(s.role, s.start, s.default_size, s.control) for s in leg.sync_managers]
    assert roles == [
        ("MBoxOut", 0x1000, 128, 0x26),
        ("MBoxIn", 0x1080, 128, 0x22),
        ("Outputs", 0x1100, 38, 0x64),
        ("Inputs", 0x1400, 22, 0x20),
    ]
    assert leg.mailbox is not None and leg.mailbox.coe and leg.mailbox.sdo_info
    assert leg.mailbox.protocols == 0x04
    assert leg.fmmus == ("Outputs", "Inputs", "MBoxState")
    assert leg.eeprom.byte_size == 2048 and len(leg.eeprom.config_data) == 14


def test_laelaps_leg_pdos_are_tables_4_1_and_4_2() -> None:
    (leg,) = load_esi(LEG)
    (rx,) = leg.rx_pdos
    (tx,) = leg.tx_pdos
    assert (rx.index, rx.sm, tx.index, tx.sm) == (0x1600, 2, 0x1A00, 3)
    assert [(e.index, e.subindex, e.name, e.data_type) for e in rx.entries] == TABLE_4_1
    assert [(e.index, e.subindex, e.name, e.data_type) for e in tx.entries] == TABLE_4_2
    # The eight bools are bit-packed into one byte, so the outputs are 38 bytes, inputs 22.
    assert rx.bit_length == 38 * 8 and tx.bit_length == 22 * 8
    layout = ProcessLayout.for_device(leg)
    assert (layout.output_bytes, layout.input_bytes) == (38, 22)


def test_laelaps_leg_dictionary() -> None:
    (leg,) = load_esi(LEG)
    name = leg.od_entry(0x1008, 0)
    assert name is not None and name.default == b"LaelapsII_Leg" and name.data_type == 9
    ident = leg.od_object(0x1018)
    assert ident is not None and ident.object_code == 9
    values = {e.subindex: int.from_bytes(e.default, "little") for e in ident.entries}
    assert values == {0: 4, 1: 0x0A12, 2: 0x00A986FD, 3: 1, 4: 0}
    sm_types = leg.od_object(0x1C00)
    assert sm_types is not None
    assert [e.default[0] for e in sm_types.entries] == [4, 1, 2, 3, 4]
    assign = [int.from_bytes(e.default, "little") for e in leg.od_object(0x1C12).entries]  # type: ignore[union-attr]
    assert assign == [1, 0x1600]
    # Mapping object 0x1600 holds the Table 4.1 entries as index<<16 | sub<<8 | bits.
    mapping = leg.od_object(0x1600)
    assert mapping is not None
    values_1600 = [int.from_bytes(e.default, "little") for e in mapping.entries]
    assert values_1600[0] == len(TABLE_4_1)
    assert values_1600[1:] == [p.mapping_value for p in leg.rx_pdos[0].entries]
    state = leg.od_entry(0x7000, 1)
    assert state is not None
    assert (state.access, state.pdo_mapping, state.bit_length) == ("rw", "R", 1)
    hip = leg.od_entry(0x6010, 1)
    assert hip is not None and (hip.access, hip.pdo_mapping) == ("ro", "T")
    for index, sub, name_, code in TABLE_4_1 + TABLE_4_2:
        e = leg.od_entry(index, sub)
        assert e is not None and (e.name, e.data_type) == (name_, code)


def test_generic_io_device() -> None:
    (gio,) = load_esi(GIO)
    assert gio.type_name == "GenericIO" and not gio.dc_required and gio.dc_supported
    layout = ProcessLayout.for_device(gio)
    assert layout.rx_pdos == (0x1600, 0x1601) and layout.tx_pdos == (0x1A00, 0x1A01)
    assert (layout.output_bytes, layout.input_bytes) == (5, 5)
    digital = [f"DigitalOutput{i}" for i in range(1, 9)]
    assert [v.name for v in layout.outputs] == [*digital, "AnalogOutput1", "AnalogOutput2"]
    assert layout.variable("AnalogInput2").key == "0x6010:02"


MINIMAL = """<?xml version="1.0"?>
<EtherCATInfo>
  <Vendor><Id>#x00000002</Id><Name>Test</Name></Vendor>
  <Descriptions>
    <Devices>
      <Device>
        <Type ProductCode="#x00010001" RevisionNo="2">Dev</Type>
        <Name>Dev</Name>
        <Profile><Dictionary>
          <DataTypes>
            <DataType><Name>DT1C12ARR</Name><BaseType>UINT</BaseType><BitSize>32</BitSize>
              <ArrayInfo><LBound>1</LBound><Elements>2</Elements></ArrayInfo></DataType>
            <DataType><Name>DT1C12</Name><BitSize>48</BitSize>
              <SubItem><Name>SubIndex 000</Name><Type>USINT</Type><BitSize>8</BitSize></SubItem>
              <SubItem><Name>Elements</Name><Type>DT1C12ARR</Type><BitSize>32</BitSize></SubItem>
            </DataType>
          </DataTypes>
          <Objects>
            <Object><Index>#x1C12</Index><Name>RxPDO assign</Name><Type>DT1C12</Type>
              <Info>
                <SubItem><Name>SubIndex 000</Name><Info><DefaultData>02</DefaultData></Info></SubItem>
                <SubItem><Name>SubIndex 001</Name><Info><DefaultData>0016</DefaultData></Info></SubItem>
                <SubItem><Name>SubIndex 002</Name><Info><DefaultValue>#x1601</DefaultValue></Info></SubItem>
              </Info></Object>
            <Object><Index>#x6000</Index><Name>Counter</Name><Type>UDINT</Type><BitSize>32</BitSize>
              <Info><DefaultValue>1000</DefaultValue></Info><Flags><Access>ro</Access><PdoMapping>T</PdoMapping></Flags></Object>
          </Objects>
        </Dictionary></Profile>
        <Sm StartAddress="#x1000" ControlByte="#x20" Enable="1">Inputs</Sm>
        <TxPdo Sm="0"><Index>#x1A00</Index><Name>In</Name>
          <Entry><Index>#x6000</Index><SubIndex>0</SubIndex><BitLen>32</BitLen><Name>Counter</Name><DataType>UDINT</DataType></Entry>
          <Entry><Index>#x0</Index><BitLen>4</BitLen></Entry>
          <Entry><Index>#x6001</Index><SubIndex>1</SubIndex><BitLen>4</BitLen><Name>Nibble</Name><DataType>BIT4</DataType></Entry>
        </TxPdo>
      </Device>
    </Devices>
  </Descriptions>
</EtherCATInfo>
"""


def test_minimal_device_arrays_padding_defaults(tmp_path: Path) -> None:
    p = tmp_path / "min.xml"
    p.write_text(MINIMAL)
    (dev,) = load_esi(p)
    assert dev.revision == 2 and dev.mailbox is None and not dev.dc_supported
    assign = dev.od_object(0x1C12)
    assert assign is not None and assign.object_code == 8
    assert [(e.subindex, int.from_bytes(e.default, "little")) for e in assign.entries] == [
        (0, 2),
        (1, 0x1600),
        (2, 0x1601),
    ]
    counter = dev.od_entry(0x6000, 0)
    assert counter is not None and int.from_bytes(counter.default, "little") == 1000
    layout = ProcessLayout.for_device(dev)
    nibble = layout.variable("Nibble")
    assert (nibble.bit_offset, nibble.bit_length, layout.input_bytes) == (36, 4, 5)
    assert len(layout.inputs) == 2  # the padding entry has no variable


def _line_of(text: str, needle: str) -> int:
    return text[: text.index(needle)].count("\n") + 1


# A fault of the file itself: one-line error naming file, line and element.
BAD_FILES = [
    ("<Id>#x00000002</Id>", "<Id>#xZZ</Id>", r"<Id>: not a number: '#xZZ'", "<Id>"),
    ("</Devices>", "</Device>", r"not well-formed XML", None),
]  # fmt: skip

# A fault of one element: that element (or its device) is disabled with one warning line
# naming file, line and element; the rest of the file loads.
BAD_ELEMENTS = [
    ("<DataType>UDINT</DataType></Entry>", "<DataType>UDINTX</DataType></Entry>", r"<DataType>: unknown data type: 'UDINTX' \(PDO #x1A00 skipped\)", "UDINT</DataType></Entry>"),
    ("<BitLen>32</BitLen><Name>Counter", "<BitLen>16</BitLen><Name>Counter", r"<Entry>: BitLen 16 does not match data type UDINT: 16 \(PDO #x1A00 skipped\)", "<BitLen>32</BitLen><Name>Counter"),
    ("<DefaultData>0016", "<DefaultData>0Q16", r"<DefaultData>: DefaultData is not hex bytes: '0Q16' \(default value skipped\)", "<DefaultData>0016"),
    ("<Type>UDINT</Type><BitSize>32", "<Type>DT9999</Type><BitSize>32", r"<Type>: unknown data type: 'DT9999' \(object #x6000 skipped\)", "<Type>UDINT</Type><BitSize>32"),
    ('<TxPdo Sm="0">', '<TxPdo Sm="5">', r"<TxPdo>: PDO names a SyncManager the device does not have: 5 \(PDO #x1A00 skipped\)", "<TxPdo"),
    ("<DefaultValue>1000", "<DefaultValue>1_000", r"<DefaultValue>: DefaultValue is not a number \(default 0 used\): '1_000'", "<DefaultValue>1000"),
    ("<DefaultValue>1000", "<DefaultValue>-5", r"<DefaultValue>: -5 is out of range for uint32 .* \(default 0 used\)", "<DefaultValue>1000"),
    ('<TxPdo Sm="0"><Index>#x1A00', '<TxPdo Sm="0"><Index>#x11A00', r"<Index>: out of range \(0..65535\): '#x11A00' \(PDO #x11A00 skipped\)", '<TxPdo Sm="0">'),
    ('RevisionNo="2"', 'RevisionNo="x2"', r"<Type>: attribute RevisionNo is not a number: 'x2' \(device Dev at line \d+ skipped\)", "<Type Product"),
]  # fmt: skip


@pytest.mark.parametrize(("old", "new", "pattern", "at"), BAD_FILES)
def test_a_broken_file_is_one_line_naming_file_line_element_value(
    tmp_path: Path, old: str, new: str, pattern: str, at: str | None
) -> None:
    assert old in MINIMAL
    text = MINIMAL.replace(old, new, 1)
    p = tmp_path / "bad.xml"
    p.write_text(text)
    with pytest.raises(ConfigError) as info:
        load_esi(p)
    msg = str(info.value)
    assert msg.startswith(f"{p}:") and "\n" not in msg, msg
    assert re.search(pattern, msg), msg
    if at is not None:
        line = _line_of(MINIMAL, at)
        assert msg.startswith(f"{p}:{line}:"), msg


@pytest.mark.parametrize(("old", "new", "pattern", "at"), BAD_ELEMENTS)
def test_a_broken_element_is_disabled_with_one_warning_line(
    tmp_path: Path, old: str, new: str, pattern: str, at: str
) -> None:
    assert old in MINIMAL
    text = MINIMAL.replace(old, new, 1)
    p = tmp_path / "bad.xml"
    p.write_text(text)
    esi = load_esi_file(p)
    line = _line_of(MINIMAL, at)
    lines = [str(w) for w in esi.warnings]
    assert any(w.startswith(f"{p}:{line}:") and re.search(pattern, w) for w in lines), lines
    assert all("\n" not in w for w in lines)


def test_vendor_constructs_load(tmp_path: Path) -> None:
    """What ETG.2000 allows loads: a vendor's SyncManager name (the direction is in the
    ControlByte), a device without ProductCode (a passive terminal), a bit pattern as the
    default of a signed object, a C-style type alias, a Virtual PDO reusing an index, an array
    with LBound 0 used as an object."""
    text = (
        MINIMAL.replace(">Inputs</Sm>", ">DynamicInputs</Sm>", 1)
        .replace("<DefaultValue>1000</DefaultValue>", "<DefaultValue>#x80000000</DefaultValue>", 1)
        .replace("<Type>UDINT</Type><BitSize>32", "<Type>DINT</Type><BitSize>32", 1)
        .replace("<DataType>UDINT</DataType></Entry>", "<DataType>UINT32</DataType></Entry>", 1)
        .replace(
            "</TxPdo>",
            '</TxPdo><TxPdo Virtual="true"><Index>#x1A00</Index><Name>V</Name>'
            "<Entry><Index>#x1D09</Index><SubIndex>#x10</SubIndex><BitLen>8</BitLen>"
            "<Name>Reg</Name><DataType>USINT</DataType></Entry></TxPdo>",
            1,
        )
        .replace(
            "</Devices>",
            "<Device><Type>EndCap</Type><Name>End cap</Name></Device></Devices>",
            1,
        )
        .replace(
            "<DataTypes>",
            "<DataTypes><DataType><Name>ARR0</Name><BaseType>USINT</BaseType><BitSize>16</BitSize>"
            "<ArrayInfo><LBound>0</LBound><Elements>2</Elements></ArrayInfo></DataType>",
            1,
        )
        .replace(
            "<Objects>",
            "<Objects><Object><Index>#x2000</Index><Name>Bytes</Name><Type>ARR0</Type>"
            "<BitSize>16</BitSize></Object>",
            1,
        )
    )
    p = tmp_path / "vendor.xml"
    p.write_text(text)
    esi = load_esi_file(p)
    assert esi.warnings == ()
    dev, cap = esi.devices
    assert dev.sync_managers[0].role == "Inputs" and dev.sync_managers[0].label == "DynamicInputs"
    counter = dev.od_entry(0x6000, 0)
    assert counter is not None and counter.default == b"\x00\x00\x00\x80"
    assert [p.virtual for p in dev.tx_pdos] == [False, True]
    pdo = dev.pdo(0x1A00)
    assert pdo is not None and not pdo.virtual and pdo.entries[0].data_type == dt.UINT32.code
    arr = dev.od_object(0x2000)
    assert arr is not None and [(e.subindex, e.bit_length) for e in arr.entries] == [
        (0, 8),
        (1, 8),
        (2, 8),
    ]
    assert cap.passive and cap.type_name == "EndCap" and cap.product_code == 0


def test_missing_esi_file_and_wrong_root(tmp_path: Path) -> None:
    with pytest.raises(ConfigError, match="ESI file not found"):
        load_esi(tmp_path / "none.xml")
    p = tmp_path / "root.xml"
    p.write_text("<Foo/>")
    with pytest.raises(ConfigError, match=r"root\.xml:1: <Foo>: root element must be"):
        load_esi(p)


def test_profile_numbers_and_state_machine_timeouts(tmp_path: Path) -> None:
    (leg,) = load_esi(LEG)
    assert leg.profile_numbers == (5001,)
    assert leg.timeouts.safeop_op_ms == 10000  # ETG.2000 default: the ESI gives none
    text = MINIMAL.replace(
        "<Name>Dev</Name>",
        "<Name>Dev</Name><Info><StateMachine><Timeout><PreopTimeout>#x7D0</PreopTimeout>"
        "<SafeopOpTimeout>9000</SafeopOpTimeout></Timeout></StateMachine></Info>"
        "<Profile><ChannelInfo><ProfileNo>402</ProfileNo></ChannelInfo>"
        "<ChannelInfo><ProfileNo>402</ProfileNo></ChannelInfo></Profile>",
        1,
    )
    p = tmp_path / "drive.xml"
    p.write_text(text)
    (dev,) = load_esi(p)
    assert dev.profile_numbers == (402, 402)
    assert (dev.timeouts.preop_ms, dev.timeouts.safeop_op_ms) == (2000, 9000)
    assert dev.timeouts.back_to_safeop_ms == 200


def test_oversampling_vendor_categories_and_array_elements_are_honoured(tmp_path: Path) -> None:
    """Issue 17: ``OSFac`` and ``<Eeprom><Category>`` were ignored without a word, and array
    elements took the array's size (IS620N's 0x1C12:01 became 32 bits)."""
    from ether_ros.config.sii import build_sii, parse_sii

    text = MINIMAL.replace('<TxPdo Sm="0">', '<TxPdo Sm="0" OSFac="4">', 1).replace(
        "</TxPdo>",
        "</TxPdo><Eeprom><ByteSize>2048</ByteSize><ConfigData>080C</ConfigData>"
        "<Category><CatNo>2000</CatNo><Data>A1B2C3D4</Data></Category></Eeprom>",
        1,
    )
    p = tmp_path / "osfac.xml"
    p.write_text(text)
    esi = load_esi_file(p)
    (dev,) = esi.devices
    # Oversampling is run at factor 1, and the listing says so (one line naming the PDO).
    assert dev.pdo(0x1A00) is not None and dev.pdo(0x1A00).os_factor == 4  # type: ignore[union-attr]
    assert [n.message for n in esi.notes if "OSFac" in n.message] == [
        "oversampling (OSFac) of 0x1a00: exchanged at factor 1 (one sample per cycle)"
    ]
    # A vendor category goes into the SII as the vendor's tool writes it.
    assert dev.eeprom.categories == ((2000, bytes.fromhex("A1B2C3D4")),)
    image = build_sii(dev)
    assert 2000 in parse_sii(image).categories
    at = image.index(bytes.fromhex("D007") + (2).to_bytes(2, "little") + bytes.fromhex("A1B2C3D4"))
    assert at >= 0x80 and at % 2 == 0
    # An array of UINT has UINT elements, whatever the array's total BitSize.
    assign = dev.od_object(0x1C12)
    assert assign is not None
    assert [(e.subindex, e.bit_length) for e in assign.entries] == [(0, 8), (1, 16), (2, 16)]
