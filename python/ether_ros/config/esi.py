"""ESI device descriptions (ETG.2000 ``EtherCATInfo`` XML) parsed into typed models.

Only what a master and the simulator need is kept: identity, SyncManagers, FMMUs, mailbox
protocols, DC operation modes, the PDOs with their entries, the CoE object dictionary (with record
and array types expanded into one :class:`OdEntry` per subindex), and the EEPROM settings.
Every error names the file, the line, the element and the offending value.
"""

from __future__ import annotations

from collections.abc import Iterable, Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from lxml import etree

from ether_ros.config import types as dt
from ether_ros.errors import ConfigError

# --------------------------------------------------------------------------------------------
# Models


@dataclass(frozen=True)
class SyncManagerDesc:
    """One ``<Sm>``: its number is its position among the device's ``<Sm>`` elements."""

    number: int
    role: str  # 'MBoxOut' | 'MBoxIn' | 'Outputs' | 'Inputs' | '' (unused)
    start: int
    default_size: int  # 0 when the ESI gives none (process data SMs are sized by their PDOs)
    control: int
    enable: bool
    min_size: int | None = None
    max_size: int | None = None


@dataclass(frozen=True)
class DcOpMode:
    name: str
    description: str
    assign_activate: int
    cycle_time_sync0: int = 0
    cycle_time_sync0_factor: int = 1
    shift_time_sync0: int = 0
    cycle_time_sync1: int = 0
    cycle_time_sync1_factor: int = 0
    shift_time_sync1: int = 0


@dataclass(frozen=True)
class MailboxDesc:
    coe: bool = False
    sdo_info: bool = False
    pdo_assign: bool = False
    pdo_config: bool = False
    complete_access: bool = False
    segmented_sdo: bool = True
    foe: bool = False
    eoe: bool = False
    soe: bool = False
    aoe: bool = False
    voe: bool = False

    @property
    def protocols(self) -> int:
        """SII word 0x1C bit mask: AoE 0x01, EoE 0x02, CoE 0x04, FoE 0x08, SoE 0x10, VoE 0x20."""
        bits = (self.aoe, self.eoe, self.coe, self.foe, self.soe, self.voe)
        return sum(1 << i for i, on in enumerate(bits) if on)


@dataclass(frozen=True)
class PdoEntry:
    """One mapped entry; ``index == 0`` is padding (``bit_length`` gap, no name/type needed)."""

    index: int
    subindex: int
    bit_length: int
    name: str
    data_type: int  # ETG.1000.6 code, 0 for padding
    type_name: str = ""

    @property
    def is_padding(self) -> bool:
        return self.index == 0

    @property
    def mapping_value(self) -> int:
        """The 32-bit value of this entry in a PDO mapping object (index<<16 | sub<<8 | bits)."""
        return (self.index << 16) | (self.subindex << 8) | self.bit_length


@dataclass(frozen=True)
class Pdo:
    index: int
    name: str
    direction: str  # 'rx' (outputs, master → slave) | 'tx' (inputs, slave → master)
    entries: tuple[PdoEntry, ...]
    sm: int | None = None
    fixed: bool = False
    mandatory: bool = False
    excludes: tuple[int, ...] = ()
    # A virtual PDO exists only to be configured (PDO configuration), not in the default image.
    virtual: bool = False

    @property
    def bit_length(self) -> int:
        return sum(e.bit_length for e in self.entries)


@dataclass(frozen=True)
class OdEntry:
    """One subindex of the object dictionary."""

    index: int
    subindex: int
    name: str
    data_type: int  # ETG.1000.6 code; 0 when the ESI type is not a basic type
    type_name: str
    bit_length: int
    access: str = "ro"  # 'ro' | 'rw' | 'wo'
    pdo_mapping: str = ""  # '', 'R', 'T' or 'RT'
    default: bytes = b""

    @property
    def pdo_mappable(self) -> bool:
        return bool(self.pdo_mapping)


@dataclass(frozen=True)
class OdObject:
    index: int
    name: str
    object_code: int  # 7 VAR, 8 ARRAY, 9 RECORD
    type_name: str
    bit_size: int
    entries: tuple[OdEntry, ...]

    def entry(self, subindex: int) -> OdEntry | None:
        for e in self.entries:
            if e.subindex == subindex:
                return e
        return None


@dataclass(frozen=True)
class EepromDesc:
    byte_size: int = 2048
    config_data: bytes = b""


@dataclass(frozen=True)
class EsiModule:
    """One ``<Module>`` of a modular device (MDP 5001): what a slot can hold."""

    type_name: str
    ident: int  # ModuleIdent: the value the device reports for this module in 0xF050
    name: str
    rx_pdos: tuple[Pdo, ...] = ()
    tx_pdos: tuple[Pdo, ...] = ()


@dataclass(frozen=True)
class EsiSlot:
    """One ``<Slot>`` of a modular device: which modules it takes and which it holds by default."""

    name: str
    min_instances: int
    max_instances: int
    module_idents: tuple[int, ...]
    default_ident: int | None


@dataclass(frozen=True)
class StateMachineTimeouts:
    """``<Info><StateMachine><Timeout>`` of a device, in milliseconds (ETG.2000 defaults when the
    ESI gives none): how long a master waits for a transition, and how long a slave may keep a
    SAFEOP->OP request pending while it waits for valid outputs."""

    preop_ms: int = 3000
    safeop_op_ms: int = 10000
    back_to_init_ms: int = 5000
    back_to_safeop_ms: int = 200


@dataclass(frozen=True)
class EsiDevice:
    """One ``<Device>`` of an ESI file."""

    vendor_id: int
    vendor_name: str
    product_code: int
    revision: int
    type_name: str  # the ``<Type>`` text: the name configs use in ``device:``
    name: str  # the ``<Name>`` text (human readable)
    group_type: str
    group_name: str
    physics: str
    sync_managers: tuple[SyncManagerDesc, ...]
    fmmus: tuple[str, ...]
    mailbox: MailboxDesc | None
    dc_opmodes: tuple[DcOpMode, ...]
    rx_pdos: tuple[Pdo, ...]
    tx_pdos: tuple[Pdo, ...]
    objects: tuple[OdObject, ...]
    eeprom: EepromDesc
    # Device profile numbers (``<Profile><ProfileNo>``, one per ``<ChannelInfo>`` of a
    # multi-channel device): 402 is a CiA 402 drive, 5001 a modular device (MDP).
    profile_numbers: tuple[int, ...] = ()
    timeouts: StateMachineTimeouts = field(default_factory=StateMachineTimeouts)
    # Modular devices (MDP 5001): the modules of the file and the device's slots.
    modules: tuple[EsiModule, ...] = ()
    slots: tuple[EsiSlot, ...] = ()
    # Names of the ``<AlternativeSmMapping>`` entries (alternative PDO-to-SM assignments).
    alternative_sm_mappings: tuple[str, ...] = ()
    source: str = ""  # file the device came from
    line: int = 0
    _od: dict[tuple[int, int], OdEntry] = field(default_factory=dict, repr=False, compare=False)

    def __post_init__(self) -> None:
        for obj in self.objects:
            for e in obj.entries:
                self._od[(e.index, e.subindex)] = e

    def od_entry(self, index: int, subindex: int) -> OdEntry | None:
        return self._od.get((index, subindex))

    def od_object(self, index: int) -> OdObject | None:
        for obj in self.objects:
            if obj.index == index:
                return obj
        return None

    def pdo(self, index: int) -> Pdo | None:
        for p in (*self.rx_pdos, *self.tx_pdos):
            if p.index == index:
                return p
        return None

    def sm(self, role: str) -> SyncManagerDesc | None:
        for sm in self.sync_managers:
            if sm.role == role:
                return sm
        return None

    @property
    def dc_supported(self) -> bool:
        return bool(self.dc_opmodes)

    @property
    def dc_required(self) -> bool:
        """True when every operation mode needs SYNC0 (no free-run mode with AssignActivate 0)."""
        return bool(self.dc_opmodes) and all(m.assign_activate & 0x0100 for m in self.dc_opmodes)

    @property
    def assign_activate(self) -> int:
        """AssignActivate of the first DC mode that uses SYNC (0 if none)."""
        for m in self.dc_opmodes:
            if m.assign_activate:
                return m.assign_activate
        return 0

    def default_rx_pdos(self) -> tuple[int, ...]:
        """The RxPDOs assigned by default: those with an ``Sm`` attribute (ETG.2000)."""
        return tuple(p.index for p in self.rx_pdos if p.sm is not None)

    def default_tx_pdos(self) -> tuple[int, ...]:
        return tuple(p.index for p in self.tx_pdos if p.sm is not None)

    def describe(self) -> str:
        return (
            f"{self.type_name} (vendor {self.vendor_id:#010x}, product {self.product_code:#010x},"
            f" revision {self.revision:#010x})"
        )


# --------------------------------------------------------------------------------------------
# Parser


class _Ctx:
    """Where we are in which file, to name both in errors."""

    def __init__(self, path: Path) -> None:
        self.path = path

    def error(self, el: etree._Element, msg: str, value: object = None) -> ConfigError:
        where = f"{self.path}:{el.sourceline}: <{_local(el)}>"
        tail = "" if value is None else f": {value!r}"
        return ConfigError(
            f"{where}: {msg}{tail}",
            file=str(self.path),
            line=_line(el) or None,
            field=f"<{_local(el)}>",
            value=value,
        )


def _local(el: etree._Element) -> str:
    tag = el.tag
    if not isinstance(tag, str):
        return "?"
    return tag.rsplit("}", 1)[-1]


def _line(el: etree._Element) -> int:
    line = getattr(el, "sourceline", None)
    return line if isinstance(line, int) else 0


def _children(el: etree._Element, name: str) -> Iterator[etree._Element]:
    for c in el:
        if isinstance(c.tag, str) and _local(c) == name:
            yield c


def _child(el: etree._Element, name: str) -> etree._Element | None:
    return next(_children(el, name), None)


def _text(el: etree._Element | None) -> str:
    return "" if el is None or el.text is None else el.text.strip()


def parse_esi_int(text: str) -> int:
    """ESI numbers: ``#x1A00`` (hex), ``0x1A00``, or decimal."""
    t = text.strip()
    if t[:2].lower() in ("#x", "0x"):
        return int(t[2:], 16)
    return int(t, 10)


def _int(ctx: _Ctx, el: etree._Element, *, name: str | None = None) -> int:
    """The integer text of child ``name`` of ``el`` (or of ``el`` itself)."""
    node = el if name is None else _child(el, name)
    if node is None:
        raise ctx.error(el, f"missing <{name}>")
    try:
        return parse_esi_int(_text(node))
    except ValueError:
        raise ctx.error(node, "not a number", _text(node)) from None


def _opt_int(ctx: _Ctx, el: etree._Element, name: str, default: int) -> int:
    node = _child(el, name)
    return default if node is None else _int(ctx, node)


def _attr_int(ctx: _Ctx, el: etree._Element, attr: str, default: int | None) -> int | None:
    raw = el.get(attr)
    if raw is None:
        return default
    try:
        return parse_esi_int(raw)
    except ValueError:
        raise ctx.error(el, f"attribute {attr} is not a number", raw) from None


def _attr_bool(el: etree._Element, attr: str, default: bool = False) -> bool:
    raw = el.get(attr)
    if raw is None:
        return default
    return raw.strip().lower() in ("1", "true", "yes")


# Largest object, entry or array the parser accepts: a CoE object is at most 65535 bytes (the
# SDO size field of segmented transfers is 32 bits, but no ESC mailbox or EEPROM holds more), an
# array has at most 255 elements (subindex 1..255).
MAX_OBJECT_BITS = 8 * 65535
MAX_SUBINDEX = 255


@dataclass
class _TypeDef:
    """A ``<DataType>`` of the dictionary."""

    name: str
    bit_size: int
    base_type: str
    subitems: list[etree._Element]
    array: tuple[int, int] | None  # (lower bound, elements)
    el: etree._Element


def load_esi(path: str | Path) -> list[EsiDevice]:
    """Parse an ESI file. Raises :class:`ConfigError` naming file, line, element and value."""
    p = Path(path)
    ctx = _Ctx(p)
    if not p.is_file():
        raise ConfigError(f"{p}: ESI file not found")
    tree = _parse_xml(p)
    root = tree.getroot()
    if _local(root) != "EtherCATInfo":
        raise ctx.error(root, "root element must be <EtherCATInfo>", _local(root))
    vendor = _child(root, "Vendor")
    if vendor is None:
        raise ctx.error(root, "missing <Vendor>")
    vendor_id = _int(ctx, vendor, name="Id")
    vendor_name = _text(_child(vendor, "Name"))
    desc = _child(root, "Descriptions")
    if desc is None:
        raise ctx.error(root, "missing <Descriptions>")
    groups: dict[str, str] = {}
    groups_el = _child(desc, "Groups")
    if groups_el is not None:
        for g in _children(groups_el, "Group"):
            groups[_text(_child(g, "Type"))] = _text(_child(g, "Name"))
    devices_el = _child(desc, "Devices")
    if devices_el is None:
        raise ctx.error(desc, "missing <Devices>")
    modules = _parse_modules(ctx, desc)
    devices = [
        _parse_device(ctx, d, vendor_id, vendor_name, groups, modules)
        for d in _children(devices_el, "Device")
    ]
    if not devices:
        raise ctx.error(devices_el, "no <Device> in <Devices>")
    return devices


def _parse_xml(path: Path) -> etree._ElementTree:
    """Parse without entity expansion, DTD loading or network access (a hostile ESI must not
    grow without bounds or reach out), and refuse any document type declaration: no vendor ESI
    has one, and it is the way in for entity attacks."""
    parser = etree.XMLParser(
        remove_comments=True,
        resolve_entities=False,
        load_dtd=False,
        no_network=True,
        huge_tree=False,
    )
    try:
        tree = etree.parse(str(path), parser)
    except etree.XMLSyntaxError as exc:
        raise ConfigError(f"{path}:{exc.lineno}: not well-formed XML: {exc.msg}") from None
    info: Any = tree.docinfo
    if info.doctype or info.internalDTD is not None:
        raise ConfigError(
            f"{path}:1: <!DOCTYPE>: document type declarations (DTD, entities) are not"
            " supported in an ESI"
        )
    return tree


def _parse_modules(ctx: _Ctx, desc: etree._Element) -> dict[int, EsiModule]:
    """``<Descriptions><Modules>`` of a modular device file, by ModuleIdent."""
    modules: dict[int, EsiModule] = {}
    mods_el = _child(desc, "Modules")
    if mods_el is None:
        return modules
    for m in _children(mods_el, "Module"):
        type_el = _child(m, "Type")
        if type_el is None or not _text(type_el):
            raise ctx.error(m, "module without <Type>")
        ident = _attr_int(ctx, type_el, "ModuleIdent", None)
        if ident is None:
            raise ctx.error(type_el, "missing attribute ModuleIdent")
        od = {(e.index, e.subindex): e for o in _parse_dictionary(ctx, m) for e in o.entries}
        modules[ident] = EsiModule(
            type_name=_text(type_el),
            ident=ident,
            name=_text(_child(m, "Name")) or _text(type_el),
            rx_pdos=tuple(_parse_pdo(ctx, x, "rx", od) for x in _children(m, "RxPdo")),
            tx_pdos=tuple(_parse_pdo(ctx, x, "tx", od) for x in _children(m, "TxPdo")),
        )
    return modules


def _parse_slots(
    ctx: _Ctx, dev: etree._Element, modules: dict[int, EsiModule]
) -> tuple[EsiSlot, ...]:
    slots_el = _child(dev, "Slots")
    if slots_el is None:
        return ()
    slots: list[EsiSlot] = []
    for sl in _children(slots_el, "Slot"):
        idents: list[int] = []
        default: int | None = None
        for mi in _children(sl, "ModuleIdent"):
            ident = _int(ctx, mi)
            if modules and ident not in modules:
                raise ctx.error(mi, "slot names a module the file does not describe", f"{ident:#x}")
            idents.append(ident)
            if _attr_bool(mi, "Default"):
                default = ident
        # Slots may also accept whole classes of modules (<ModuleClass>): those add no ident.
        slots.append(
            EsiSlot(
                name=_text(_child(sl, "Name")),
                min_instances=_attr_int(ctx, sl, "MinInstances", 0) or 0,
                max_instances=_attr_int(ctx, sl, "MaxInstances", 1) or 0,
                module_idents=tuple(idents),
                default_ident=default,
            )
        )
    return tuple(slots)


def load_esi_paths(paths: Iterable[str | Path]) -> list[EsiDevice]:
    """All devices of the given ESI files and directories (``*.xml`` in them, sorted; a
    directory's dictionary files — root ``<Dictionary>``, referenced by a ``DictionaryFile`` —
    are not ESI files of their own and are passed over)."""
    out: list[EsiDevice] = []
    for item in paths:
        p = Path(item)
        if p.is_dir():
            for f in esi_files(p):
                out.extend(load_esi(f))
        elif p.is_file():
            out.extend(load_esi(p))
        else:
            raise ConfigError(f"{p}: ESI file or directory not found")
    return out


def esi_files(directory: Path) -> list[Path]:
    """The ESI files of a directory: ``*.xml`` sorted, without dictionary files (root
    ``<Dictionary>``, referenced by a device's ``DictionaryFile``)."""
    return [f for f in sorted(directory.glob("*.xml")) if _root_name(f) != "Dictionary"]


def _root_name(path: Path) -> str:
    """The root element's name, read without parsing the whole file."""
    try:
        for _, el in etree.iterparse(str(path), events=("start",), resolve_entities=False):
            return _local(el)
    except etree.XMLSyntaxError:
        pass
    return ""


def _parse_device(
    ctx: _Ctx,
    dev: etree._Element,
    vendor_id: int,
    vendor_name: str,
    groups: dict[str, str],
    modules: dict[int, EsiModule],
) -> EsiDevice:
    type_el = _child(dev, "Type")
    if type_el is None:
        raise ctx.error(dev, "missing <Type>")
    product = _attr_int(ctx, type_el, "ProductCode", None)
    if product is None:
        raise ctx.error(type_el, "missing attribute ProductCode")
    revision = _attr_int(ctx, type_el, "RevisionNo", 0) or 0
    type_name = _text(type_el)
    if not type_name:
        raise ctx.error(type_el, "empty device type name")
    names = list(_children(dev, "Name"))
    name = type_name
    for n in names:
        if n.get("LcId", "1033") == "1033":
            name = _text(n)
            break
    else:
        if names:
            name = _text(names[0])
    group_type = _text(_child(dev, "GroupType"))

    sms: list[SyncManagerDesc] = []
    for i, sm in enumerate(_children(dev, "Sm")):
        role = _text(sm)
        if role not in ("MBoxOut", "MBoxIn", "Outputs", "Inputs", ""):
            raise ctx.error(sm, "unknown SyncManager role", role)
        start = _attr_int(ctx, sm, "StartAddress", None)
        if start is None:
            raise ctx.error(sm, "missing attribute StartAddress")
        sms.append(
            SyncManagerDesc(
                number=i,
                role=role,
                start=start,
                default_size=_attr_int(ctx, sm, "DefaultSize", 0) or 0,
                control=_attr_int(ctx, sm, "ControlByte", 0) or 0,
                enable=_attr_bool(sm, "Enable", True),
                min_size=_attr_int(ctx, sm, "MinSize", None),
                max_size=_attr_int(ctx, sm, "MaxSize", None),
            )
        )
    fmmus: list[str] = []
    for f in _children(dev, "Fmmu"):
        role = _text(f)
        if role not in ("Outputs", "Inputs", "MBoxState", ""):
            raise ctx.error(f, "unknown FMMU role", role)
        fmmus.append(role)

    mailbox = _parse_mailbox(dev)
    for role in ("MBoxOut", "MBoxIn"):
        if mailbox is not None and not any(s.role == role for s in sms):
            raise ctx.error(dev, f"device has a <Mailbox> but no {role} SyncManager", type_name)

    dc_modes: list[DcOpMode] = []
    dc_el = _child(dev, "Dc")
    if dc_el is not None:
        for om in _children(dc_el, "OpMode"):
            c0 = _child(om, "CycleTimeSync0")
            c1 = _child(om, "CycleTimeSync1")
            dc_modes.append(
                DcOpMode(
                    name=_text(_child(om, "Name")),
                    description=_text(_child(om, "Desc")),
                    assign_activate=_int(ctx, om, name="AssignActivate"),
                    cycle_time_sync0=0 if c0 is None else _int(ctx, c0),
                    cycle_time_sync0_factor=1
                    if c0 is None
                    else (_attr_int(ctx, c0, "Factor", 1) or 0),
                    shift_time_sync0=_opt_int(ctx, om, "ShiftTimeSync0", 0),
                    cycle_time_sync1=0 if c1 is None else _int(ctx, c1),
                    cycle_time_sync1_factor=0
                    if c1 is None
                    else (_attr_int(ctx, c1, "Factor", 0) or 0),
                    shift_time_sync1=_opt_int(ctx, om, "ShiftTimeSync1", 0),
                )
            )

    objects = _parse_dictionary(ctx, dev, _dictionary_file_of(ctx, dev))
    od = {(e.index, e.subindex): e for o in objects for e in o.entries}
    rx = [_parse_pdo(ctx, p, "rx", od) for p in _children(dev, "RxPdo")]
    tx = [_parse_pdo(ctx, p, "tx", od) for p in _children(dev, "TxPdo")]
    seen: dict[int, Pdo] = {}
    for pdo, el in zip(
        (*rx, *tx), (*_children(dev, "RxPdo"), *_children(dev, "TxPdo")), strict=True
    ):
        if pdo.index in seen:
            raise ctx.error(el, "duplicate PDO index", f"{pdo.index:#06x}")
        seen[pdo.index] = pdo
        if pdo.sm is not None and not 0 <= pdo.sm < len(sms):
            raise ctx.error(el, "PDO names a SyncManager the device does not have", pdo.sm)

    profile_numbers: list[int] = []
    for prof in _children(dev, "Profile"):
        for holder in (prof, *_children(prof, "ChannelInfo")):
            no = _child(holder, "ProfileNo")
            if no is not None:
                profile_numbers.append(_int(ctx, no))

    timeouts = StateMachineTimeouts()
    info = _child(dev, "Info")
    sm_el = _child(info, "StateMachine") if info is not None else None
    to_el = _child(sm_el, "Timeout") if sm_el is not None else None
    if to_el is not None:
        d = StateMachineTimeouts()
        timeouts = StateMachineTimeouts(
            preop_ms=_opt_int(ctx, to_el, "PreopTimeout", d.preop_ms),
            safeop_op_ms=_opt_int(ctx, to_el, "SafeopOpTimeout", d.safeop_op_ms),
            back_to_init_ms=_opt_int(ctx, to_el, "BackToInitTimeout", d.back_to_init_ms),
            back_to_safeop_ms=_opt_int(ctx, to_el, "BackToSafeopTimeout", d.back_to_safeop_ms),
        )

    eeprom = EepromDesc()
    ee = _child(dev, "Eeprom")
    if ee is not None:
        size = _opt_int(ctx, ee, "ByteSize", 2048)
        cd_el = _child(ee, "ConfigData")
        cd = b""
        if cd_el is not None:
            try:
                cd = bytes.fromhex(_text(cd_el))
            except ValueError:
                raise ctx.error(cd_el, "not hex bytes", _text(cd_el)) from None
            if len(cd) > 16:
                raise ctx.error(cd_el, "ConfigData longer than 16 bytes", _text(cd_el))
        if size < 128 or size % 128:
            raise ctx.error(ee, "ByteSize must be a multiple of 128 (at least 128)", size)
        eeprom = EepromDesc(byte_size=size, config_data=cd)

    return EsiDevice(
        vendor_id=vendor_id,
        vendor_name=vendor_name,
        product_code=product,
        revision=revision,
        type_name=type_name,
        name=name,
        group_type=group_type,
        group_name=groups.get(group_type, group_type),
        physics=dev.get("Physics", ""),
        sync_managers=tuple(sms),
        fmmus=tuple(fmmus),
        mailbox=mailbox,
        dc_opmodes=tuple(dc_modes),
        rx_pdos=tuple(rx),
        tx_pdos=tuple(tx),
        objects=tuple(objects),
        eeprom=eeprom,
        profile_numbers=tuple(profile_numbers),
        timeouts=timeouts,
        modules=tuple(modules.values()) if _child(dev, "Slots") is not None else (),
        slots=_parse_slots(ctx, dev, modules),
        alternative_sm_mappings=tuple(
            _text(_child(a, "Name")) for a in _children(dev, "AlternativeSmMapping")
        ),
        source=str(ctx.path),
        line=_line(dev),
    )


def _parse_mailbox(dev: etree._Element) -> MailboxDesc | None:
    mb = _child(dev, "Mailbox")
    if mb is None:
        return None
    coe = _child(mb, "CoE")
    return MailboxDesc(
        coe=coe is not None,
        sdo_info=coe is not None and _attr_bool(coe, "SdoInfo"),
        pdo_assign=coe is not None and _attr_bool(coe, "PdoAssign"),
        pdo_config=coe is not None and _attr_bool(coe, "PdoConfig"),
        complete_access=coe is not None and _attr_bool(coe, "CompleteAccess"),
        segmented_sdo=coe is None or _attr_bool(coe, "SegmentedSdo", True),
        foe=_child(mb, "FoE") is not None,
        eoe=_child(mb, "EoE") is not None,
        soe=_child(mb, "SoE") is not None,
        aoe=_child(mb, "AoE") is not None,
        voe=_child(mb, "VoE") is not None,
    )


def _parse_pdo(
    ctx: _Ctx, el: etree._Element, direction: str, od: dict[tuple[int, int], OdEntry]
) -> Pdo:
    index = _int(ctx, el, name="Index")
    entries: list[PdoEntry] = []
    for e in _children(el, "Entry"):
        idx = _int(ctx, e, name="Index")
        bits = _int(ctx, e, name="BitLen")
        if not 1 <= bits <= 64 and idx != 0:
            raise ctx.error(e, "BitLen must be 1..64", bits)
        if idx == 0:
            entries.append(PdoEntry(0, 0, bits, "", 0, ""))
            continue
        sub = _opt_int(ctx, e, "SubIndex", 0)
        type_el = _child(e, "DataType")
        type_name = _text(type_el)
        code = 0
        if type_el is not None:
            t = dt.esi_type(type_name)
            odent = od.get((idx, sub))
            if t is None and odent is not None and odent.type_name == type_name:
                # A vendor type name (a DataType of the dictionary) that the mapped object uses
                # too: the object knows its basic type.
                t = dt.BY_CODE.get(odent.data_type)
            if t is None:
                raise ctx.error(type_el, "unknown data type", type_name)
            if t.bit_length and t.bit_length != bits:
                raise ctx.error(e, f"BitLen {bits} does not match data type {type_name}", bits)
            code = t.code
        elif (odent := od.get((idx, sub))) is not None:
            code, type_name = odent.data_type, odent.type_name
        else:
            raise ctx.error(e, "entry has no <DataType> and no object in the dictionary", idx)
        name = _text(_child(e, "Name")) or f"{idx:#06x}:{sub:02x}"
        entries.append(PdoEntry(idx, sub, bits, name, code, type_name))
    sm = _attr_int(ctx, el, "Sm", None)
    return Pdo(
        index=index,
        name=_text(_child(el, "Name")),
        direction=direction,
        entries=tuple(entries),
        sm=sm,
        fixed=_attr_bool(el, "Fixed"),
        mandatory=_attr_bool(el, "Mandatory"),
        excludes=tuple(_int(ctx, x) for x in _children(el, "Exclude")),
        virtual=_attr_bool(el, "Virtual"),
    )


def _dictionary_file_of(ctx: _Ctx, dev: etree._Element) -> tuple[_Ctx, etree._Element] | None:
    """A ``<Profile><DictionaryFile>``: the dictionary kept in a file of its own, next to the
    ESI (its first ``<Dictionary>`` element is used)."""
    for prof in _children(dev, "Profile"):
        ref = _child(prof, "DictionaryFile")
        if ref is None:
            continue
        name = _text(ref)
        target = (ctx.path.parent / name).resolve()
        if not name or ctx.path.parent.resolve() not in target.parents:
            raise ctx.error(ref, "DictionaryFile must name a file next to the ESI", name)
        if not target.is_file():
            raise ctx.error(ref, "DictionaryFile not found", str(target))
        root = _parse_xml(target).getroot()
        found = (
            root
            if _local(root) == "Dictionary"
            else next(
                (e for e in root.iter() if isinstance(e.tag, str) and _local(e) == "Dictionary"),
                None,
            )
        )
        if found is None:
            raise ctx.error(ref, "DictionaryFile holds no <Dictionary>", name)
        return _Ctx(target), found
    return None


def _parse_dictionary(
    ctx: _Ctx, dev: etree._Element, external: tuple[_Ctx, etree._Element] | None = None
) -> list[OdObject]:
    dictionary = None
    for prof in _children(dev, "Profile"):
        dictionary = _child(prof, "Dictionary")
        if dictionary is not None:
            break
    if dictionary is None and external is not None:
        ctx, dictionary = external
    if dictionary is None:
        return []
    typedefs: dict[str, _TypeDef] = {}
    dts = _child(dictionary, "DataTypes")
    if dts is not None:
        for d in _children(dts, "DataType"):
            name = _text(_child(d, "Name"))
            if not name:
                raise ctx.error(d, "data type without <Name>")
            ai = _child(d, "ArrayInfo")
            array = None
            if ai is not None:
                array = (_opt_int(ctx, ai, "LBound", 0), _int(ctx, ai, name="Elements"))
                if array[1] < 0 or array[1] > 0xFFFF or array[0] < 0:
                    raise ctx.error(ai, "array bounds out of range (0..65535 elements)", array)
            bit_size = _opt_int(ctx, d, "BitSize", 0)
            if not 0 <= bit_size <= MAX_OBJECT_BITS:
                raise ctx.error(d, f"BitSize out of range (0..{MAX_OBJECT_BITS})", bit_size)
            _check_subitem_extent(ctx, d, bit_size)
            typedefs[name] = _TypeDef(
                name=name,
                bit_size=bit_size,
                base_type=_text(_child(d, "BaseType")),
                subitems=list(_children(d, "SubItem")),
                array=array,
                el=d,
            )
    objects: list[OdObject] = []
    objs = _child(dictionary, "Objects")
    if objs is None:
        return objects
    seen: set[int] = set()
    for o in _children(objs, "Object"):
        obj = _parse_object(ctx, o, typedefs)
        if obj.index in seen:
            raise ctx.error(o, "duplicate object index", f"{obj.index:#06x}")
        seen.add(obj.index)
        objects.append(obj)
    return objects


def _check_subitem_extent(ctx: _Ctx, d: etree._Element, bit_size: int) -> None:
    """A subitem that ends beyond its DataType's BitSize is an inconsistent ESI (gaps between
    subitems are fine: vendors align entries with BitOffs)."""
    if not bit_size:
        return
    for si in _children(d, "SubItem"):
        offs = _child(si, "BitOffs")
        if offs is None:
            continue
        end = _int(ctx, offs) + _opt_int(ctx, si, "BitSize", 0)
        if end > bit_size:
            raise ctx.error(
                si,
                f"subitem ends at bit {end}, beyond its DataType's BitSize {bit_size}",
                _text(_child(si, "Name")),
            )


def _flags(el: etree._Element | None, access: str, mapping: str) -> tuple[str, str]:
    if el is None:
        return access, mapping
    fl = _child(el, "Flags")
    if fl is None:
        return access, mapping
    a = _text(_child(fl, "Access")) or access
    m = _text(_child(fl, "PdoMapping")).upper()
    if m == "TR":
        m = "RT"
    return a.lower(), m or mapping


def _default(ctx: _Ctx, info: etree._Element | None, bits: int, code: int) -> bytes:
    """Default value bytes from an ``<Info>`` (DefaultData hex, DefaultValue number, or
    DefaultString)."""
    nbytes = (bits + 7) // 8
    if info is None:
        return bytes(nbytes)
    dd = _child(info, "DefaultData")
    if dd is not None:
        try:
            data = bytes.fromhex(_text(dd))
        except ValueError:
            raise ctx.error(dd, "DefaultData is not hex bytes", _text(dd)) from None
        return data[:nbytes].ljust(nbytes, b"\0") if nbytes else data
    dv = _child(info, "DefaultValue")
    if dv is not None:
        t = dt.BY_CODE.get(code)
        try:
            value = parse_esi_int(_text(dv))
        except ValueError:
            raise ctx.error(dv, "DefaultValue is not a number", _text(dv)) from None
        if t is not None and t.kind in ("int", "uint", "bool"):
            try:
                return dt.encode_value(t, value, bits)
            except ValueError as exc:
                raise ctx.error(dv, str(exc), _text(dv)) from None
        return (value & ((1 << max(bits, 1)) - 1)).to_bytes(max(nbytes, 1), "little")[:nbytes]
    ds = _child(info, "DefaultString")
    if ds is not None:
        data = _text(ds).encode()
        return data[:nbytes].ljust(nbytes, b"\0") if nbytes else data
    return bytes(nbytes)


def _parse_object(ctx: _Ctx, o: etree._Element, typedefs: dict[str, _TypeDef]) -> OdObject:
    index = _int(ctx, o, name="Index")
    name = _text(_child(o, "Name"))
    type_el = _child(o, "Type")
    type_name = _text(type_el)
    if type_el is None or not type_name:
        raise ctx.error(o, "object without <Type>", f"{index:#06x}")
    bit_size = _opt_int(ctx, o, "BitSize", 0)
    if not 0 <= bit_size <= MAX_OBJECT_BITS:
        raise ctx.error(o, f"BitSize out of range (0..{MAX_OBJECT_BITS})", bit_size)
    access, mapping = _flags(o, "ro", "")
    info = _child(o, "Info")
    td = typedefs.get(type_name)
    if td is None or (not td.subitems and td.array is None):
        # A plain variable (VAR) of a basic type, possibly declared as a <DataType> too.
        t = dt.esi_type(type_name) or (dt.esi_type(td.base_type) if td is not None else None)
        if t is None:
            raise ctx.error(type_el, "unknown data type", type_name)
        bits = bit_size or t.bit_length or (td.bit_size if td is not None else 0)
        entry = OdEntry(
            index=index,
            subindex=0,
            name=name,
            data_type=t.code,
            type_name=type_name,
            bit_length=bits,
            access=access,
            pdo_mapping=mapping,
            default=_default(ctx, info, bits, t.code),
        )
        return OdObject(index, name, 7, type_name, bits, (entry,))
    info_subs = [] if info is None else list(_children(info, "SubItem"))
    info_by_name = {_text(_child(s, "Name")): s for s in info_subs}
    entries: list[OdEntry] = []
    object_code = 9

    def add(sub: int, ename: str, tname: str, bits: int, el: etree._Element, pos: int) -> None:
        if not 0 <= sub <= MAX_SUBINDEX:
            raise ctx.error(el, f"subindex out of range (0..{MAX_SUBINDEX})", sub)
        code, bits = _entry_type(ctx, el, tname, bits, typedefs)
        a, m = _flags(el, access, mapping)
        sub_info_el = info_by_name.get(ename)
        if sub_info_el is None and pos < len(info_subs):
            sub_info_el = info_subs[pos]
        sub_info = None if sub_info_el is None else _child(sub_info_el, "Info")
        entries.append(
            OdEntry(index, sub, ename, code, tname, bits, a, m, _default(ctx, sub_info, bits, code))
        )

    if td.array is not None and not td.subitems:
        # An array type used directly: subindex 0 holds the count, elements follow.
        object_code = 8
        lb, n = td.array
        _check_array(ctx, td.el, lb, n)
        entries.append(
            OdEntry(index, 0, "SubIndex 000", dt.UINT8.code, "USINT", 8, "ro", "", bytes([n]))
        )
        elem = dt.esi_type(td.base_type)
        if elem is None:
            raise ctx.error(td.el, "unknown array base type", td.base_type)
        for k in range(n):
            sub = lb + k
            add(sub, f"SubIndex {sub:03d}", td.base_type, elem.bit_length, td.el, k + 1)
    else:
        pos = 0
        for si in td.subitems:
            sname = _text(_child(si, "Name"))
            stype = _text(_child(si, "Type"))
            sbits = _opt_int(ctx, si, "BitSize", 0)
            inner = typedefs.get(stype)
            sub_el = _child(si, "SubIdx")
            if inner is not None and inner.array is not None and sub_el is None:
                # "Elements" of an array object (no SubIdx of its own): one subindex per
                # element. An array-typed subitem *with* a SubIdx is one subindex holding the
                # whole array (e.g. an ARRAY [0..511] OF BYTE inside a record).
                object_code = 8
                lb, n = inner.array
                _check_array(ctx, si, lb, n)
                ebits = sbits // n if sbits and n else 0
                for k in range(n):
                    sub = lb + k
                    add(sub, f"SubIndex {sub:03d}", inner.base_type, ebits, si, pos)
                    pos += 1
                continue
            sub = pos if sub_el is None else _int(ctx, sub_el)
            add(sub, sname, stype, sbits, si, pos)
            pos += 1
    subs = [e.subindex for e in entries]
    if len(set(subs)) != len(subs):
        raise ctx.error(o, "duplicate subindex in object", f"{index:#06x}")
    return OdObject(index, name, object_code, type_name, bit_size or td.bit_size, tuple(entries))


def _check_array(ctx: _Ctx, el: etree._Element, lower: int, elements: int) -> None:
    if lower + elements - 1 > MAX_SUBINDEX:
        raise ctx.error(
            el,
            f"array of {elements} elements from subindex {lower} does not fit in subindices"
            f" 1..{MAX_SUBINDEX}",
        )


def _entry_type(
    ctx: _Ctx, el: etree._Element, tname: str, bits: int, typedefs: dict[str, _TypeDef]
) -> tuple[int, int]:
    """(data type code, bit length) of one subindex of type ``tname``. Basic types give their
    code; a byte array or string gives OCTET_STRING/STRING sized by BitSize; any other
    structured type (a nested record, an array of words) is one opaque value (code 0) of its
    BitSize, read and written as bytes."""
    if not 0 <= bits <= MAX_OBJECT_BITS:
        raise ctx.error(el, f"BitSize out of range (0..{MAX_OBJECT_BITS})", bits)
    t = dt.esi_type(tname)
    if t is not None:
        return t.code, bits or t.bit_length
    inner = typedefs.get(tname)
    if inner is None:
        raise ctx.error(el, "unknown data type", tname)
    size = bits or inner.bit_size
    if inner.array is not None:
        elem = dt.esi_type(inner.base_type)
        if elem is not None and elem.bit_length == 8 and elem.kind in ("uint", "int"):
            return dt.OCTET_STRING.code, size
        return 0, size
    if inner.subitems:
        return 0, size
    base = dt.esi_type(inner.base_type)
    if base is None:
        raise ctx.error(el, "unknown data type", tname)
    return base.code, size or base.bit_length
