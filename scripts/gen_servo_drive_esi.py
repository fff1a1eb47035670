"""Generate devices/servo_drive.xml: the ESI of our simulated CiA 402 servo drives.

The file is derived, not hand-written: a 2-axis drive repeats every axis object 0x800 higher
(ETG.6010 multi-axis layout), which is easy to get wrong by hand. Edit the tables here and run
``python scripts/gen_servo_drive_esi.py`` to rewrite the file; the unit test
tests/unit/test_servo_drive_esi.py checks the result.

The default values match the simulator's defaults for a small robot-joint servo
(crates/sim/src/devices/cia402.rs, docs/cia402-simulator.md).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from xml.sax.saxutils import escape

VENDOR_ID = 0x00000A12
AXIS_OFFSET = 0x800

# Defaults shared with the simulator (crates/sim/src/devices/cia402.rs `Cia402Config`).
COUNTS_PER_REV = 16384  # 14-bit absolute magnetic encoder on the motor shaft
GEAR_RATIO = 50  # motor revolutions per joint revolution
RATED_TORQUE_MNM = 200  # 0x6076: 0.2 Nm motor rated torque
MAX_TORQUE_PERMILLE = 3000  # 0x6072: 300 % of rated = 0.6 Nm peak
MAX_MOTOR_SPEED_RPM = 6000  # 0x6080
SUPPORTED_MODES = (
    (1 << 0) | (1 << 2) | (1 << 5) | (1 << 7) | (1 << 8) | (1 << 9)
)  # PP PV HM CSP..CST
# 0x60E3: homing on the index pulse (33 negative, 34 positive direction), on the home switch
# (19: switch on the positive side, home at its edge), on the current position (35, 37).
HOMING_METHODS = (19, 33, 34, 35, 37)

BASIC_BITS = {"BOOL": 1, "SINT": 8, "USINT": 8, "INT": 16, "UINT": 16, "DINT": 32, "UDINT": 32}
SIGNED = {"SINT", "INT", "DINT"}


@dataclass(frozen=True)
class Var:
    """A VAR object: (offset index, name, type, access, PDO mapping 'R'/'T'/'', default)."""

    index: int
    name: str
    type_name: str
    access: str = "rw"
    pdo: str = ""
    default: int = 0


@dataclass(frozen=True)
class Sub:
    name: str
    type_name: str
    access: str = "rw"
    default: int = 0
    subindex: int | None = None  # None: the next one
    pdo: str = ""  # PDO mapping flag of the subindex: "", "R" or "T"


@dataclass(frozen=True)
class Record:
    """A RECORD/ARRAY object with subindex 0 (the count) followed by ``subs``."""

    index: int
    name: str
    type_name: str  # DataType name, shared by the axes
    subs: tuple[Sub, ...]
    sub0_access: str = "ro"
    count: int | None = None  # subindex 0 value (default: number of subs)


# The CiA 402 objects of one axis (IEC 61800-7-201), at their axis-1 index.
AXIS_VARS = (
    Var(0x603F, "Error code", "UINT", "ro", "T"),
    Var(0x6040, "Controlword", "UINT", "rw", "R"),
    Var(0x6041, "Statusword", "UINT", "ro", "T"),
    Var(0x605A, "Quick stop option code", "INT", "rw", "", 2),
    Var(0x6060, "Modes of operation", "SINT", "rw", "R"),
    Var(0x6061, "Modes of operation display", "SINT", "ro", "T"),
    Var(0x6064, "Position actual value", "DINT", "ro", "T"),
    Var(0x6065, "Following error window", "UDINT", "rw", "", COUNTS_PER_REV),
    Var(0x6066, "Following error time out", "UINT", "rw", "", 10),
    # Target reached windows of PP (1 % of a motor revolution) and PV (0.1 motor rev/s).
    Var(0x6067, "Position window", "UDINT", "rw", "", COUNTS_PER_REV // 100),
    Var(0x606C, "Velocity actual value", "DINT", "ro", "T"),
    Var(0x606D, "Velocity window", "UINT", "rw", "", COUNTS_PER_REV // 10),
    Var(0x6071, "Target torque", "INT", "rw", "R"),
    Var(0x6072, "Max torque", "UINT", "rw", "R", MAX_TORQUE_PERMILLE),
    Var(0x6076, "Motor rated torque", "UDINT", "rw", "", RATED_TORQUE_MNM),
    Var(0x6077, "Torque actual value", "INT", "ro", "T"),
    Var(0x607A, "Target position", "DINT", "rw", "R"),
    Var(0x607C, "Home offset", "DINT", "rw", ""),
    Var(0x6080, "Max motor speed", "UDINT", "rw", "", MAX_MOTOR_SPEED_RPM),
    # Profile velocity 1 motor rev/s; acceleration/deceleration 10 motor rev/s².
    Var(0x6081, "Profile velocity", "UDINT", "rw", "R", COUNTS_PER_REV),
    Var(0x6083, "Profile acceleration", "UDINT", "rw", "", 10 * COUNTS_PER_REV),
    Var(0x6084, "Profile deceleration", "UDINT", "rw", "", 10 * COUNTS_PER_REV),
    # Quick stop deceleration: 100 motor rev/s² (stops from full speed in 1 s).
    Var(0x6085, "Quick stop deceleration", "UDINT", "rw", "", 100 * COUNTS_PER_REV),
    Var(0x6098, "Homing method", "SINT", "rw", "", 37),
    Var(0x609A, "Homing acceleration", "UDINT", "rw", "", 10 * COUNTS_PER_REV),
    # Offsets added to the velocity (CSP, CSV) and torque (CSP, CSV, CST) commands: feed-forward.
    Var(0x60B1, "Velocity offset", "DINT", "rw", "R"),
    Var(0x60B2, "Torque offset", "INT", "rw", "R"),
    # Touch probe 1: function (enable, single/continuous, source: home switch or index pulse,
    # edges), status, and the positions latched at its edges.
    Var(0x60B8, "Touch probe function", "UINT", "rw", "R"),
    Var(0x60B9, "Touch probe status", "UINT", "ro", "T"),
    Var(0x60BA, "Touch probe 1 positive edge", "DINT", "ro", "T"),
    Var(0x60BB, "Touch probe 1 negative edge", "DINT", "ro", "T"),
    Var(0x60F4, "Following error actual value", "DINT", "ro", "T"),
    # Bit 0 negative limit switch, 1 positive limit switch, 2 home switch; 16-31 the
    # manufacturer's inputs (wired to outputs 16-31 of 0x60FE in the simulated drive).
    Var(0x60FD, "Digital inputs", "UDINT", "ro", "T"),
    Var(0x60FF, "Target velocity", "DINT", "rw", "R"),
    Var(0x6502, "Supported drive modes", "UDINT", "ro", "", SUPPORTED_MODES),
)

AXIS_RECORDS = (
    Record(
        0x607D,
        "Software position limit",
        "DT607D",
        (
            Sub("Min position limit", "DINT", default=-(2**31)),
            Sub("Max position limit", "DINT", default=2**31 - 1),
        ),
    ),
    Record(
        0x608F,
        "Position encoder resolution",
        "DT608F",
        (
            Sub("Encoder increments", "UDINT", default=COUNTS_PER_REV),
            Sub("Motor revolutions", "UDINT", default=1),
        ),
    ),
    Record(
        0x6091,
        "Gear ratio",
        "DT6091",
        (
            Sub("Motor revolutions", "UDINT", default=GEAR_RATIO),
            Sub("Shaft revolutions", "UDINT", default=1),
        ),
    ),
    Record(
        0x6099,
        "Homing speeds",
        "DT6099",
        (
            Sub("Speed during search for switch", "UDINT", default=COUNTS_PER_REV),
            Sub("Speed during search for zero", "UDINT", default=COUNTS_PER_REV // 4),
        ),
    ),
    Record(
        0x60E3,
        "Supported homing methods",
        "DT60E3",
        tuple(Sub(f"Homing method {k + 1}", "SINT", "ro", m) for k, m in enumerate(HOMING_METHODS)),
    ),
    Record(
        0x60FE,
        "Digital outputs",
        "DT60FE",
        (
            Sub("Physical outputs", "UDINT", pdo="R"),
            Sub("Bit mask", "UDINT", default=0xFFFF0000, pdo="R"),
        ),
    ),
    Record(
        0x60C2,
        "Interpolation time period",
        "DT60C2",
        (
            Sub("Interpolation time period value", "USINT", default=1),
            Sub("Interpolation time index", "SINT", default=-3),
        ),
    ),
)


def _sync_params(index: int, name: str) -> Record:
    """0x1C32 / 0x1C33 (ETG.1020 SM output/input parameters): sync type 0 free run, 2 DC SYNC0."""
    return Record(
        index,
        name,
        f"DT{index:04X}",
        (
            Sub("Sync mode", "UINT", "rw", 0, 1),
            Sub("Cycle time", "UDINT", "rw", 1_000_000, 2),
            Sub("Shift time", "UDINT", "ro", 0, 3),
            # Bit 0 free run, bit 1 SM synchronous, bits 2-3 = 01 DC SYNC0.
            Sub("Sync modes supported", "UINT", "ro", 0x0007, 4),
            Sub("Minimum cycle time", "UDINT", "ro", 125_000, 5),
            Sub("Calc and copy time", "UDINT", "ro", 20_000, 6),
            Sub("Get cycle time", "UINT", "rw", 0, 8),
            Sub("Delay time", "UDINT", "ro", 10_000, 9),
            Sub("Sync0 cycle time", "UDINT", "rw", 1_000_000, 10),
            Sub("SM event missed", "UINT", "ro", 0, 11),
            Sub("Cycle time too small", "UINT", "ro", 0, 12),
            Sub("Sync error", "BOOL", "ro", 0, 32),
        ),
        count=32,
    )


RX_ENTRIES = ((0x6040, "UINT"), (0x6060, "SINT"), (0, "pad8"), (0x607A, "DINT"))
RX_ENTRIES += ((0x60FF, "DINT"), (0x6071, "INT"))
TX_ENTRIES = ((0x6041, "UINT"), (0x6061, "SINT"), (0, "pad8"), (0x6064, "DINT"))
TX_ENTRIES += ((0x606C, "DINT"), (0x6077, "INT"), (0x603F, "UINT"), (0x60F4, "DINT"))
MAPPING_CAPACITY = 16  # entries a remapped PDO may hold


def _hex(value: int, bits: int) -> str:
    nbytes = max(1, (bits + 7) // 8)
    return (value & ((1 << (8 * nbytes)) - 1)).to_bytes(nbytes, "little").hex().upper()


def _entry_bits(type_name: str) -> int:
    return 8 if type_name == "pad8" else BASIC_BITS[type_name]


def _mapping_value(index: int, type_name: str) -> int:
    return (index << 16) | _entry_bits(type_name) if index else _entry_bits(type_name)


def _var_names() -> dict[int, str]:
    return {v.index: v.name for v in AXIS_VARS}


class Writer:
    def __init__(self) -> None:
        self.lines: list[str] = []

    def add(self, indent: int, text: str) -> None:
        self.lines.append("  " * indent + text)


def _subitem_type(w: Writer, name: str, subs: list[tuple[int, str, str, int, str]]) -> None:
    """A record DataType; ``subs`` = (subindex, name, type, bits, access), subindex 0 first."""
    offset = 0
    items = []
    for sub, sname, tname, bits, access_pdo in subs:
        if bits >= 16 and offset % 16:
            offset += 16 - offset % 16
        # "rw/R": access rw, mappable into RxPDOs.
        access, _, pdo = access_pdo.partition("/")
        mapping = f"<PdoMapping>{pdo}</PdoMapping>" if pdo else ""
        items.append(
            f"<SubItem><SubIdx>{sub}</SubIdx><Name>{escape(sname)}</Name><Type>{tname}</Type>"
            f"<BitSize>{bits}</BitSize><BitOffs>{offset}</BitOffs>"
            f"<Flags><Access>{access}</Access>{mapping}</Flags></SubItem>"
        )
        offset += bits
        if sub == 0:
            offset = 16  # ETG.2000: subindex 0 padded to 16 bits
    total = offset + (-offset % 16)
    w.add(7, f"<DataType><Name>{name}</Name><BitSize>{total}</BitSize>")
    for item in items:
        w.add(8, item)
    w.add(7, "</DataType>")


def _record_subs(rec: Record) -> list[tuple[int, str, str, int, str]]:
    rows = [(0, "SubIndex 000", "USINT", 8, rec.sub0_access)]
    nxt = 1
    for s in rec.subs:
        sub = s.subindex if s.subindex is not None else nxt
        access = f"{s.access}/{s.pdo}" if s.pdo else s.access
        rows.append((sub, s.name, s.type_name, BASIC_BITS[s.type_name], access))
        nxt = sub + 1
    return rows


def _record_bits(rec: Record) -> int:
    offset = 16
    for _, _, _, bits, _ in _record_subs(rec)[1:]:
        if bits >= 16 and offset % 16:
            offset += 16 - offset % 16
        offset += bits
    return offset + (-offset % 16)


def _object_var(w: Writer, index: int, name: str, type_name: str, default: str, flags: str) -> None:
    bits = BASIC_BITS.get(type_name, 0)
    w.add(
        7,
        f"<Object><Index>#x{index:04X}</Index><Name>{escape(name)}</Name><Type>{type_name}</Type>"
        f"<BitSize>{bits}</BitSize><Info>{default}</Info><Flags>{flags}</Flags></Object>",
    )


def _flags(access: str, pdo: str) -> str:
    mapping = f"<PdoMapping>{pdo}</PdoMapping>" if pdo else ""
    return f"<Access>{access}</Access>{mapping}"


def _object_record(
    w: Writer, index: int, name: str, type_name: str, bits: int, defaults: list[tuple[str, str]]
) -> None:
    w.add(7, f"<Object><Index>#x{index:04X}</Index><Name>{escape(name)}</Name>")
    w.add(8, f"<Type>{type_name}</Type><BitSize>{bits}</BitSize>")
    w.add(8, "<Info>")
    for sname, data in defaults:
        w.add(
            9,
            f"<SubItem><Name>{escape(sname)}</Name><Info><DefaultData>{data}</DefaultData>"
            "</Info></SubItem>",
        )
    w.add(8, "</Info>")
    w.add(8, "<Flags><Access>ro</Access></Flags>")
    w.add(7, "</Object>")


def _record_object(w: Writer, rec: Record, index: int) -> None:
    defaults = [("SubIndex 000", _hex(rec.count or len(rec.subs), 8))]
    defaults += [(s.name, _hex(s.default, BASIC_BITS[s.type_name])) for s in rec.subs]
    _object_record(w, index, rec.name, rec.type_name, _record_bits(rec), defaults)


def _mapping_type(w: Writer, name: str, access: str, count: int) -> None:
    rows = [(0, "SubIndex 000", "USINT", 8, access)]
    rows += [(k, f"SubIndex {k:03d}", t, b, access) for k, t, b in _slots(count)]
    _subitem_type(w, name, rows)


def _slots(count: int) -> list[tuple[int, str, int]]:
    return [(k, "UDINT", 32) for k in range(1, count + 1)]


def _mapping_bits(count: int) -> int:
    return 16 + 32 * count


def _pdo_xml(
    w: Writer, tag: str, index: int, name: str, sm: int, entries: tuple[tuple[int, str], ...]
) -> None:
    names = _var_names()
    w.add(4, f'<{tag} Mandatory="0" Sm="{sm}">')
    w.add(5, f"<Index>#x{index:04X}</Index>")
    w.add(5, f"<Name>{escape(name)}</Name>")
    for entry_index, type_name in entries:
        if entry_index == 0:
            w.add(5, "<Entry><Index>#x0</Index><BitLen>8</BitLen></Entry>")
            continue
        base = entry_index - (entry_index - 0x6000) // AXIS_OFFSET * AXIS_OFFSET
        w.add(
            5,
            f"<Entry><Index>#x{entry_index:04X}</Index><SubIndex>0</SubIndex>"
            f"<BitLen>{BASIC_BITS[type_name]}</BitLen><Name>{escape(names[base])}</Name>"
            f"<DataType>{type_name}</DataType></Entry>",
        )
    w.add(4, f"</{tag}>")


def _axis_entries(entries: tuple[tuple[int, str], ...], axis: int) -> tuple[tuple[int, str], ...]:
    return tuple((i + axis * AXIS_OFFSET if i else 0, t) for i, t in entries)


def _pdo_bytes(entries: tuple[tuple[int, str], ...]) -> int:
    return sum(_entry_bits(t) for _, t in entries) // 8


def device(w: Writer, axes: int, product: int, type_name: str, title: str) -> None:
    w.add(3, '<Device Physics="YY">')
    w.add(4, f'<Type ProductCode="#x{product:08X}" RevisionNo="#x00000001">{type_name}</Type>')
    w.add(4, f'<Name LcId="1033">{escape(title)}</Name>')
    w.add(4, "<GroupType>ServoDrive</GroupType>")
    w.add(4, "<Profile>")
    if axes == 1:
        w.add(5, "<ProfileNo>402</ProfileNo>")
    else:
        for _ in range(axes):
            w.add(5, "<ChannelInfo><ProfileNo>402</ProfileNo></ChannelInfo>")
    w.add(5, "<Dictionary>")
    w.add(6, "<DataTypes>")
    for t, bits in BASIC_BITS.items():
        w.add(7, f"<DataType><Name>{t}</Name><BitSize>{bits}</BitSize></DataType>")
    w.add(
        7,
        f"<DataType><Name>STRING({len(type_name)})</Name>"
        f"<BitSize>{8 * len(type_name)}</BitSize></DataType>",
    )
    identity = [(0, "SubIndex 000", "USINT", 8, "ro")]
    identity += [
        (k, n, "UDINT", 32, "ro")
        for k, n in enumerate(("Vendor ID", "Product code", "Revision", "Serial number"), 1)
    ]
    _subitem_type(w, "DT1018", identity)
    sm_type = [(0, "SubIndex 000", "USINT", 8, "ro")]
    sm_type += [(k, f"SubIndex {k:03d}", "USINT", 8, "ro") for k in range(1, 5)]
    _subitem_type(w, "DT1C00", sm_type)
    _mapping_type(w, "DTPDOMAP", "rw", MAPPING_CAPACITY)
    assign = [(0, "SubIndex 000", "USINT", 8, "rw")]
    assign += [(k, f"SubIndex {k:03d}", "UINT", 16, "rw") for k in range(1, axes + 1)]
    _subitem_type(w, "DTPDOASSIGN", assign)
    for rec in (*AXIS_RECORDS, _sync_params(0x1C32, ""), _sync_params(0x1C33, "")):
        _subitem_type(w, rec.type_name, _record_subs(rec))
    w.add(6, "</DataTypes>")
    w.add(6, "<Objects>")
    _object_var(
        w,
        0x1000,
        "Device type",
        "UDINT",
        f"<DefaultData>{_hex(0x00020192, 32)}</DefaultData>",
        _flags("ro", ""),
    )
    _object_var(
        w, 0x1001, "Error register", "USINT", "<DefaultData>00</DefaultData>", _flags("ro", "")
    )
    w.add(
        7,
        f"<Object><Index>#x1008</Index><Name>Device name</Name><Type>STRING({len(type_name)})"
        f"</Type><BitSize>{8 * len(type_name)}</BitSize><Info><DefaultString>{type_name}"
        "</DefaultString></Info><Flags><Access>ro</Access></Flags></Object>",
    )
    _object_record(
        w,
        0x1018,
        "Identity",
        "DT1018",
        144,
        [
            ("SubIndex 000", "04"),
            ("Vendor ID", _hex(VENDOR_ID, 32)),
            ("Product code", _hex(product, 32)),
            ("Revision", _hex(1, 32)),
            ("Serial number", _hex(0, 32)),
        ],
    )
    for base, entries, label in (
        (0x1600, RX_ENTRIES, "RxPDO"),
        (0x1A00, TX_ENTRIES, "TxPDO"),
    ):
        for axis in range(axes):
            mapped = _axis_entries(entries, axis)
            defaults = [("SubIndex 000", _hex(len(mapped), 8))]
            defaults += [
                (
                    f"SubIndex {k:03d}",
                    _hex(_mapping_value(i, t), 32) if k <= len(mapped) else "00000000",
                )
                for k, (i, t) in enumerate(
                    (*mapped, *[(0, "pad8")] * (MAPPING_CAPACITY - len(mapped))), 1
                )
            ]
            _object_record(
                w,
                base + 0x10 * axis,
                f"{label} mapping axis {axis + 1}",
                "DTPDOMAP",
                _mapping_bits(MAPPING_CAPACITY),
                defaults,
            )
    _object_record(
        w,
        0x1C00,
        "Sync manager type",
        "DT1C00",
        48,
        [("SubIndex 000", "04")] + [(f"SubIndex {k:03d}", f"{k:02X}") for k in range(1, 5)],
    )
    for index, base, label in ((0x1C12, 0x1600, "RxPDO assign"), (0x1C13, 0x1A00, "TxPDO assign")):
        defaults = [("SubIndex 000", _hex(axes, 8))]
        defaults += [
            (f"SubIndex {a:03d}", _hex(base + 0x10 * (a - 1), 16)) for a in range(1, axes + 1)
        ]
        _object_record(w, index, label, "DTPDOASSIGN", 16 + 16 * axes, defaults)
    for index, label in ((0x1C32, "SM output parameter"), (0x1C33, "SM input parameter")):
        _record_object(w, _sync_params(index, label), index)
    for axis in range(axes):
        off = axis * AXIS_OFFSET
        rows: list[tuple[int, Var | Record]] = [(v.index, v) for v in AXIS_VARS]
        rows += [(r.index, r) for r in AXIS_RECORDS]
        for index, obj in sorted(rows, key=lambda r: r[0]):
            if isinstance(obj, Var):
                bits = BASIC_BITS[obj.type_name]
                _object_var(
                    w,
                    index + off,
                    obj.name,
                    obj.type_name,
                    f"<DefaultData>{_hex(obj.default, bits)}</DefaultData>",
                    _flags(obj.access, obj.pdo),
                )
            else:
                _record_object(w, obj, index + off)
    w.add(6, "</Objects>")
    w.add(5, "</Dictionary>")
    w.add(4, "</Profile>")
    w.add(4, "<Fmmu>Outputs</Fmmu>")
    w.add(4, "<Fmmu>Inputs</Fmmu>")
    w.add(4, "<Fmmu>MBoxState</Fmmu>")
    rx_size, tx_size = axes * _pdo_bytes(RX_ENTRIES), axes * _pdo_bytes(TX_ENTRIES)
    w.add(
        4,
        '<Sm MinSize="34" MaxSize="128" DefaultSize="128" StartAddress="#x1000" '
        'ControlByte="#x26" Enable="1">MBoxOut</Sm>',
    )
    w.add(
        4,
        '<Sm MinSize="34" MaxSize="128" DefaultSize="128" StartAddress="#x1080" '
        'ControlByte="#x22" Enable="1">MBoxIn</Sm>',
    )
    w.add(
        4,
        f'<Sm DefaultSize="{rx_size}" StartAddress="#x1100" ControlByte="#x64" '
        'Enable="1">Outputs</Sm>',
    )
    w.add(
        4,
        f'<Sm DefaultSize="{tx_size}" StartAddress="#x1400" ControlByte="#x20" '
        'Enable="1">Inputs</Sm>',
    )
    for axis in range(axes):
        _pdo_xml(
            w,
            "RxPdo",
            0x1600 + 0x10 * axis,
            f"Axis {axis + 1} outputs",
            2,
            _axis_entries(RX_ENTRIES, axis),
        )
    for axis in range(axes):
        _pdo_xml(
            w,
            "TxPdo",
            0x1A00 + 0x10 * axis,
            f"Axis {axis + 1} inputs",
            3,
            _axis_entries(TX_ENTRIES, axis),
        )
    w.add(4, '<Mailbox DataLinkLayer="true">')
    w.add(
        5,
        '<CoE SdoInfo="true" PdoAssign="true" PdoConfig="true" CompleteAccess="false" '
        'SegmentedSdo="true"/>',
    )
    w.add(4, "</Mailbox>")
    w.add(4, "<Dc>")
    w.add(
        5,
        "<OpMode><Name>DC</Name><Desc>DC-Synchron (SYNC0)</Desc>"
        '<AssignActivate>#x0300</AssignActivate><CycleTimeSync0 Factor="1">0</CycleTimeSync0>'
        "<ShiftTimeSync0>0</ShiftTimeSync0></OpMode>",
    )
    w.add(
        5,
        "<OpMode><Name>FreeRun</Name><Desc>Free run (SM-synchronous)</Desc>"
        "<AssignActivate>#x0000</AssignActivate></OpMode>",
    )
    w.add(4, "</Dc>")
    w.add(
        4,
        "<Eeprom><ByteSize>2048</ByteSize>"
        "<ConfigData>0506034464000000000000000000</ConfigData></Eeprom>",
    )
    w.add(3, "</Device>")


def render() -> str:
    w = Writer()
    w.add(0, '<?xml version="1.0" encoding="UTF-8"?>')
    w.add(
        0,
        "<!-- CiA 402 servo drives of the ether_ros simulator (1 and 2 axes). Generated by"
        " scripts/gen_servo_drive_esi.py: edit that script, not this file. -->",
    )
    w.add(0, '<EtherCATInfo xmlns:xsi="http://www.w3.org/2001/XMLSchema-instance" Version="1.6">')
    w.add(1, f"<Vendor><Id>#x{VENDOR_ID:08X}</Id><Name>CSL-EP NTUA</Name></Vendor>")
    w.add(1, "<Descriptions>")
    w.add(
        2,
        "<Groups><Group><Type>ServoDrive</Type><Name>Servo drives (CiA 402)</Name>"
        "</Group></Groups>",
    )
    w.add(2, "<Devices>")
    device(w, 1, 0x00020001, "ServoDrive1", "Servo drive, 1 axis (CiA 402)")
    device(w, 2, 0x00020002, "ServoDrive2", "Servo drive, 2 axes (CiA 402)")
    w.add(2, "</Devices>")
    w.add(1, "</Descriptions>")
    w.add(0, "</EtherCATInfo>")
    return "\n".join(w.lines) + "\n"


def main() -> None:
    target = Path(__file__).resolve().parent.parent / "devices" / "servo_drive.xml"
    target.write_text(render(), encoding="utf-8")
    print(f"wrote {target}")


if __name__ == "__main__":
    main()
