"""The ESI corpus (tests/data/esi): one small file per group of constructs vendors use, and what
the parser makes of each — dictionary, PDOs with their entries, SyncManagers and DC settings —
plus hostile and inconsistent files, which get a one-line error naming file, line and element."""

from __future__ import annotations

import re
from pathlib import Path

import pytest

from ether_ros.config import ProcessLayout, load_bus_config, load_esi
from ether_ros.config import types as dt
from ether_ros.config.esi import EsiDevice, esi_files, is_dictionary_file, load_esi_file
from ether_ros.errors import ConfigError

CORPUS = Path(__file__).resolve().parents[1] / "data" / "esi"


def one(name: str, type_name: str | None = None, revision: int | None = None) -> EsiDevice:
    devices = load_esi(CORPUS / name)
    for d in devices:
        if (type_name is None or d.type_name == type_name) and (
            revision is None or d.revision == revision
        ):
            return d
    raise AssertionError(f"{type_name} rev {revision} not in {name}")


def test_record_with_a_byte_array_subindex_is_one_subindex() -> None:
    # The construct that made a real drive ESI fail: 'duplicate subindex in object 0x58b2'.
    servo = one("servo_vendor_style.xml")
    blob = servo.od_object(0x58B2)
    assert blob is not None and blob.object_code == 9
    assert [(e.subindex, e.bit_length) for e in blob.entries] == [(0, 8), (1, 16), (2, 4096)]
    data = blob.entry(2)
    assert data is not None and data.data_type == dt.OCTET_STRING.code


def test_nested_records_strings_and_bit_arrays() -> None:
    servo = one("servo_vendor_style.xml")
    home = servo.od_entry(0x2010, 1)
    assert home is not None and (home.data_type, home.bit_length) == (0, 64)  # nested record
    status = servo.od_entry(0x2010, 2)
    assert status is not None and status.data_type == dt.BITARR16.code
    flags = servo.od_entry(0x2010, 3)
    assert flags is not None and (flags.data_type, flags.bit_length) == (dt.BITARR8.code, 8)
    name = servo.od_entry(0x1008, 0)
    assert name is not None and name.data_type == dt.STRING.code and name.bit_length == 128
    assert name.default.rstrip(b"\0") == b"CorpusServo"
    label = servo.od_entry(0x2011, 0)
    assert label is not None and label.data_type == dt.UNICODE_STRING.code


def test_assign_arrays_expand_into_elements() -> None:
    servo = one("servo_vendor_style.xml")
    assign = servo.od_object(0x1C12)
    assert assign is not None and assign.object_code == 8
    assert [(e.subindex, int.from_bytes(e.default, "little")) for e in assign.entries] == [
        (0, 1),
        (1, 0x1600),
    ]


def test_fixed_mandatory_virtual_and_excluded_pdos() -> None:
    servo = one("servo_vendor_style.xml")
    p1600, p1601, p1602 = (servo.pdo(i) for i in (0x1600, 0x1601, 0x1602))
    assert p1600 is not None and p1601 is not None and p1602 is not None
    assert p1600.fixed and p1600.sm == 2 and p1600.excludes == (0x1601,)
    assert p1601.excludes == (0x1600,) and p1601.sm is None
    assert p1602.virtual and not p1600.virtual
    tx = servo.pdo(0x1A00)
    assert tx is not None and tx.mandatory
    # Padding inside a PDO keeps its place: 16 + 32 + 8 + 8 bits.
    assert p1601.bit_length == 64 and p1601.entries[-1].is_padding
    # Defaults: the PDOs with an Sm attribute.
    layout = ProcessLayout.for_device(servo)
    assert (layout.output_bytes, layout.input_bytes) == (6, 6)
    assert [v.name for v in layout.outputs] == ["Controlword", "Target position"]


def test_sync_managers_dc_profile_and_timeouts() -> None:
    servo = one("servo_vendor_style.xml")
    out = servo.sm("Outputs")
    assert out is not None and out.default_size == 0 and out.start == 0x1100  # no DefaultSize
    assert [m.assign_activate for m in servo.dc_opmodes] == [0x0000, 0x0300]
    assert servo.dc_supported and not servo.dc_required
    assert servo.profile_numbers == (402,)
    assert servo.timeouts.safeop_op_ms == 9000  # "#x2328"
    assert servo.name == "Corpus servo drive"  # the English name of several
    assert servo.mailbox is not None and servo.mailbox.coe and servo.mailbox.pdo_assign


def test_several_devices_and_revisions_in_latin1_with_decimal_numbers() -> None:
    devices = load_esi(CORPUS / "multi_device_latin1.xml")
    assert [(d.type_name, d.revision) for d in devices] == [
        ("CorpusDIO8", 1),
        ("CorpusDIO8", 2),
        ("CorpusDIO16", 1),
    ]
    first = devices[0]
    assert first.vendor_id == 0xA12 and first.product_code == 4097
    assert first.vendor_name == "Gerätebau Müller (CSL-EP)"
    assert first.name == "8 Kanäle digital, Rev. 1"
    assert ProcessLayout.for_device(devices[2]).input_bytes == 2
    assert first.eeprom.byte_size == 1024


def test_utf16_file_and_a_device_without_mailbox() -> None:
    (analog,) = load_esi(CORPUS / "analog_utf16.xml")
    assert analog.name == "Analog 2 channels ±10 V"
    assert analog.mailbox is None and analog.objects == ()
    layout = ProcessLayout.for_device(analog)
    assert [v.name for v in layout.inputs] == ["Input 1", "Input 2"]
    assert (layout.output_bytes, layout.input_bytes) == (4, 4)


def test_modules_slots_and_alternative_sm_mappings() -> None:
    coupler = one("modular_coupler.xml")
    assert [m.type_name for m in coupler.modules] == ["CorpusModuleDI8", "CorpusModuleDO8"]
    di8 = coupler.modules[0]
    assert di8.ident == 0x00010001 and [p.index for p in di8.tx_pdos] == [0x1A10]
    assert [(s.name, s.default_ident) for s in coupler.slots] == [
        ("Slot 1", 0x00010001),
        ("Slot 2", None),
    ]
    assert coupler.slots[0].module_idents == (0x00010001, 0x00010002)
    assert coupler.alternative_sm_mappings == ("Standard", "Status only")
    assert coupler.od_entry(0xF000, 2) is not None


def test_dictionary_from_a_dictionary_file() -> None:
    counter = one("dictfile_counter.xml")
    entry = counter.od_entry(0x6000, 0)
    assert entry is not None and entry.data_type == dt.UINT32.code and entry.pdo_mapping == "T"
    assert counter.od_entry(0x1018, 2) is not None


SOE_DRIVE = """<?xml version="1.0"?>
<EtherCATInfo><Vendor><Id>2</Id></Vendor><Descriptions><Devices>
<Device><Type ProductCode="#x13ed6012" RevisionNo="1">SoeDrive</Type>
<Profile><DictionaryFile>{ref}</DictionaryFile></Profile>
<Sm MinSize="128" MaxSize="128" DefaultSize="128" StartAddress="#x1800" ControlByte="#x26"
 Enable="1">MBoxOut</Sm>
<Sm MinSize="128" MaxSize="128" DefaultSize="128" StartAddress="#x1a00" ControlByte="#x22"
 Enable="1">MBoxIn</Sm>
<Mailbox><SoE/></Mailbox>
</Device></Devices></Descriptions></EtherCATInfo>
"""

# Beckhoff's dictionary files: root <EtherCATDict>; enumerations and display variants as
# <DataType>s with only a name and a BitSize.
IDN_DICTIONARY = """<?xml version="1.0" encoding="utf-8"?>
<EtherCATDict><Dictionary><DataTypes>
<DataType><Name>UINT</Name><BitSize>16</BitSize></DataType>
<DataType><Name>UINT_IDN</Name><BitSize>16</BitSize></DataType>
<DataType><Name>DT_Mode</Name><BitSize>16</BitSize>
 <EnumInfo><Text>Cancel</Text><Enum>0</Enum></EnumInfo></DataType>
<DataType><Name>DT_Flag</Name><BitSize>1</BitSize></DataType>
<DataType><Name>DT_Bits</Name><BitSize>16</BitSize>
 <SubItem><Name>Bit 0</Name><Type>DT_Flag</Type><BitSize>1</BitSize><BitOffs>0</BitOffs></SubItem>
 <SubItem><Name>Bit 1</Name><Type>DT_Flag</Type><BitSize>1</BitSize><BitOffs>1</BitOffs></SubItem>
</DataType>
</DataTypes><Objects>
<Object><Index>1</Index><Name>Control unit cycle time (TNcyc)</Name><Type>UINT</Type>
 <BitSize>16</BitSize></Object>
<Object><Index>16</Index><Name>AT configuration</Name><Type>UINT_IDN</Type>
 <BitSize>16</BitSize></Object>
<Object><Index>32789</Index><Name>Procedure</Name><Type>DT_Mode</Type><BitSize>16</BitSize></Object>
<Object><Index>11</Index><Name>Class 1 diagnostic</Name><Type>DT_Bits</Type>
 <BitSize>16</BitSize></Object>
</Objects></Dictionary></EtherCATDict>
"""


@pytest.mark.parametrize(
    "ref",
    [
        "Drives\\Soe Drive Dict.xml",  # as the vendor writes it: a Windows path
        "drives/SOE DRIVE DICT.XML",  # another case: the vendor's tools ignore case
    ],
)
def test_a_dictionary_file_in_a_sub_folder_named_with_a_windows_path(
    tmp_path: Path, ref: str
) -> None:
    (tmp_path / "Drives").mkdir()
    (tmp_path / "Drives" / "Soe Drive Dict.xml").write_text(IDN_DICTIONARY)
    esi_path = tmp_path / "Drives.xml"
    esi_path.write_text(SOE_DRIVE.format(ref=ref))
    esi = load_esi_file(esi_path)
    assert esi.warnings == ()
    (drive,) = esi.devices
    # A Sercos drive's dictionary is its IDNs, apart from the CoE dictionary it lacks.
    assert drive.objects == ()
    idns = {o.index: o for o in drive.idns}
    assert sorted(idns) == [1, 11, 16, 32789]
    # Size-only types: unsigned integers of their BitSize (enumerations included).
    assert idns[16].entries[0].data_type == dt.UINT16.code
    assert idns[32789].entries[0].data_type == dt.UINT16.code
    assert [(e.name, e.bit_length) for e in idns[11].entries] == [("Bit 0", 1), ("Bit 1", 1)]
    # The folder's ESI files leave the dictionary out; loading it directly says what it is.
    assert esi_files(tmp_path) == [esi_path]
    assert is_dictionary_file(tmp_path / "Drives" / "Soe Drive Dict.xml")
    with pytest.raises(ConfigError, match=r"Dict\.xml:2: <EtherCATDict>: a dictionary file"):
        load_esi_file(tmp_path / "Drives" / "Soe Drive Dict.xml")


def test_a_missing_or_escaping_dictionary_file_is_a_warning_naming_it(tmp_path: Path) -> None:
    for ref, why in [
        ("Drives\\Other Dict.xml", r"not found in the ESI's folder \(not read\): 'Drives/Other"),
        ("..\\outside.xml", r"must name a file in the ESI's folder"),
        ("C:\\TwinCAT\\Dict.xml", r"must name a file in the ESI's folder"),
    ]:
        esi_path = tmp_path / "Drive.xml"
        esi_path.write_text(SOE_DRIVE.format(ref=ref))
        esi = load_esi_file(esi_path)
        (warning,) = esi.warnings
        assert re.search(why, str(warning)), warning
        assert esi.devices[0].idns == ()


HEADER = '<?xml version="1.0"?>\n'
SHELL = (
    "<EtherCATInfo><Vendor><Id>1</Id></Vendor><Descriptions><Devices><Device>"
    '<Type ProductCode="1">X</Type>{body}</Device></Devices></Descriptions></EtherCATInfo>'
)


def _dictionary(types: str, objects: str) -> str:
    return (
        f"<Profile><Dictionary><DataTypes>{types}</DataTypes><Objects>{objects}</Objects>"
        "</Dictionary></Profile>"
    )


HOSTILE = [
    pytest.param(
        '<!DOCTYPE lol [<!ENTITY a "aaaaaaaaaa"><!ENTITY b "&a;&a;&a;&a;&a;&a;&a;&a;">]>\n'
        + SHELL.format(body="<Name>&b;</Name>"),
        r":1: <!DOCTYPE>: document type declarations \(DTD, entities\) are not supported",
        id="entity-expansion",
    ),
    pytest.param(
        '<!DOCTYPE x [<!ENTITY e SYSTEM "file:///etc/passwd">]>\n'
        + SHELL.format(body="<Name>&e;</Name>"),
        r"<!DOCTYPE>",
        id="external-entity",
    ),
    pytest.param(
        SHELL.format(
            body=_dictionary(
                "<DataType><Name>HUGE</Name><BaseType>USINT</BaseType><BitSize>8</BitSize>"
                "<ArrayInfo><LBound>1</LBound><Elements>1000000000</Elements></ArrayInfo>"
                "</DataType>",
                "",
            )
        ),
        r"<Elements>: out of range \(0\.\.65535\): '1000000000' \(data type skipped\)",
        id="huge-array",
    ),
    pytest.param(
        SHELL.format(
            body=_dictionary(
                "",
                "<Object><Index>#x2000</Index><Name>big</Name><Type>USINT</Type>"
                "<BitSize>2147483648</BitSize></Object>",
            )
        ),
        r"<BitSize>: out of range \(0\.\.65535\): '2147483648' \(object #x2000 skipped\)",
        id="huge-bitsize",
    ),
    pytest.param(
        SHELL.format(
            body=_dictionary(
                "<DataType><Name>DT2000</Name><BitSize>16</BitSize><SubItem><SubIdx>0</SubIdx>"
                "<Name>a</Name><Type>UDINT</Type><BitSize>32</BitSize><BitOffs>0</BitOffs>"
                "</SubItem></DataType>",
                "",
            )
        ),
        r"<SubItem>: subitem ends at bit 32, beyond its DataType's BitSize 16: 'a'",
        id="inconsistent-bitsize",
    ),
    pytest.param(
        SHELL.format(
            body=_dictionary(
                "<DataType><Name>ARR</Name><BaseType>UINT</BaseType><BitSize>4800</BitSize>"
                "<ArrayInfo><LBound>1</LBound><Elements>300</Elements></ArrayInfo></DataType>",
                "<Object><Index>#x2000</Index><Name>a</Name><Type>ARR</Type>"
                "<BitSize>4800</BitSize></Object>",
            )
        ),
        r"<DataType>: array of 300 elements from subindex 1 does not fit in subindices 1..255",
        id="array-beyond-subindex-255",
    ),
    pytest.param(
        SHELL.format(body="<Profile><DictionaryFile>../../etc/passwd</DictionaryFile></Profile>"),
        r"<DictionaryFile>: DictionaryFile must name a file in the ESI's folder",
        id="dictionary-file-outside",
    ),
]


@pytest.mark.parametrize(("text", "pattern"), HOSTILE)
def test_hostile_and_inconsistent_files_get_one_line_errors(
    tmp_path: Path, text: str, pattern: str
) -> None:
    """A hostile file is refused, or the element it abuses is disabled: either way one line
    naming file, line and element, and nothing unbounded happens."""
    p = tmp_path / "hostile.xml"
    p.write_text(HEADER + text)
    try:
        esi = load_esi_file(p)
    except ConfigError as exc:
        message = str(exc)
    else:
        assert len(esi.warnings) == 1, esi.warnings
        message = str(esi.warnings[0])
    assert re.search(pattern, message), message
    assert "\n" not in message and message.startswith(str(p))


def _corpus_config(tmp_path: Path, slaves: str) -> Path:
    p = tmp_path / "corpus.yaml"
    p.write_text(f"bus: {{name: corpus, cycle_us: 1000}}\nesi: [{CORPUS}]\nslaves:\n{slaves}")
    return p


def test_config_picks_devices_and_revisions_from_the_corpus(tmp_path: Path) -> None:
    cfg = load_bus_config(
        _corpus_config(
            tmp_path,
            "  - {name: old, position: 0, device: CorpusDIO8, revision: 1}\n"
            "  - {name: new, position: 1, device: CorpusDIO8}\n"
            "  - {name: servo, position: 2, device: CorpusServo,"
            " pdo_assign: {rx: [0x1601], tx: [0x1A00]}}\n",
        )
    )
    old, new, servo = cfg.slaves
    assert (old.esi.revision, new.esi.revision) == (1, 2)  # newest unless a revision is given
    assert [v.name for v in servo.layout.outputs][-1] == "Modes of operation"


def test_assigning_pdos_that_exclude_each_other_is_refused(tmp_path: Path) -> None:
    from ether_ros.config import load_bus_config

    path = _corpus_config(
        tmp_path,
        "  - {name: servo, position: 0, device: CorpusServo,"
        " pdo_assign: {rx: [0x1600, 0x1601], tx: [0x1A00]}}\n",
    )
    with pytest.raises(ConfigError, match=r"PDO 0x1600 excludes 0x1601 \(ESI <Exclude>\)"):
        load_bus_config(path)


def test_the_simulator_refuses_a_device_its_chip_cannot_carry(tmp_path: Path) -> None:
    """The servo's four SyncManagers fit an ET1200; a fifth one does not, and a config that asks
    for it gets one line naming the config, the slave and what does not fit."""
    from dataclasses import replace

    from ether_ros._native import SimNetwork
    from ether_ros.config.esi import SyncManagerDesc
    from ether_ros.sim.network import build_network
    from ether_ros.sim.spec import device_spec

    servo = one("servo_vendor_style.xml")
    SimNetwork().add_slave(device_spec(servo, name="ok", esc="et1200"))
    fifth = SyncManagerDesc(
        number=4, role="", start=0x1300, default_size=0, control=0, enable=False
    )
    wide = replace(servo, sync_managers=(*servo.sync_managers, fifth))
    with pytest.raises(
        ValueError,
        match=r"slave 'wide': cannot emulate: the device describes 5 SyncManagers, the ET1200 h",
    ):
        SimNetwork().add_slave(device_spec(wide, name="wide", esc="et1200"))
    SimNetwork().add_slave(device_spec(wide, name="wide", esc="et1100"))

    cfg = load_bus_config(
        _corpus_config(
            tmp_path, "  - {name: drive, position: 0, device: CorpusServo, sim: {esc: lan9252}}\n"
        )
    )
    cfg.slaves[0]._esi = wide  # the same device with the fifth SyncManager
    with pytest.raises(
        ConfigError, match=r"corpus.yaml: slave 'drive': cannot emulate: .* LAN9252 has 4"
    ):
        build_network(cfg)
