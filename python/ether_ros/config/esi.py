"""ESI device descriptions (ETG.2000 ``EtherCATInfo`` XML) parsed into typed models.

Only what a master and the simulator need is kept: identity, SyncManagers, FMMUs, mailbox
protocols and the CoE init commands, DC operation modes, the PDOs with their entries, the CoE
object dictionary (with record and array types expanded into one :class:`OdEntry` per
subindex), modules and slots (ETG.2001) and the EEPROM settings.

The parser is tolerant and exact. An ESI describes a device as its vendor sells it, so what the
schema allows is accepted (vendor SyncManager names, bit patterns as default values, type
aliases, passive terminals without a product code, Virtual PDOs reusing an index). A construct
that is really unsupported or inconsistent disables only the element that uses it (a PDO, an
object, a default value, an init command) or, failing that, the one device; it never takes
the rest of the file down. Each such case is one :class:`EsiWarning` line naming file, line
and element. What makes the whole file unusable (unreadable, not XML, a document type
declaration, no vendor) is a :class:`ConfigError` of one line naming file and line.

Hostile input is bounded: regular files only, at most :data:`MAX_ESI_BYTES`, no entity
expansion, and every count (devices, PDOs, entries, objects, subindices) and number (each
field's own range) is checked before it is used.
"""

from __future__ import annotations

import logging
import os
import re
import stat
import threading
from collections.abc import Iterable, Iterator
from contextvars import ContextVar
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

from lxml import etree

from ether_ros._native.protocol import dc as reg_dc
from ether_ros._native.protocol import sii_syncm
from ether_ros._native.protocol import sm as reg_sm
from ether_ros.config import esi_cache
from ether_ros.config import types as dt
from ether_ros.errors import ConfigError

log = logging.getLogger(__name__)

# --------------------------------------------------------------------------------------------
# Bounds (hostile input; every real vendor file stays far below them)

#: Largest ESI file read (the biggest real vendor files are a few MB).
MAX_ESI_BYTES = 32 * 1024 * 1024
#: Devices in one file, modules in one file.
MAX_DEVICES = 1024
MAX_MODULES = 1024
#: PDOs of one device (the RxPDO and TxPDO index ranges hold 512 each) and entries of one PDO
#: (the mapping object has subindices 1..255).
MAX_PDOS = 1024
MAX_PDO_ENTRIES = 255
#: Objects and data types of one dictionary.
MAX_OBJECTS = 8192
MAX_DATA_TYPES = 8192
#: Init commands of one device, slots of one device, EEPROM categories.
MAX_INIT_CMDS = 1024
MAX_SLOTS = 256
MAX_CATEGORIES = 64
#: Largest object, entry or array in bits: the CoE entry description gives a bit length in 16
#: bits (ETG.1000.6, SDO information); an array has at most 255 elements (subindex 1..255).
MAX_OBJECT_BITS = 0xFFFF
MAX_SUBINDEX = 255
#: EEPROM sizes an ESC can address (ESC datasheet, 0x0502 bit 7: two address bytes; the
#: largest EEPROM a real ESC drives is 4 Mbit).
MIN_EEPROM_BYTES = 128
MAX_EEPROM_BYTES = 512 * 1024
#: Init command data and EEPROM category data.
MAX_DATA_BYTES = 65535

U8, U16, U32 = 0xFF, 0xFFFF, 0xFFFF_FFFF
I32 = (-(1 << 31), (1 << 31) - 1)

# --------------------------------------------------------------------------------------------
# Models


@dataclass(frozen=True)
class EsiWarning:
    """Something of an ESI the parser disabled or could only partly honour, one line:
    ``FILE:LINE: <Element>: message``."""

    file: str
    line: int
    element: str
    message: str

    def __str__(self) -> str:
        return f"{self.file}:{self.line}: <{self.element}>: {self.message}"


#: SyncManager roles (the SII SyncM types 1..4, ``ether_ros.config.sii.SM_TYPE``).
SM_ROLES = ("MBoxOut", "MBoxIn", "Outputs", "Inputs")


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
    # A virtual SyncManager uses no hardware SyncManager: its PDOs are mapped by an FMMU
    # straight onto the ESC memory at ``start`` (e.g. DC registers, ESI ``Virtual``).
    virtual: bool = False
    # Enabled only in OP (ESI ``OpOnly``): the master enables it on SAFEOP -> OP.
    op_only: bool = False
    # The ``<Sm>`` text as the vendor wrote it (the role comes from it or from ControlByte).
    label: str = ""

    @property
    def is_process_data(self) -> bool:
        return self.role in ("Outputs", "Inputs")

    @property
    def sii_enable(self) -> int:
        """The SII SyncM enable byte (ETG.2010)."""
        # A virtual SM takes no hardware SM: flagged virtual and not enabled, so that a master
        # that writes every SM of the SII (SOEM, ethercrab) leaves it disabled and maps it by
        # FMMU only.
        enabled = sii_syncm.ENABLE if self.enable else 0
        base = sii_syncm.VIRTUAL if self.virtual else enabled
        return base | (sii_syncm.OP_ONLY if self.op_only else 0)


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
class InitCmd:
    """One CoE ``<InitCmd>``: an SDO download the master sends in the given transitions
    (``IP``, ``PS``, ``SO``, ...), in ESI order."""

    transitions: tuple[str, ...]
    index: int
    subindex: int
    data: bytes
    complete_access: bool = False
    comment: str = ""
    line: int = 0


#: AL state transitions an init command may name (ETG.2000: I, P, S, O, B).
INIT_TRANSITIONS = frozenset(
    {"IP", "PS", "PI", "SP", "SO", "SI", "OS", "OP", "OI", "IB", "BI", "II", "PP", "SS"}
)


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
    init_cmds: tuple[InitCmd, ...] = ()

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
    # ETG.2001 modules: the index moves by the slot's index increment.
    depends_on_slot: bool = False

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
    # A virtual PDO exists only to be configured (PDO configuration), or maps ESC memory
    # through a virtual SyncManager.
    virtual: bool = False
    # Oversampling (ESI ``OSFac``): the entries are those of one sample; the device may
    # repeat them. The master exchanges one sample (factor 1), see docs/devices.md.
    os_factor: int = 1
    # ETG.2001 modules: the PDO index moves by the slot's PDO increment.
    index_depends_on_slot: bool = False
    line: int = 0

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
    # Vendor categories of the SII (``<Category><CatNo>``, ``<Data>``), copied as they are.
    categories: tuple[tuple[int, bytes], ...] = ()


@dataclass(frozen=True)
class EsiModule:
    """One ``<Module>`` of a modular device (MDP 5001): what a slot can hold."""

    type_name: str
    ident: int  # ModuleIdent: the value the device reports for this module in 0xF050
    name: str
    rx_pdos: tuple[Pdo, ...] = ()
    tx_pdos: tuple[Pdo, ...] = ()
    profile_numbers: tuple[int, ...] = ()


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
    # The IDN dictionary of a Sercos-profile drive (SoE in its mailbox, no CoE: Beckhoff's
    # AX5000): its dictionary's <Index> values are IDNs (S-0-nnnn below 0x8000, P-0-nnnn from
    # it; the parameter set in bits 12..14), never CoE objects, so it is kept apart.
    idns: tuple[OdObject, ...] = ()
    # Device profile numbers (``<Profile><ProfileNo>``, one per ``<ChannelInfo>`` of a
    # multi-channel device): 402 is a CiA 402 drive, 5001 a modular device (MDP).
    profile_numbers: tuple[int, ...] = ()
    timeouts: StateMachineTimeouts = field(default_factory=StateMachineTimeouts)
    # Modular devices (MDP 5001): the modules of the file and the device's slots.
    modules: tuple[EsiModule, ...] = ()
    slots: tuple[EsiSlot, ...] = ()
    # ETG.2001: the PDO index and object index distance from one slot to the next.
    slot_pdo_increment: int = 0
    slot_index_increment: int = 0
    # Names of the ``<AlternativeSmMapping>`` entries (alternative PDO-to-SM assignments).
    alternative_sm_mappings: tuple[str, ...] = ()
    # A passive terminal (``<Type>`` without a ProductCode, e.g. an end cap): it has no
    # EtherCAT slave controller and is not on the bus.
    passive: bool = False
    # Elements of this device the parser disabled (and constructs it honours only in part).
    warnings: tuple[EsiWarning, ...] = ()
    notes: tuple[EsiWarning, ...] = ()
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

    def pdo(self, index: int, direction: str | None = None) -> Pdo | None:
        """The PDO with this index (of ``direction`` when given); a Virtual PDO only when no
        other has the index (vendors reuse indices for Virtual PDOs)."""
        found = [
            p
            for p in (*self.rx_pdos, *self.tx_pdos)
            if p.index == index and (direction is None or p.direction == direction)
        ]
        if not found:
            return None
        return next((p for p in found if not p.virtual), found[0])

    def sm(self, role: str) -> SyncManagerDesc | None:
        """The first real (not virtual) SyncManager of ``role``."""
        for sm in self.sync_managers:
            if sm.role == role and not sm.virtual:
                return sm
        for sm in self.sync_managers:
            if sm.role == role:
                return sm
        return None

    def sm_number(self, number: int) -> SyncManagerDesc | None:
        if 0 <= number < len(self.sync_managers):
            return self.sync_managers[number]
        return None

    @property
    def dc_supported(self) -> bool:
        return bool(self.dc_opmodes)

    @property
    def dc_required(self) -> bool:
        """True when every operation mode uses the distributed clock (AssignActivate bit 8,
        "cyclic unit active", i.e. 0x0981 bit 0): no free-run mode with AssignActivate 0."""
        cyclic = reg_dc.ACTIVATE_CYCLIC << 8  # AssignActivate's high byte goes to 0x0981
        return bool(self.dc_opmodes) and all(m.assign_activate & cyclic for m in self.dc_opmodes)

    @property
    def sync0_required(self) -> bool:
        """True when every operation mode needs SYNC0 (AssignActivate bit 9, 0x0981 bit 1); a
        latch-only mode (EL1252 "DcLatch", 0x0100) needs the clock but no SYNC0."""
        sync0 = reg_dc.ACTIVATE_SYNC0 << 8
        return bool(self.dc_opmodes) and all(m.assign_activate & sync0 for m in self.dc_opmodes)

    @property
    def assign_activate(self) -> int:
        """AssignActivate of the first DC mode that uses SYNC (0 if none)."""
        for m in self.dc_opmodes:
            if m.assign_activate:
                return m.assign_activate
        return 0

    @property
    def init_cmds(self) -> tuple[InitCmd, ...]:
        return self.mailbox.init_cmds if self.mailbox is not None else ()

    def default_rx(self) -> tuple[Pdo, ...]:
        """The RxPDOs assigned by default: those with an ``Sm`` attribute (ETG.2000)."""
        return tuple(p for p in self.rx_pdos if p.sm is not None)

    def default_tx(self) -> tuple[Pdo, ...]:
        return tuple(p for p in self.tx_pdos if p.sm is not None)

    def default_rx_pdos(self) -> tuple[int, ...]:
        """Indices of the RxPDOs assigned by default."""
        return tuple(p.index for p in self.default_rx())

    def default_tx_pdos(self) -> tuple[int, ...]:
        return tuple(p.index for p in self.default_tx())

    def describe(self) -> str:
        return (
            f"{self.type_name} (vendor {self.vendor_id:#010x}, product {self.product_code:#010x},"
            f" revision {self.revision:#010x})"
        )


@dataclass(frozen=True)
class EsiFile:
    """What one ESI file holds: its usable devices and every warning (including the devices
    that had to be skipped, one line each)."""

    path: str
    devices: tuple[EsiDevice, ...]
    warnings: tuple[EsiWarning, ...]
    skipped_devices: tuple[EsiWarning, ...] = ()
    notes: tuple[EsiWarning, ...] = ()


# --------------------------------------------------------------------------------------------
# Numbers

_HEX = re.compile(r"^(?:#x|0x)([0-9A-Fa-f]{1,16})$")
_DEC = re.compile(r"^[+-]?[0-9]{1,20}$")
_DOUBLE_PREFIX = re.compile(r"^#x0x([0-9A-Fa-f]{1,8})$")


def parse_esi_int(text: str) -> int:
    """ESI numbers (ETG.2000 ``HexDecValue``): ``#x1A00`` or ``0x1A00`` (hex, at most 64
    bits) or a decimal number with an optional sign. Anything else — empty text, digit
    separators, other scripts' digits, 5000-digit numbers — is a ``ValueError``."""
    t = text.strip(" \t\r\n")  # XML's white space only
    if m := _HEX.match(t):
        return int(m.group(1), 16)
    if _DEC.match(t):
        return int(t, 10)
    raise ValueError(f"not a number: {text[:40]!r}")


class EsiError(ConfigError):
    """One-line ESI error: ``FILE:LINE: <Element>: message``. As every :class:`ConfigError`
    it carries ``file``, ``line``, ``field`` (``<Element>``) and ``value``; also the bare
    ``element`` and ``message``, so a disabled element can be reported as an :class:`EsiWarning`.
    """

    def __init__(
        self, file: str, line: int, element: str, message: str, value: object = None
    ) -> None:
        super().__init__(
            f"{file}:{line}: <{element}>: {message}",
            file=file,
            line=line or None,
            field=f"<{element}>",
            value=value,
        )
        self.element = element
        self.message = message

    def warning(self, suffix: str = "") -> EsiWarning:
        return EsiWarning(str(self.file), self.line or 0, self.element, self.message + suffix)


# --------------------------------------------------------------------------------------------
# Parser helpers


class _Ctx:
    """Where we are in which file, to name both in errors and warnings; collects warnings."""

    def __init__(self, path: Path) -> None:
        self.path = path
        self.warnings: list[EsiWarning] = []
        self.notes: list[EsiWarning] = []
        self._once: set[str] = set()

    def error(self, el: etree._Element, msg: str, value: object = None) -> EsiError:
        tail = "" if value is None else f": {_show(value)}"
        return EsiError(str(self.path), _line(el), _local(el), f"{msg}{tail}", value)

    def warn(self, el: etree._Element, msg: str, value: object = None) -> None:
        tail = "" if value is None else f": {_show(value)}"
        self.warnings.append(EsiWarning(str(self.path), _line(el), _local(el), f"{msg}{tail}"))

    def warn_once(self, el: etree._Element, msg: str, value: object = None) -> None:
        """``warn``, the first time this message (without its value) comes up."""
        if msg not in self._once:
            self._once.add(msg)
            self.warn(el, f"{msg} (here and further on)", value)

    def note(self, el: etree._Element, msg: str) -> None:
        self.notes.append(EsiWarning(str(self.path), _line(el), _local(el), msg))

    def skipped(self, exc: EsiError, what: str) -> None:
        self.warnings.append(exc.warning(f" ({what} skipped)"))


def _show(value: object) -> str:
    text = repr(value)
    return text if len(text) <= 80 else text[:77] + "..."


def _local(el: etree._Element) -> str:
    tag = el.tag
    if not isinstance(tag, str):
        return "?"
    return tag.rsplit("}", 1)[-1]


def _line(el: etree._Element) -> int:
    line = el.sourceline  # None for an element built rather than parsed
    return line if isinstance(line, int) else 0


def _children(el: etree._Element, name: str) -> Iterator[etree._Element]:
    """The child elements called ``name`` (in any namespace or none), by lxml's own search."""
    return el.iterchildren("{*}" + name)


def _child(el: etree._Element, name: str) -> etree._Element | None:
    return next(_children(el, name), None)


def _count(el: etree._Element, name: str, limit: int, ctx: _Ctx, what: str) -> None:
    """Refuse more than ``limit`` ``name`` children of ``el`` before iterating them."""
    n = sum(1 for _ in _children(el, name))
    if n > limit:
        raise ctx.error(el, f"more than {limit} {what}", n)


def _text(el: etree._Element | None) -> str:
    return "" if el is None or el.text is None else el.text.strip()


def _int(
    ctx: _Ctx,
    el: etree._Element,
    *,
    name: str | None = None,
    lo: int = 0,
    hi: int = U32,
) -> int:
    """The integer text of child ``name`` of ``el`` (or of ``el`` itself), in ``lo..hi``."""
    node = el if name is None else _child(el, name)
    if node is None:
        raise ctx.error(el, f"missing <{name}>")
    try:
        value = parse_esi_int(_text(node))
    except ValueError:
        m = _DOUBLE_PREFIX.match(_text(node))
        if m is None:
            raise ctx.error(node, "not a number", _text(node)) from None
        # '#x0x6041': a vendor tool wrote both prefixes; the number is not in doubt.
        value = int(m.group(1), 16)
        ctx.warn_once(node, "hex number with two prefixes ('#x0x') read as hex", _text(node))
    if not lo <= value <= hi:
        raise ctx.error(node, f"out of range ({_range(lo, hi)})", _text(node))
    return value


def _range(lo: int, hi: int) -> str:
    mask = hi >= 0x10000 and lo >= 0 and (hi + 1) & hi == 0
    fmt = (lambda v: f"{v:#x}") if mask else str
    return f"{fmt(lo)}..{fmt(hi)}"


def _opt_int(
    ctx: _Ctx, el: etree._Element, name: str, default: int, lo: int = 0, hi: int = U32
) -> int:
    node = _child(el, name)
    return default if node is None else _int(ctx, node, lo=lo, hi=hi)


def _attr_int(
    ctx: _Ctx,
    el: etree._Element,
    attr: str,
    default: int | None,
    lo: int = 0,
    hi: int = U32,
) -> int | None:
    raw = el.get(attr)
    if raw is None:
        return default
    try:
        value = parse_esi_int(raw)
    except ValueError:
        raise ctx.error(el, f"attribute {attr} is not a number", raw) from None
    if not lo <= value <= hi:
        raise ctx.error(el, f"attribute {attr} out of range ({_range(lo, hi)})", raw)
    return value


def _attr_bool(el: etree._Element, attr: str, default: bool = False) -> bool:
    raw = el.get(attr)
    if raw is None:
        return default
    return raw.strip().lower() in ("1", "true", "yes")


def _hex_bytes(ctx: _Ctx, el: etree._Element, what: str) -> bytes:
    text = "".join(_text(el).split())
    if len(text) > 2 * MAX_DATA_BYTES:
        raise ctx.error(el, f"{what} longer than {MAX_DATA_BYTES} bytes", len(text) // 2)
    try:
        return bytes.fromhex(text)
    except ValueError:
        raise ctx.error(el, f"{what} is not hex bytes", text) from None


@dataclass
class _TypeDef:
    """A ``<DataType>`` of the dictionary."""

    name: str
    bit_size: int
    base_type: str
    subitems: list[etree._Element]
    array: tuple[int, int] | None  # (lower bound, elements)
    el: etree._Element


# --------------------------------------------------------------------------------------------
# Files: read bounded, parse once per process

_cache: dict[tuple[str, int, int], EsiFile] = {}
_cache_lock = threading.Lock()


def load_esi(path: str | Path) -> list[EsiDevice]:
    """The usable devices of an ESI file. Disabled elements and skipped devices are logged as
    warnings (once per file and process). Raises :class:`ConfigError` (one line, naming file
    and line) when the file itself is unusable or holds no usable device."""
    esi = load_esi_file(path)
    if not esi.devices:
        why = f": {esi.warnings[0]}" if esi.warnings else ""
        raise ConfigError(f"{esi.path}: no usable device in this ESI file{why}")
    return list(esi.devices)


def load_esi_file(path: str | Path) -> EsiFile:
    """Parse an ESI file into an :class:`EsiFile` (devices, warnings, notes). Results are
    cached per (file, modification time, size) for the life of the process."""
    p = Path(path)
    st = _stat_regular(p)
    key = (str(p.resolve()), st.st_mtime_ns, st.st_size)
    with _cache_lock:
        cached = _cache.get(key)
    if cached is not None:
        return cached
    esi = _from_disk_cache_or_parsed(p)
    for w in esi.warnings:
        log.warning("%s", w)
    with _cache_lock:
        if len(_cache) > 256:
            _cache.clear()
        _cache[key] = esi
    return esi


# The files a parse looks up beside its ESI (``<DictionaryFile>``), recorded for the disk cache.
_LOOKUPS: ContextVar[list[esi_cache.Lookup] | None] = ContextVar("esi_lookups", default=None)


def _from_disk_cache_or_parsed(p: Path) -> EsiFile:
    """The parse from the disk cache (``esi_cache``) when its entry still holds, else a
    fresh parse, then stored there."""
    digest = esi_cache.file_digest(p)
    key = f"{p}\0{p.resolve()}"
    if digest is not None:
        cached = esi_cache.load(key, digest, _lookup_still_true)
        if isinstance(cached, EsiFile):
            return cached
    lookups: list[esi_cache.Lookup] = []
    token = _LOOKUPS.set(lookups)
    try:
        esi = _parse_file(p)
    finally:
        _LOOKUPS.reset(token)
    if digest is not None:
        esi_cache.store(key, digest, esi, lookups)
    return esi


def _record_lookup(folder: Path, name: str, target: Path | None) -> None:
    lookups = _LOOKUPS.get()
    if lookups is not None:
        digest = None if target is None else esi_cache.file_digest(target)
        lookups.append(
            esi_cache.Lookup(str(folder), name, None if target is None else str(target), digest)
        )


def _lookup_still_true(lookup: esi_cache.Lookup) -> bool:
    """The same lookup, done now, finds the same file with the same bytes (or again none)."""
    target = _dictionary_path(Path(lookup.folder), lookup.name)
    if (None if target is None else str(target)) != lookup.resolved:
        return False
    return (None if target is None else esi_cache.file_digest(target)) == lookup.digest


def _stat_regular(p: Path) -> os.stat_result:
    """The file's status; a missing file, a directory, a FIFO, a device (``/dev/zero``) or an
    oversized file is refused before anything is read."""
    try:
        st = p.stat()
    except FileNotFoundError:
        raise ConfigError(f"{p}: ESI file not found") from None
    except OSError as exc:
        raise ConfigError(f"{p}: cannot read the ESI file: {exc.strerror}") from None
    if not stat.S_ISREG(st.st_mode):
        raise ConfigError(f"{p}: not a regular file (an ESI must be an XML file)")
    if st.st_size > MAX_ESI_BYTES:
        raise ConfigError(f"{p}: {st.st_size} bytes, more than an ESI may have ({MAX_ESI_BYTES})")
    return st


def _read_bounded(p: Path) -> bytes:
    """The file's bytes, never more than :data:`MAX_ESI_BYTES`, without blocking on a FIFO
    swapped in after the check."""
    try:
        fd = os.open(p, os.O_RDONLY | os.O_NONBLOCK | os.O_CLOEXEC)
    except OSError as exc:
        raise ConfigError(f"{p}: cannot read the ESI file: {exc.strerror}") from None
    try:
        if not stat.S_ISREG(os.fstat(fd).st_mode):
            raise ConfigError(f"{p}: not a regular file (an ESI must be an XML file)")
        chunks: list[bytes] = []
        total = 0
        while True:
            chunk = os.read(fd, 1 << 20)
            if not chunk:
                break
            total += len(chunk)
            if total > MAX_ESI_BYTES:
                raise ConfigError(f"{p}: more than an ESI may have ({MAX_ESI_BYTES} bytes)")
            chunks.append(chunk)
        return b"".join(chunks)
    except OSError as exc:
        raise ConfigError(f"{p}: cannot read the ESI file: {exc.strerror}") from None
    finally:
        os.close(fd)


def _parser(recover: bool = False) -> etree.XMLParser:
    """No entity expansion, DTD loading or network access (a hostile ESI must not grow without
    bounds or reach out); lxml's default limits on depth and text size stay on."""
    return etree.XMLParser(
        remove_comments=True,
        resolve_entities=False,
        load_dtd=False,
        no_network=True,
        huge_tree=False,
        recover=recover,
    )


def _parse_xml(path: Path, ctx: _Ctx | None = None) -> etree._Element:
    """The root element of ``path``. A document type declaration is refused (no vendor ESI has
    one; it is the way in for entity attacks). A file whose only fault is an unescaped ``&``
    (vendors write ``AB&T``) is recovered with a warning naming line and column."""
    data = _read_bounded(path)
    try:
        root = etree.fromstring(data, _parser())
    except etree.XMLSyntaxError as exc:
        root = _recover(path, data, exc, ctx)
    except ValueError as exc:  # e.g. a declared encoding that does not decode
        raise ConfigError(f"{path}:1: not well-formed XML: {_one_line(str(exc))}") from None
    info: Any = root.getroottree().docinfo
    if info.doctype or info.internalDTD is not None:
        raise ConfigError(
            f"{path}:1: <!DOCTYPE>: document type declarations (DTD, entities) are not"
            " supported in an ESI"
        )
    return root


def _one_line(text: str) -> str:
    return " ".join(text.split())


def _recover(path: Path, data: bytes, exc: etree.XMLSyntaxError, ctx: _Ctx | None) -> Any:
    msg = _one_line(exc.msg or "")
    where = f"{path}:{exc.lineno}:{exc.offset}"
    bare_ampersand = "EntityRef" in msg or "xmlParseEntityRef" in msg
    if ctx is None or not bare_ampersand or b"<!DOCTYPE" in data[:4096]:
        raise ConfigError(f"{where}: not well-formed XML: {msg}") from None
    # Escape every '&' that does not start a reference, then parse strictly again: only the
    # vendor's stray ampersands change, and any other fault is still an error.
    fixed = re.sub(rb"&(?!(?:[A-Za-z_][\w.-]*|#[0-9]+|#x[0-9A-Fa-f]+);)", b"&amp;", data)
    try:
        root = etree.fromstring(fixed, _parser())
    except (etree.XMLSyntaxError, ValueError):
        raise ConfigError(f"{where}: not well-formed XML: {msg}") from None
    column = exc.offset
    if m := re.search(r", line (\d+), column (\d+)$", msg):
        column, msg = int(m.group(2)), msg[: m.start()]
    ctx.warnings.append(
        EsiWarning(
            str(path),
            exc.lineno or 0,
            "xml",
            f"not well-formed XML at column {column} ({msg}): an unescaped '&', read as '&amp;'",
        )
    )
    return root


def _parse_file(p: Path) -> EsiFile:
    ctx = _Ctx(p)
    root = _parse_xml(p, ctx)
    if _local(root) in DICTIONARY_ROOTS:
        raise ctx.error(
            root,
            "a dictionary file, not an ESI file: it is read for the devices whose"
            " <Profile><DictionaryFile> names it (load the ESI file beside it)",
            _local(root),
        )
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
    _count(devices_el, "Device", MAX_DEVICES, ctx, "devices in one file")
    modules = _parse_modules(ctx, desc)
    devices: list[EsiDevice] = []
    skipped: list[EsiWarning] = []
    for d in _children(devices_el, "Device"):
        dev_ctx = _Ctx(p)
        try:
            dev = _parse_device(dev_ctx, d, vendor_id, vendor_name, groups, modules)
        except EsiError as exc:
            name = _text(_child(d, "Type")) or "?"
            w = exc.warning(f" (device {name} at line {_line(d)} skipped)")
            skipped.append(w)
            ctx.warnings.extend(dev_ctx.warnings)
            ctx.warnings.append(w)
            continue
        ctx.warnings.extend(dev_ctx.warnings)
        ctx.notes.extend(dev_ctx.notes)
        devices.append(replace(dev, warnings=tuple(dev_ctx.warnings), notes=tuple(dev_ctx.notes)))
    return EsiFile(str(p), tuple(devices), tuple(ctx.warnings), tuple(skipped), tuple(ctx.notes))


# --------------------------------------------------------------------------------------------
# Modules and slots (ETG.2001)


def _parse_modules(ctx: _Ctx, desc: etree._Element) -> dict[int, EsiModule]:
    """``<Descriptions><Modules>`` of a modular device file, by ModuleIdent; a broken module
    is skipped with a warning."""
    modules: dict[int, EsiModule] = {}
    mods_el = _child(desc, "Modules")
    if mods_el is None:
        return modules
    _count(mods_el, "Module", MAX_MODULES, ctx, "modules in one file")
    for m in _children(mods_el, "Module"):
        try:
            module = _parse_module(ctx, m)
        except EsiError as exc:
            ctx.skipped(exc, f"module at line {_line(m)}")
            continue
        modules[module.ident] = module
    return modules


def _parse_module(ctx: _Ctx, m: etree._Element) -> EsiModule:
    type_el = _child(m, "Type")
    if type_el is None or not _text(type_el):
        raise ctx.error(m, "module without <Type>")
    ident = _attr_int(ctx, type_el, "ModuleIdent", None)
    if ident is None:
        raise ctx.error(type_el, "missing attribute ModuleIdent")
    od = {(e.index, e.subindex): e for o in _parse_dictionary(ctx, m) for e in o.entries}
    rx = _parse_pdos(ctx, m, "RxPdo", "rx", od)
    tx = _parse_pdos(ctx, m, "TxPdo", "tx", od)
    return EsiModule(
        type_name=_text(type_el),
        ident=ident,
        name=_text(_child(m, "Name")) or _text(type_el),
        rx_pdos=tuple(rx),
        tx_pdos=tuple(tx),
        profile_numbers=_profile_numbers(ctx, m),
    )


def _parse_slots(
    ctx: _Ctx, dev: etree._Element, modules: dict[int, EsiModule]
) -> tuple[tuple[EsiSlot, ...], int, int]:
    """The slots, the PDO increment and the index increment of a modular device."""
    slots_el = _child(dev, "Slots")
    if slots_el is None:
        return (), 0, 0
    _count(slots_el, "Slot", MAX_SLOTS, ctx, "slots")
    pdo_inc = _attr_int(ctx, slots_el, "SlotPdoIncrement", 0, hi=0x1FF) or 0
    index_inc = _attr_int(ctx, slots_el, "SlotIndexIncrement", 0, hi=U16) or 0
    slots: list[EsiSlot] = []
    for sl in _children(slots_el, "Slot"):
        idents: list[int] = []
        default: int | None = None
        for mi in _children(sl, "ModuleIdent"):
            ident = _int(ctx, mi)
            if modules and ident not in modules:
                ctx.warn(mi, "slot names a module the file does not describe", f"{ident:#x}")
                continue
            idents.append(ident)
            if _attr_bool(mi, "Default"):
                default = ident
        # Slots may also accept whole classes of modules (<ModuleClass>): those add no ident.
        slots.append(
            EsiSlot(
                name=_text(_child(sl, "Name")),
                min_instances=_attr_int(ctx, sl, "MinInstances", 0, hi=MAX_SLOTS) or 0,
                max_instances=_attr_int(ctx, sl, "MaxInstances", 1, hi=MAX_SLOTS) or 0,
                module_idents=tuple(idents),
                default_ident=default,
            )
        )
    return tuple(slots), pdo_inc, index_inc


def place_modules(device: EsiDevice, idents: Iterable[int | None]) -> EsiDevice:
    """``device`` with ``idents[k]`` (a ModuleIdent, None: the slot stays empty) in slot k: each
    module's PDOs join the device's, their PDO indices moved by k × SlotPdoIncrement and the
    indices of entries that depend on the slot by k × SlotIndexIncrement (ETG.2001). The
    module PDOs that name a SyncManager are assigned by default, as the device's own."""
    by_ident = {m.ident: m for m in device.modules}
    rx = list(device.rx_pdos)
    tx = list(device.tx_pdos)
    for slot, ident in enumerate(idents):
        if ident is None:
            continue
        module = by_ident[ident]
        for pdo in (*module.rx_pdos, *module.tx_pdos):
            placed = _placed(pdo, slot, device.slot_pdo_increment, device.slot_index_increment)
            (rx if pdo.direction == "rx" else tx).append(placed)
    return replace(device, rx_pdos=tuple(rx), tx_pdos=tuple(tx))


def _placed(pdo: Pdo, slot: int, pdo_inc: int, index_inc: int) -> Pdo:
    index = pdo.index + (slot * pdo_inc if pdo.index_depends_on_slot or pdo_inc else 0)
    entries = tuple(
        replace(e, index=e.index + slot * index_inc) if e.depends_on_slot and e.index else e
        for e in pdo.entries
    )
    return replace(pdo, index=index & U16, entries=entries)


def default_modules(device: EsiDevice) -> list[int | None]:
    """The module each slot holds by default (None: none)."""
    return [s.default_ident for s in device.slots]


# --------------------------------------------------------------------------------------------
# Directories


def load_esi_paths(paths: Iterable[str | Path]) -> list[EsiDevice]:
    """All devices of the given ESI files and directories (``*.xml`` in them, sorted; a
    directory's dictionary files (:func:`is_dictionary_file`) are not ESI files of their own
    and are passed over)."""
    out: list[EsiDevice] = []
    for item in paths:
        p = Path(item)
        if p.is_dir():
            for f in esi_files(p):
                out.extend(load_esi(f))
        elif p.exists():
            out.extend(load_esi(p))
        else:
            raise ConfigError(f"{p}: ESI file or directory not found")
    return out


def esi_files(directory: Path) -> list[Path]:
    """The ESI files of a directory: ``*.xml`` sorted (regular files), without dictionary
    files (see :func:`is_dictionary_file`)."""
    return [f for f in sorted(directory.glob("*.xml")) if f.is_file() and not is_dictionary_file(f)]


# Root elements of the files a device's ``<Profile><DictionaryFile>`` names: ``<EtherCATDict>``
# (ETG.2000's EtherCATDict.xsd, as Beckhoff ships them) or a bare ``<Dictionary>``. Such a file
# describes no device of its own: it is read for the devices that name it.
DICTIONARY_ROOTS = ("EtherCATDict", "Dictionary")


def is_dictionary_file(path: Path) -> bool:
    """Whether ``path`` is a dictionary file (root element one of ``DICTIONARY_ROOTS``), read
    for the devices that name it and never loaded as an ESI file of its own."""
    return _root_name(path) in DICTIONARY_ROOTS


def _root_name(path: Path) -> str:
    """The root element's name, read from the file's first bytes."""
    try:
        with open(path, "rb") as fh:
            head = fh.read(8192)
    except OSError:
        return ""
    m = re.search(rb"<([A-Za-z_][\w.:-]*)[\s>/]", re.sub(rb"<[?!][^>]*>", b"", head))
    return m.group(1).decode("ascii", "replace").rsplit(":", 1)[-1] if m else ""


# --------------------------------------------------------------------------------------------
# Devices


def _profile_numbers(ctx: _Ctx, el: etree._Element) -> tuple[int, ...]:
    numbers: list[int] = []
    for prof in _children(el, "Profile"):
        for holder in (prof, *_children(prof, "ChannelInfo")):
            no = _child(holder, "ProfileNo")
            if no is not None:
                try:
                    numbers.append(_int(ctx, no, hi=U16))
                except EsiError as exc:
                    ctx.skipped(exc, "profile number")
    return tuple(numbers)


def _device_name(dev: etree._Element, type_name: str) -> str:
    names = list(_children(dev, "Name"))
    for n in names:
        if n.get("LcId", "1033") == "1033":
            return _text(n)
    return _text(names[0]) if names else type_name


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
    type_name = _text(type_el)
    if not type_name:
        raise ctx.error(type_el, "empty device type name")
    product = _attr_int(ctx, type_el, "ProductCode", None)
    revision = _attr_int(ctx, type_el, "RevisionNo", 0) or 0
    group_type = _text(_child(dev, "GroupType"))
    common: dict[str, Any] = {
        "vendor_id": vendor_id,
        "vendor_name": vendor_name,
        "revision": revision,
        "type_name": type_name,
        "name": _device_name(dev, type_name),
        "group_type": group_type,
        "group_name": groups.get(group_type, group_type),
        "physics": dev.get("Physics", ""),
        "source": str(ctx.path),
        "line": _line(dev),
    }
    if product is None:
        # A passive terminal (end cap, shield, potential feed): no ESC, nothing on the bus.
        ctx.note(type_el, f"{type_name}: no ProductCode: a passive terminal, not on the bus")
        return EsiDevice(
            product_code=0,
            sync_managers=(),
            fmmus=(),
            mailbox=None,
            dc_opmodes=(),
            rx_pdos=(),
            tx_pdos=(),
            objects=(),
            eeprom=EepromDesc(),
            passive=True,
            **common,
        )

    sms = _parse_sync_managers(ctx, dev)
    fmmus: list[str] = []
    by_label = {sm.label: sm.role for sm in sms if sm.role in ("Outputs", "Inputs")}
    for f in _children(dev, "Fmmu"):
        role = _text(f)
        if role not in ("Outputs", "Inputs", "MBoxState", ""):
            # A vendor's name (Pollen's "OrbitaIn"): the role of the SM of that name, or the
            # mailbox state FMMU; masters that go by the SII's FMMU list (ethercrab) need one.
            named = by_label.get(role) or ("MBoxState" if "state" in role.lower() else "")
            ctx.note(f, f"FMMU {role!r} is no ETG.2000 role: taken as {named or 'unused'!r}")
            role = named
        fmmus.append(role)
    if len(fmmus) > 16:
        raise ctx.error(dev, "more than 16 FMMUs", len(fmmus))

    mailbox = _parse_mailbox(ctx, dev)
    for role in ("MBoxOut", "MBoxIn"):
        if mailbox is not None and not any(s.role == role for s in sms):
            raise ctx.error(dev, f"device has a <Mailbox> but no {role} SyncManager", type_name)

    dc_modes = _parse_dc(ctx, dev)
    objects = _parse_dictionary(ctx, dev, _dictionary_file_of(ctx, dev))
    idns: list[OdObject] = []
    if mailbox is not None and mailbox.soe and not mailbox.coe:
        idns, objects = objects, []
    od = {(e.index, e.subindex): e for o in objects for e in o.entries}
    _count(dev, "RxPdo", MAX_PDOS, ctx, "RxPDOs")
    _count(dev, "TxPdo", MAX_PDOS, ctx, "TxPDOs")
    rx = _parse_pdos(ctx, dev, "RxPdo", "rx", od, sms)
    tx = _parse_pdos(ctx, dev, "TxPdo", "tx", od, sms)
    _check_duplicate_pdos(ctx, rx, tx)

    slots, pdo_inc, index_inc = _parse_slots(ctx, dev, modules)
    info = _child(dev, "Info")
    return EsiDevice(
        product_code=product,
        sync_managers=tuple(sms),
        fmmus=tuple(fmmus),
        mailbox=mailbox,
        dc_opmodes=tuple(dc_modes),
        rx_pdos=tuple(rx),
        tx_pdos=tuple(tx),
        objects=tuple(objects),
        idns=tuple(idns),
        eeprom=_parse_eeprom(ctx, dev),
        profile_numbers=_profile_numbers(ctx, dev),
        timeouts=_parse_timeouts(ctx, info),
        modules=tuple(modules.values()) if slots else (),
        slots=slots,
        slot_pdo_increment=pdo_inc,
        slot_index_increment=index_inc,
        alternative_sm_mappings=tuple(
            _text(_child(a, "Name")) for a in _children(dev, "AlternativeSmMapping")
        ),
        **common,
    )


def _sm_role(ctx: _Ctx, sm: etree._Element, label: str, control: int | None) -> str:
    """The role of an ``<Sm>``. The ESC goes by the ControlByte (ESC datasheet, 0x0804: mode
    and direction), so its direction decides: a vendor's own name (``DynamicOutputs``) or a
    label that contradicts it (SMC's EX250 calls an input SM "Outputs") takes the role the
    ControlByte gives, with a note. Without a ControlByte the label is the role."""
    if label == "":
        return label
    if control is None:
        if label in SM_ROLES:
            return label
        ctx.warn(sm, "SyncManager name is no role and there is no ControlByte: SM unused", label)
        return ""
    writes = control & reg_sm.DIR_MASK == reg_sm.DIR_WRITE
    if label in ("MBoxOut", "MBoxIn"):
        role = "MBoxOut" if writes else "MBoxIn"
    elif label in ("Outputs", "Inputs"):
        # A process-data SM may run in one-buffer (mailbox) mode: still process data.
        role = "Outputs" if writes else "Inputs"
    else:
        mailbox = control & reg_sm.MODE_MASK == reg_sm.MODE_MAILBOX
        role = (
            ("MBoxOut" if writes else "MBoxIn") if mailbox else ("Outputs" if writes else "Inputs")
        )
    if role != label:
        ctx.note(sm, f"SyncManager {label!r} is {role} (ControlByte {control:#04x})")
    return role


def _parse_sync_managers(ctx: _Ctx, dev: etree._Element) -> list[SyncManagerDesc]:
    sms: list[SyncManagerDesc] = []
    elements = list(_children(dev, "Sm"))
    if len(elements) > 16:
        raise ctx.error(dev, "more than 16 SyncManagers", len(elements))
    for i, sm in enumerate(elements):
        label = _text(sm)
        control = _attr_int(ctx, sm, "ControlByte", None, hi=U8)
        start = _attr_int(ctx, sm, "StartAddress", None, hi=U16)
        if start is None:
            raise ctx.error(sm, "missing attribute StartAddress")
        # ``Enable`` is the SII enable byte; bit 3 there is "enabled only in OP" too.
        enable_raw = sm.get("Enable")
        enable_byte = 1
        if enable_raw is not None:
            if enable_raw.strip().lower() in ("true", "false"):
                enable_byte = int(enable_raw.strip().lower() == "true")
            else:
                enable_byte = _attr_int(ctx, sm, "Enable", 1, hi=U8) or 0
        sms.append(
            SyncManagerDesc(
                number=i,
                role=_sm_role(ctx, sm, label, control),
                start=start,
                default_size=_attr_int(ctx, sm, "DefaultSize", 0, hi=U16) or 0,
                control=control or 0,
                enable=bool(enable_byte & sii_syncm.ENABLE),
                min_size=_attr_int(ctx, sm, "MinSize", None, hi=U16),
                max_size=_attr_int(ctx, sm, "MaxSize", None, hi=U16),
                virtual=_attr_bool(sm, "Virtual"),
                op_only=_attr_bool(sm, "OpOnly") or bool(enable_byte & sii_syncm.OP_ONLY),
                label=label,
            )
        )
    return sms


def _parse_dc(ctx: _Ctx, dev: etree._Element) -> list[DcOpMode]:
    dc_modes: list[DcOpMode] = []
    dc_el = _child(dev, "Dc")
    if dc_el is None:
        return dc_modes
    for om in _children(dc_el, "OpMode"):
        try:
            c0 = _child(om, "CycleTimeSync0")
            c1 = _child(om, "CycleTimeSync1")
            dc_modes.append(
                DcOpMode(
                    name=_text(_child(om, "Name")),
                    description=_text(_child(om, "Desc")),
                    assign_activate=_int(ctx, om, name="AssignActivate", hi=U16),
                    cycle_time_sync0=0 if c0 is None else _int(ctx, c0),
                    cycle_time_sync0_factor=1
                    if c0 is None
                    else (_attr_int(ctx, c0, "Factor", 1, lo=-0x8000, hi=0x7FFF) or 0),
                    shift_time_sync0=_opt_int(ctx, om, "ShiftTimeSync0", 0, *I32),
                    cycle_time_sync1=0 if c1 is None else _int(ctx, c1),
                    cycle_time_sync1_factor=0
                    if c1 is None
                    else (_attr_int(ctx, c1, "Factor", 0, lo=-0x8000, hi=0x7FFF) or 0),
                    shift_time_sync1=_opt_int(ctx, om, "ShiftTimeSync1", 0, *I32),
                )
            )
        except EsiError as exc:
            ctx.skipped(exc, "DC operation mode")
    if len(dc_modes) > 255:
        raise ctx.error(dc_el, "more than 255 DC operation modes", len(dc_modes))
    return dc_modes


def _parse_timeouts(ctx: _Ctx, info: etree._Element | None) -> StateMachineTimeouts:
    d = StateMachineTimeouts()
    sm_el = _child(info, "StateMachine") if info is not None else None
    to_el = _child(sm_el, "Timeout") if sm_el is not None else None
    if to_el is None:
        return d
    try:
        # At most ten minutes per transition: a hostile value must not hold a master forever.
        hi = 600_000
        return StateMachineTimeouts(
            preop_ms=_opt_int(ctx, to_el, "PreopTimeout", d.preop_ms, hi=hi),
            safeop_op_ms=_opt_int(ctx, to_el, "SafeopOpTimeout", d.safeop_op_ms, hi=hi),
            back_to_init_ms=_opt_int(ctx, to_el, "BackToInitTimeout", d.back_to_init_ms, hi=hi),
            back_to_safeop_ms=_opt_int(
                ctx, to_el, "BackToSafeopTimeout", d.back_to_safeop_ms, hi=hi
            ),
        )
    except EsiError as exc:
        ctx.skipped(exc, "state machine timeouts (ETG.2000 defaults used)")
        return d


def _parse_eeprom(ctx: _Ctx, dev: etree._Element) -> EepromDesc:
    ee = _child(dev, "Eeprom")
    if ee is None:
        return EepromDesc()
    size = _opt_int(ctx, ee, "ByteSize", 2048, lo=0, hi=MAX_EEPROM_BYTES)
    if size < MIN_EEPROM_BYTES or size % 128:
        fixed = max(MIN_EEPROM_BYTES, -(-size // 128) * 128)
        ctx.warn(ee, f"ByteSize is not a multiple of 128 (at least 128): {fixed} used", size)
        size = fixed
    cd = b""
    cd_el = _child(ee, "ConfigData")
    if cd_el is not None:
        try:
            cd = _hex_bytes(ctx, cd_el, "ConfigData")
        except EsiError as exc:
            ctx.skipped(exc, "ConfigData")
        if len(cd) > 16:
            ctx.warn(cd_el, "ConfigData longer than 16 bytes: the first 16 used", len(cd))
            cd = cd[:16]
    categories: list[tuple[int, bytes]] = []
    for cat in _children(ee, "Category"):
        if len(categories) >= MAX_CATEGORIES:
            ctx.warn(cat, f"more than {MAX_CATEGORIES} EEPROM categories: the rest skipped")
            break
        try:
            number = _int(ctx, cat, name="CatNo", lo=1, hi=0x7FFE)
            data_el = _child(cat, "Data")
            data = b"" if data_el is None else _hex_bytes(ctx, data_el, "category data")
        except EsiError as exc:
            ctx.skipped(exc, "EEPROM category")
            continue
        categories.append((number, data))
    return EepromDesc(byte_size=size, config_data=cd, categories=tuple(categories))


def _parse_mailbox(ctx: _Ctx, dev: etree._Element) -> MailboxDesc | None:
    mb = _child(dev, "Mailbox")
    if mb is None:
        return None
    coe = _child(mb, "CoE")
    cmds: list[InitCmd] = []
    if coe is not None:
        _count(coe, "InitCmd", MAX_INIT_CMDS, ctx, "init commands")
        for el in _children(coe, "InitCmd"):
            try:
                cmds.append(_parse_init_cmd(ctx, el))
            except EsiError as exc:
                ctx.skipped(exc, "init command")
    for proto in ("EoE", "SoE", "FoE", "AoE", "VoE"):
        p = _child(mb, proto)
        if p is not None and any(True for _ in _children(p, "InitCmd")):
            ctx.note(p, f"{proto} init commands are not sent (the master speaks CoE only)")
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
        init_cmds=tuple(cmds),
    )


def _parse_init_cmd(ctx: _Ctx, el: etree._Element) -> InitCmd:
    transitions = tuple(_text(t).upper() for t in _children(el, "Transition"))
    if not transitions:
        raise ctx.error(el, "init command without <Transition>")
    for t in transitions:
        if t not in INIT_TRANSITIONS:
            raise ctx.error(el, "unknown transition", t)
    ccs = _opt_int(ctx, el, "Ccs", 1, hi=U8)
    if ccs != 1:
        raise ctx.error(el, "only SDO downloads (Ccs 1) are sent", ccs)
    data_el = _child(el, "Data")
    data = b"" if data_el is None else _hex_bytes(ctx, data_el, "Data")
    if not data:
        raise ctx.error(el, "init command without <Data>")
    return InitCmd(
        transitions=transitions,
        index=_int(ctx, el, name="Index", lo=1, hi=U16),
        subindex=_opt_int(ctx, el, "SubIndex", 0, hi=U8),
        data=data,
        complete_access=_attr_bool(el, "CompleteAccess"),
        comment=_text(_child(el, "Comment")),
        line=_line(el),
    )


# --------------------------------------------------------------------------------------------
# PDOs


def _parse_pdos(
    ctx: _Ctx,
    dev: etree._Element,
    tag: str,
    direction: str,
    od: dict[tuple[int, int], OdEntry],
    sms: list[SyncManagerDesc] | None = None,
) -> list[Pdo]:
    """Every ``<RxPdo>``/``<TxPdo>`` of ``dev``; a broken PDO is skipped with a warning."""
    out: list[Pdo] = []
    for el in _children(dev, tag):
        try:
            pdo = _parse_pdo(ctx, el, direction, od)
            if sms is not None and pdo.sm is not None and not 0 <= pdo.sm < len(sms):
                raise ctx.error(el, "PDO names a SyncManager the device does not have", pdo.sm)
        except EsiError as exc:
            index = _text(_child(el, "Index")) or "?"
            ctx.skipped(exc, f"PDO {index}")
            continue
        out.append(pdo)
    if any(p.os_factor > 1 for p in out):
        listed = ", ".join(f"{p.index:#06x}" for p in out if p.os_factor > 1)
        ctx.note(
            dev,
            f"oversampling (OSFac) of {listed}: exchanged at factor 1 (one sample per cycle)",
        )
    return out


def _parse_pdo(
    ctx: _Ctx, el: etree._Element, direction: str, od: dict[tuple[int, int], OdEntry]
) -> Pdo:
    index_el = _child(el, "Index")
    index = _int(ctx, el, name="Index", hi=U16)
    _count(el, "Entry", MAX_PDO_ENTRIES, ctx, "entries in one PDO")
    entries: list[PdoEntry] = []
    for e in _children(el, "Entry"):
        e_index_el = _child(e, "Index")
        idx = _int(ctx, e, name="Index", hi=U16)
        depends = e_index_el is not None and _attr_bool(e_index_el, "DependOnSlot")
        if idx == 0:
            bits = _int(ctx, e, name="BitLen", lo=1, hi=MAX_OBJECT_BITS)
            entries.append(PdoEntry(0, 0, bits, "", 0, ""))
            continue
        bits = _int(ctx, e, name="BitLen", lo=1, hi=MAX_OBJECT_BITS)
        sub = _opt_int(ctx, e, "SubIndex", 0, hi=U8)
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
        if bits > 64 and code not in (dt.OCTET_STRING.code, dt.STRING.code, 0):
            raise ctx.error(e, "BitLen must be 1..64 for a number", bits)
        name = _text(_child(e, "Name")) or f"{idx:#06x}:{sub:02x}"
        entries.append(PdoEntry(idx, sub, bits, name, code, type_name, depends))
    total = sum(e.bit_length for e in entries)
    if total > MAX_OBJECT_BITS:
        raise ctx.error(el, f"PDO longer than {MAX_OBJECT_BITS} bits", total)
    return Pdo(
        index=index,
        name=_text(_child(el, "Name")),
        direction=direction,
        entries=tuple(entries),
        sm=_attr_int(ctx, el, "Sm", None, hi=15),
        fixed=_attr_bool(el, "Fixed"),
        mandatory=_attr_bool(el, "Mandatory"),
        excludes=tuple(_int(ctx, x, hi=U16) for x in _children(el, "Exclude")),
        virtual=_attr_bool(el, "Virtual"),
        os_factor=_attr_int(ctx, el, "OSFac", 1, hi=U16) or 1,
        index_depends_on_slot=index_el is not None and _attr_bool(index_el, "DependOnSlot"),
        line=_line(el),
    )


def _check_duplicate_pdos(ctx: _Ctx, rx: list[Pdo], tx: list[Pdo]) -> None:
    """Two PDOs with one index: fine when at least one is Virtual (vendors reuse indices for
    those, e.g. EL2252); else the later one is skipped with a warning."""
    seen: dict[int, Pdo] = {}
    for pdos in (rx, tx):
        for pdo in list(pdos):
            other = seen.get(pdo.index)
            if other is None:
                seen[pdo.index] = pdo
                continue
            if pdo.virtual or other.virtual:
                if not pdo.virtual:
                    seen[pdo.index] = pdo
                continue
            pdos.remove(pdo)
            ctx.warnings.append(
                EsiWarning(
                    str(ctx.path),
                    pdo.line,
                    "RxPdo" if pdo.direction == "rx" else "TxPdo",
                    f"duplicate PDO index: '{pdo.index:#06x}' (PDO skipped; the first one, at"
                    f" line {other.line}, is used)",
                )
            )


# --------------------------------------------------------------------------------------------
# Dictionary


def _dictionary_file_of(ctx: _Ctx, dev: etree._Element) -> tuple[_Ctx, etree._Element] | None:
    """A ``<Profile><DictionaryFile>``: the dictionary kept in a file of its own, in the ESI's
    folder or below it (its first ``<Dictionary>`` element is used). Vendors write the path
    as Windows does (``Beckhoff AX5xxx\\Beckhoff AX5101-xxxx-0210 Dict.xml``): a backslash
    separates folders, and a name that differs from the file's only in case is the file (the
    tools these files are made for run on a case-insensitive file system). A bad reference is
    a warning naming it: the device loads without a dictionary."""
    for prof in _children(dev, "Profile"):
        ref = _child(prof, "DictionaryFile")
        if ref is None:
            continue
        name = _text(ref)
        folder = ctx.path.parent.resolve()
        target = _dictionary_path(folder, name)
        _record_lookup(folder, name, target)
        if target is None:
            ctx.warn(ref, "DictionaryFile must name a file in the ESI's folder (not read)", name)
            return None
        if not target.is_file():
            # Named as the ESI names it (in the ESI's folder), short enough to read whole.
            shown = str(target.relative_to(folder))
            ctx.warn(ref, "DictionaryFile not found in the ESI's folder (not read)", shown)
            return None
        try:
            root = _parse_dictionary_xml(target)
        except ConfigError as exc:
            ctx.warn(ref, f"DictionaryFile not read: {exc}")
            return None
        found = (
            root
            if _local(root) == "Dictionary"
            else next(
                (e for e in root.iter() if isinstance(e.tag, str) and _local(e) == "Dictionary"),
                None,
            )
        )
        if found is None:
            ctx.warn(ref, "DictionaryFile holds no <Dictionary> (not read)", name)
            return None
        return _Ctx(target), found
    return None


def _dictionary_path(folder: Path, name: str) -> Path | None:
    """The file a ``DictionaryFile`` reference names, relative to the ESI's ``folder``; None
    when the reference is empty, absolute or leaves the folder."""
    parts = [p for p in name.replace("\\", "/").split("/") if p not in ("", ".")]
    if not name or name.startswith(("/", "\\")) or ":" in name or ".." in parts or not parts:
        return None
    target = folder.joinpath(*parts)
    if not target.exists():
        target = _case_insensitive(folder, parts) or target
    resolved = target.resolve()
    return resolved if folder in resolved.parents else None


def _case_insensitive(folder: Path, parts: list[str]) -> Path | None:
    """``folder/parts...`` matched one name at a time without regard to case, or None."""
    here = folder
    for part in parts:
        try:
            match = next((c for c in here.iterdir() if c.name.casefold() == part.casefold()), None)
        except OSError:
            return None
        if match is None:
            return None
        here = match
    return here


# A dictionary file is parsed once per (path, modification time, size) in a process: a vendor
# file names one from many devices, and one is over a megabyte.
_dictionary_xml_cache: dict[tuple[str, int, int], etree._Element] = {}


def _parse_dictionary_xml(path: Path) -> etree._Element:
    st = path.stat()
    key = (str(path), st.st_mtime_ns, st.st_size)
    with _cache_lock:
        root = _dictionary_xml_cache.get(key)
    if root is None:
        root = _parse_xml(path)
        with _cache_lock:
            if len(_dictionary_xml_cache) > 16:
                _dictionary_xml_cache.clear()
            _dictionary_xml_cache[key] = root
    return root


def _parse_dictionary(
    ctx: _Ctx, dev: etree._Element, external: tuple[_Ctx, etree._Element] | None = None
) -> list[OdObject]:
    dictionary = None
    for prof in _children(dev, "Profile"):
        dictionary = _child(prof, "Dictionary")
        if dictionary is not None:
            break
    outer = ctx
    if dictionary is None and external is not None:
        ctx, dictionary = external
    if dictionary is None:
        return []
    typedefs: dict[str, _TypeDef] = {}
    dts = _child(dictionary, "DataTypes")
    if dts is not None:
        _count(dts, "DataType", MAX_DATA_TYPES, ctx, "data types")
        for d in _children(dts, "DataType"):
            try:
                td = _parse_datatype(ctx, d)
            except EsiError as exc:
                ctx.skipped(exc, "data type")
                continue
            typedefs[td.name] = td
    objects: list[OdObject] = []
    objs = _child(dictionary, "Objects")
    if objs is not None:
        _count(objs, "Object", MAX_OBJECTS, ctx, "objects")
        seen: set[int] = set()
        for o in _children(objs, "Object"):
            try:
                obj = _parse_object(ctx, o, typedefs)
                if obj.index in seen:
                    raise ctx.error(o, "duplicate object index", f"{obj.index:#06x}")
            except EsiError as exc:
                index = _text(_child(o, "Index")) or "?"
                ctx.skipped(exc, f"object {index}")
                continue
            seen.add(obj.index)
            objects.append(obj)
    if ctx is not outer:
        outer.warnings.extend(ctx.warnings)
        outer.notes.extend(ctx.notes)
    return objects


def _parse_datatype(ctx: _Ctx, d: etree._Element) -> _TypeDef:
    name = _text(_child(d, "Name"))
    if not name:
        raise ctx.error(d, "data type without <Name>")
    ai = _child(d, "ArrayInfo")
    array = None
    if ai is not None:
        lb = _opt_int(ctx, ai, "LBound", 0, hi=U16)
        n = _int(ctx, ai, name="Elements", hi=U16)
        array = (lb, n)
    bit_size = _opt_int(ctx, d, "BitSize", 0, hi=MAX_OBJECT_BITS)
    _count(d, "SubItem", MAX_SUBINDEX + 1, ctx, "subitems")
    _check_subitem_extent(ctx, d, bit_size)
    return _TypeDef(
        name=name,
        bit_size=bit_size,
        base_type=_text(_child(d, "BaseType")),
        subitems=list(_children(d, "SubItem")),
        array=array,
        el=d,
    )


def _check_subitem_extent(ctx: _Ctx, d: etree._Element, bit_size: int) -> None:
    """A subitem that ends beyond its DataType's BitSize is an inconsistent ESI (gaps between
    subitems are fine: vendors align entries with BitOffs)."""
    if not bit_size:
        return
    for si in _children(d, "SubItem"):
        offs = _child(si, "BitOffs")
        if offs is None:
            continue
        end = _int(ctx, offs, hi=MAX_OBJECT_BITS) + _opt_int(
            ctx, si, "BitSize", 0, hi=MAX_OBJECT_BITS
        )
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
    a = a.lower()
    if a not in ("ro", "rw", "wo", "const"):
        a = access
    return ("ro" if a == "const" else a), m or mapping


def _default(ctx: _Ctx, info: etree._Element | None, bits: int, code: int) -> bytes:
    """Default value bytes from an ``<Info>`` (DefaultData hex, DefaultValue number, or
    DefaultString). A hexadecimal DefaultValue is a bit pattern (``#x80000000`` on a DINT is
    its lowest value); a decimal one must fit the type. A value that does not fit is a warning
    and the default is zero."""
    nbytes = (bits + 7) // 8
    if info is None:
        return bytes(nbytes)
    dd = _child(info, "DefaultData")
    if dd is not None:
        try:
            data = _hex_bytes(ctx, dd, "DefaultData")
        except EsiError as exc:
            ctx.skipped(exc, "default value")
            return bytes(nbytes)
        return data[:nbytes].ljust(nbytes, b"\0") if nbytes else data
    dv = _child(info, "DefaultValue")
    if dv is not None:
        text = _text(dv)
        try:
            value = parse_esi_int(text)
        except ValueError:
            ctx.warn(dv, "DefaultValue is not a number (default 0 used)", text)
            return bytes(nbytes)
        t = dt.BY_CODE.get(code)
        width = max(bits, 1)
        if text[:2].lower() in ("#x", "0x"):
            if value >> width:
                ctx.warn(dv, f"DefaultValue does not fit {width} bits (default 0 used)", text)
                return bytes(nbytes)
            return value.to_bytes(max(nbytes, 1), "little")[:nbytes]
        if t is not None and t.kind in ("int", "uint", "bool") and bits:
            try:
                return dt.encode_value(t, value, bits)
            except ValueError as exc:
                ctx.warn(dv, f"{exc} (default 0 used)", text)
                return bytes(nbytes)
        lo, hi = -(1 << (width - 1)), (1 << width) - 1
        if not lo <= value <= hi:
            ctx.warn(dv, f"DefaultValue does not fit {width} bits (default 0 used)", text)
            return bytes(nbytes)
        return (value & ((1 << width) - 1)).to_bytes(max(nbytes, 1), "little")[:nbytes]
    ds = _child(info, "DefaultString")
    if ds is not None:
        data = _text(ds).encode()
        return data[:nbytes].ljust(nbytes, b"\0") if nbytes else data[:MAX_DATA_BYTES]
    return bytes(nbytes)


def _parse_object(ctx: _Ctx, o: etree._Element, typedefs: dict[str, _TypeDef]) -> OdObject:
    index = _int(ctx, o, name="Index", lo=1, hi=U16)
    name = _text(_child(o, "Name"))
    type_el = _child(o, "Type")
    type_name = _text(type_el)
    if type_el is None or not type_name:
        raise ctx.error(o, "object without <Type>", f"{index:#06x}")
    bit_size = _opt_int(ctx, o, "BitSize", 0, hi=MAX_OBJECT_BITS)
    access, mapping = _flags(o, "ro", "")
    info = _child(o, "Info")
    td = typedefs.get(type_name)
    if td is None or (not td.subitems and td.array is None):
        # A plain variable (VAR) of a basic type, possibly declared as a <DataType> too.
        t = dt.esi_type(type_name) or (dt.esi_type(td.base_type) if td is not None else None)
        sized = _sized_alias(td) if t is None and td is not None else None
        t = t or sized
        if t is None:
            raise ctx.error(type_el, "unknown data type", type_name)
        own_bits = td.bit_size if td is not None else 0
        bits = bit_size or (own_bits if sized else t.bit_length) or own_bits
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
        # An array type used directly: subindex 0 holds the count, the elements follow from
        # subindex 1 (LBound describes the array type's index range, not the subindices).
        object_code = 8
        _lb, n = td.array
        _check_array(ctx, td.el, 1, n)
        entries.append(
            OdEntry(index, 0, "SubIndex 000", dt.UINT8.code, "USINT", 8, "ro", "", bytes([n]))
        )
        elem = dt.esi_type(td.base_type)
        if elem is None:
            raise ctx.error(td.el, "unknown array base type", td.base_type)
        ebits = elem.bit_length or ((td.bit_size // n) if n else 0)
        for k in range(n):
            add(k + 1, f"SubIndex {k + 1:03d}", td.base_type, ebits, td.el, k + 1)
    else:
        pos = 0
        for si in td.subitems:
            sname = _text(_child(si, "Name"))
            stype = _text(_child(si, "Type"))
            sbits = _opt_int(ctx, si, "BitSize", 0, hi=MAX_OBJECT_BITS)
            inner = typedefs.get(stype)
            sub_el = _child(si, "SubIdx")
            if inner is not None and inner.array is not None and sub_el is None:
                # "Elements" of an array object (no SubIdx of its own): one subindex per
                # element, each of the base type's size. They follow what is already there
                # (subindex 0, the count), whatever LBound says.
                object_code = 8
                _lb, n = inner.array
                first = max(pos, 1)
                _check_array(ctx, si, first, n)
                elem = dt.esi_type(inner.base_type)
                ebits = (elem.bit_length if elem is not None else 0) or (
                    sbits // n if sbits and n else 0
                )
                for k in range(n):
                    sub = first + k
                    add(sub, f"SubIndex {sub:03d}", inner.base_type, ebits, si, pos)
                    pos += 1
                pos = max(pos, first + n)
                continue
            sub = pos if sub_el is None else _int(ctx, sub_el, hi=MAX_SUBINDEX)
            add(sub, sname, stype, sbits, si, pos)
            pos += 1
    subs = [e.subindex for e in entries]
    if len(set(subs)) != len(subs):
        raise ctx.error(o, "duplicate subindex in object", f"{index:#06x}")
    return OdObject(index, name, object_code, type_name, bit_size or td.bit_size, tuple(entries))


def _check_array(ctx: _Ctx, el: etree._Element, first: int, elements: int) -> None:
    if first + elements - 1 > MAX_SUBINDEX:
        raise ctx.error(
            el,
            f"array of {elements} elements from subindex {first} does not fit in subindices"
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
    base = dt.esi_type(inner.base_type) or _sized_alias(inner)
    if base is None:
        raise ctx.error(el, "unknown data type", tname)
    return base.code, size or base.bit_length


def _sized_alias(td: _TypeDef) -> dt.DataType | None:
    """The type of a ``<DataType>`` that gives only a name and a BitSize (an enumeration with
    ``<EnumInfo>`` values, or a display variant such as Beckhoff's ``UINT_IDN``, ``UDINT_hex``,
    ``UINT10``): ETG.2000 enumerations are unsigned integers of their BitSize, and so is a
    sized alias. The smallest unsigned type that holds BitSize, which the entry's own bit
    length then narrows; None without a BitSize or with a BaseType of its own."""
    if td.base_type or td.subitems or td.array is not None or not 0 < td.bit_size <= 64:
        return None
    bits = td.bit_size
    name = (
        f"BIT{bits}"
        if bits <= 8
        else next(
            n for w, n in ((16, "UINT"), (24, "UINT24"), (32, "UDINT"), (64, "ULINT")) if bits <= w
        )
    )
    return dt.esi_type(name)
