"""Slave Information Interface (SII) EEPROM images, ETG.2010.

:func:`build_sii` turns an ESI device into the EEPROM content a real slave would carry (the
simulator serves it through the ESC's EEPROM interface); :func:`parse_sii` decodes such an image
(the master reads it during bring-up, ``ether-ros sii-read`` prints it).

Layout: 64 header words (configuration area with its CRC, identity, mailbox, protocols, size,
version), then categories from word 0x40: ``type:u16, size_in_words:u16, data``, ending with
0xFFFF. All values little endian.

The byte layout of the categories and their records (SyncM, TxPDO/RxPDO, DC, the General bits)
is the protocol crate's (``crates/protocol/src/sii.rs``, the codec the simulator reads the
image with); this module decides what goes into them.
"""

from __future__ import annotations

import logging
import struct
import unicodedata
from dataclasses import dataclass, field

from ether_ros._native.protocol import (
    parse_sii_dcs,
    parse_sii_pdos,
    parse_sii_syncms,
    sii_categories,
    sii_category,
    sii_category_bytes,
    sii_checksum,
    sii_dc_record,
    sii_fmmu,
    sii_general,
    sii_pdo,
    sii_pdo_entry_record,
    sii_pdo_record,
    sii_syncm,
    sii_syncm_record,
    sii_word,
)
from ether_ros.config.esi import MAX_EEPROM_BYTES, EsiDevice, Pdo
from ether_ros.errors import ConfigError

log = logging.getLogger(__name__)

# Category types and header word addresses are the protocol crate's (ETG.2010); in bytes:
HEADER_BYTES = 2 * sii_word.FIRST_CATEGORY
CHECKSUMMED = sii_word.CHECKSUM_COVERS  # bytes of words 0..6 the CRC-8 in word 7 covers
#: The EEPROM bytes SOEM reads (its EC_MAXEEPBUF): categories past them it does not find.
SOEM_EEPROM_WINDOW = 4096

SM_TYPE = {
    "": sii_syncm.TYPE_UNUSED,
    "MBoxOut": sii_syncm.TYPE_MBOX_OUT,
    "MBoxIn": sii_syncm.TYPE_MBOX_IN,
    "Outputs": sii_syncm.TYPE_OUTPUTS,
    "Inputs": sii_syncm.TYPE_INPUTS,
}
SM_ROLE = {v: k for k, v in SM_TYPE.items()}
FMMU_TYPE = {
    "": sii_fmmu.UNUSED,
    "Outputs": sii_fmmu.OUTPUTS,
    "Inputs": sii_fmmu.INPUTS,
    "MBoxState": sii_fmmu.MBOX_STATE,
}
FMMU_ROLE = {v: k for k, v in FMMU_TYPE.items()}


# --------------------------------------------------------------------------------------------
# Decoded image


@dataclass(frozen=True)
class SiiGeneral:
    group: str
    image: str
    order: str
    name: str
    coe_details: int  # bit0 SDO, bit1 SDO info, bit2 PDO assign, bit3 PDO config,
    # bit4 upload at startup, bit5 SDO complete access
    foe_details: int
    eoe_details: int
    flags: int
    current_on_ebus_ma: int
    physical_ports: int  # 4 bits per port: 0 none, 1 MII, 3 EBUS


@dataclass(frozen=True)
class SiiSyncManager:
    start: int
    length: int
    control: int
    enable: int
    role: str  # 'MBoxOut' | 'MBoxIn' | 'Outputs' | 'Inputs' | ''


@dataclass(frozen=True)
class SiiPdoEntry:
    index: int
    subindex: int
    name: str
    data_type: int
    bit_length: int


@dataclass(frozen=True)
class SiiPdo:
    index: int
    sm: int
    name: str
    flags: int
    entries: tuple[SiiPdoEntry, ...]

    @property
    def bit_length(self) -> int:
        return sum(e.bit_length for e in self.entries)


@dataclass(frozen=True)
class SiiDc:
    cycle_time_sync0: int
    shift_time_sync0: int
    shift_time_sync1: int
    sync1_cycle_factor: int
    assign_activate: int
    sync0_cycle_factor: int
    name: str
    description: str


@dataclass(frozen=True)
class SiiInfo:
    pdi_control: int
    pdi_config: int
    alias: int
    checksum: int
    checksum_ok: bool
    vendor_id: int
    product_code: int
    revision: int
    serial: int
    bootstrap_mailbox: tuple[int, int, int, int]  # rx offset, rx size, tx offset, tx size
    mailbox: tuple[int, int, int, int]  # standard mailbox: rx offset, rx size, tx offset, tx size
    mailbox_protocols: int  # AoE 0x01, EoE 0x02, CoE 0x04, FoE 0x08, SoE 0x10, VoE 0x20
    eeprom_bytes: int
    version: int
    strings: tuple[str, ...] = ()
    general: SiiGeneral | None = None
    fmmus: tuple[str, ...] = ()
    sync_managers: tuple[SiiSyncManager, ...] = ()
    tx_pdos: tuple[SiiPdo, ...] = ()
    rx_pdos: tuple[SiiPdo, ...] = ()
    dc: tuple[SiiDc, ...] = ()
    categories: tuple[int, ...] = field(default=())  # category types in image order

    @property
    def name(self) -> str:
        return self.general.name if self.general else ""

    @property
    def has_coe(self) -> bool:
        return bool(self.mailbox_protocols & 0x04)


# --------------------------------------------------------------------------------------------
# Builder


class _Strings:
    def __init__(self) -> None:
        self.items: list[str] = []
        self._index: dict[str, int] = {}

    def index(self, text: str) -> int:
        """1-based string index; 0 means 'no string'."""
        if not text:
            return 0
        if text in self._index:
            return self._index[text]
        if len(self.items) >= 255:
            # The category indexes strings with one byte: the rest go without a name.
            return 0
        self.items.append(text)
        self._index[text] = len(self.items)
        return len(self.items)

    def copy(self) -> _Strings:
        other = _Strings()
        other.items = list(self.items)
        other._index = dict(self._index)
        return other

    def encode(self) -> bytes:
        out = bytearray([len(self.items)])
        for s in self.items:
            b = sii_text(s)[:255]
            out += bytes([len(b)]) + b
        return bytes(out)


# Characters vendors use that have no ASCII decomposition.
_ASCII_FOR = {"µ": "u", "μ": "u", "°": "deg", "±": "+/-", "ß": "ss", "Ω": "Ohm", "€": "EUR"}


def sii_text(text: str) -> bytes:
    """A string as the SII stores it: printable ASCII (ETG.2010 strings are visible strings),
    which every master decodes. Accents are dropped ("é" → "e"), a few signs spelled out
    ("µs" → "us"), anything else is "?" and control characters are dropped."""
    spelled = "".join(_ASCII_FOR.get(c, c) for c in text)
    plain = unicodedata.normalize("NFKD", spelled)
    out = []
    for c in plain:
        if unicodedata.combining(c):
            continue
        if " " <= c <= "~":
            out.append(c)
        elif not unicodedata.category(c).startswith("C"):
            out.append("?")
    return "".join(out).encode("ascii")


def _category(ctype: int, data: bytes) -> bytes:
    return sii_category_bytes(ctype, data)


def _pdo_category(
    device: EsiDevice, pdos: tuple[Pdo, ...], strings: _Strings, named: bool = True
) -> bytes:
    """The TxPDO or RxPDO category. An entry longer than 255 bits (the category's bit length
    is one byte) cannot be described: the PDO is left out with a warning."""
    out = bytearray()
    for p in pdos:
        too_long = next((e for e in p.entries if e.bit_length > 0xFF), None)
        if too_long is not None or len(p.entries) > 0xFF:
            log.warning(
                "%s: %s: PDO 0x%04X has an entry of more than 255 bits: not in the SII",
                device.source,
                device.type_name,
                p.index,
            )
            continue
        flags = (
            (sii_pdo.FLAG_MANDATORY if p.mandatory else 0)
            | (sii_pdo.FLAG_DEFAULT if p.sm is not None else 0)
            | (sii_pdo.FLAG_FIXED if p.fixed else 0)
        )
        out += sii_pdo_record(
            p.index,
            len(p.entries),
            sii_pdo.NO_SM if p.sm is None else p.sm,
            strings.index(p.name),
            flags,
        )
        for e in p.entries:
            out += sii_pdo_entry_record(
                e.index,
                e.subindex,
                strings.index(e.name) if named else 0,
                e.data_type & 0xFF,
                e.bit_length,
            )
    return bytes(out)


def build_sii(device: EsiDevice, alias: int = 0, serial: int = 0) -> bytes:
    """The SII EEPROM image of ``device``: ``device.eeprom.byte_size`` bytes, 0xFF filled, or
    more (a power of two, with a warning) when the content needs more than the ESI says."""
    if not 0 <= alias <= 0xFFFF:
        raise ConfigError(f"SII alias must be 0..65535, got {alias}")
    if not 0 <= serial <= 0xFFFFFFFF:
        raise ConfigError(f"SII serial must be 0..0xFFFFFFFF, got {serial}")
    strings = _Strings()
    head = bytearray(HEADER_BYTES)
    config = device.eeprom.config_data[:CHECKSUMMED].ljust(CHECKSUMMED, b"\0")
    head[0:CHECKSUMMED] = config
    struct.pack_into("<H", head, 2 * sii_word.CONFIGURED_ALIAS, alias)
    head[CHECKSUMMED] = sii_checksum(bytes(head[0:CHECKSUMMED]))
    head[CHECKSUMMED + 1] = 0
    struct.pack_into(
        "<IIII",
        head,
        2 * sii_word.VENDOR_ID,
        device.vendor_id,
        device.product_code,
        device.revision,
        serial,
    )
    mbx_out, mbx_in = device.sm("MBoxOut"), device.sm("MBoxIn")
    if device.mailbox is not None and mbx_out is not None and mbx_in is not None:
        mbx = (mbx_out.start, mbx_out.default_size, mbx_in.start, mbx_in.default_size)
        struct.pack_into(
            "<HHHH", head, 2 * sii_word.BOOT_RX_MBX_OFFSET, *mbx
        )  # bootstrap mailbox: same as standard
        struct.pack_into("<HHHH", head, 2 * sii_word.STD_RX_MBX_OFFSET, *mbx)
        struct.pack_into("<H", head, 2 * sii_word.MBX_PROTOCOL, device.mailbox.protocols)

    # Categories. Strings first: the others reference them, so build them before encoding.
    mb = device.mailbox
    coe = 0
    if mb is not None and mb.coe:
        coe = (
            sii_general.COE_SDO
            | (sii_general.COE_SDO_INFO if mb.sdo_info else 0)
            | (sii_general.COE_PDO_ASSIGN if mb.pdo_assign else 0)
            | (sii_general.COE_PDO_CONFIG if mb.pdo_config else 0)
            | (sii_general.COE_COMPLETE_ACCESS if mb.complete_access else 0)
        )
    ports = 0
    port_type = {
        "Y": sii_general.PORT_MII,
        "K": sii_general.PORT_EBUS,
        "H": sii_general.PORT_FAST_HOT_CONNECT,
    }
    for i, ch in enumerate(device.physics[:4]):
        ports |= port_type.get(ch, sii_general.PORT_NONE) << (4 * i)
    general = bytearray(sii_general.LEN)
    # The name must be string 1: SOEM takes string 1 as the slave name, IgH the NameIdx.
    general[sii_general.NAME] = strings.index(device.name)
    general[sii_general.GROUP] = strings.index(device.group_type)
    general[sii_general.IMAGE] = 0
    general[sii_general.ORDER] = strings.index(device.type_name)
    general[sii_general.COE_DETAILS] = coe
    general[sii_general.FOE_DETAILS] = 1 if mb is not None and mb.foe else 0
    general[sii_general.EOE_DETAILS] = 1 if mb is not None and mb.eoe else 0
    general[sii_general.FLAGS] = sii_general.FLAG_ENABLE_SAFEOP
    struct.pack_into("<h", general, sii_general.CURRENT_ON_EBUS, 0)
    general[sii_general.GROUP_COPY] = general[sii_general.GROUP]
    struct.pack_into("<H", general, sii_general.PHYSICAL_PORTS, ports)
    fmmu = bytes(FMMU_TYPE[r] for r in device.fmmus)
    if len(fmmu) % 2:
        fmmu += bytes([sii_fmmu.PADDING])  # category padding: 0xFF marks an unused FMMU
    syncm = bytearray()
    for sm in device.sync_managers:
        size = sm.default_size
        if sm.role in ("Outputs", "Inputs") and not size:
            kind = "rx" if sm.role == "Outputs" else "tx"
            pdos = device.rx_pdos if kind == "rx" else device.tx_pdos
            size = (sum(p.bit_length for p in pdos if p.sm == sm.number) + 7) // 8
        # Enable byte (ETG.2010): a virtual SM is flagged and not enabled (it takes no
        # hardware SM: a master maps its memory with an FMMU only), an OpOnly SM flagged.
        enable = sm.sii_enable
        syncm += sii_syncm_record(sm.start, size & 0xFFFF, sm.control, enable, SM_TYPE[sm.role])
    # The PDO categories, strings and DC category: as much as the ESI's EEPROM holds. A CoE
    # device's vendor tool leaves out what masters read over CoE (ETG.2010: the PDO categories
    # describe the PDOs of a device without CoE): first the PDOs not assigned by default, then
    # the entry names, then the PDO categories; a device without CoE keeps its default PDOs.
    coe_pdos = mb is not None and mb.coe and (mb.pdo_assign or mb.sdo_info)
    levels = ("all", "default", "unnamed") + (("none",) if coe_pdos else ())
    for level in levels:
        trial = strings.copy()
        body = _body(device, level, trial, bytes(general), fmmu, bytes(syncm))
        if len(head) + len(body) <= device.eeprom.byte_size:
            break
    needed = len(head) + len(body)
    size = device.eeprom.byte_size
    if needed > size:
        # As big as the content needs (a power of two, as EEPROMs come): the ESI's ByteSize
        # describes the vendor's EEPROM, whose SII the vendor's tool made smaller.
        grown = max(size, 128)
        while grown < needed:
            grown *= 2
        log.warning(
            "%s: %s: the SII needs %d bytes, more than <Eeprom><ByteSize> %d: the simulated "
            "EEPROM has %d",
            device.source,
            device.type_name,
            needed,
            size,
            grown,
        )
        size = grown
    if size > MAX_EEPROM_BYTES:
        raise ConfigError(
            f"{device.source}: SII image of {device.type_name} needs {needed} bytes, more than an"
            f" EEPROM holds ({MAX_EEPROM_BYTES})"
        )
    size_kbit = size * 8 // 1024
    struct.pack_into("<HH", head, 2 * sii_word.SIZE, max(size_kbit - 1, 0), 1)
    image = bytes(head) + bytes(body)
    return image.ljust(size, b"\xff")


def _body(
    device: EsiDevice, level: str, strings: _Strings, general: bytes, fmmu: bytes, syncm: bytes
) -> bytes:
    """The categories after the header, the PDO categories as ``level`` says: ``all`` PDOs,
    the ``default`` assigned ones, those ``unnamed`` (no entry names) or ``none``."""
    tx_pdos, rx_pdos = device.tx_pdos, device.rx_pdos
    if level != "all":
        tx_pdos = tuple(p for p in tx_pdos if p.sm is not None)
        rx_pdos = tuple(p for p in rx_pdos if p.sm is not None)
    if level == "none":
        tx_pdos = rx_pdos = ()
    named = level == "all" or level == "default"
    tx = _pdo_category(device, tx_pdos, strings, named)
    rx = _pdo_category(device, rx_pdos, strings, named)
    dc = bytearray()
    for m in device.dc_opmodes:
        dc += sii_dc_record(
            m.cycle_time_sync0,
            m.shift_time_sync0,
            m.shift_time_sync1,
            m.cycle_time_sync1_factor & 0xFFFF,
            m.assign_activate,
            m.cycle_time_sync0_factor & 0xFFFF,
            strings.index(m.name),
            strings.index(m.description),
        )
    essential = bytearray(_category(sii_category.GENERAL, general))
    if fmmu:
        essential += _category(sii_category.FMMU, fmmu)
    if syncm:
        essential += _category(sii_category.SYNCM, syncm)
    pdos = bytearray()
    if tx:
        pdos += _category(sii_category.TXPDO, tx)
    if rx:
        pdos += _category(sii_category.RXPDO, rx)
    text = _category(sii_category.STRINGS, strings.encode())
    if HEADER_BYTES + len(text) + len(essential) <= SOEM_EEPROM_WINDOW:
        body = bytearray(text + essential + pdos)  # the usual order (ETG.2010's examples)
    else:
        # SOEM reads the first 4 KiB of an EEPROM only (EC_MAXEEPBUF): General, FMMU and
        # SyncM go first so that it finds them; the strings after (names late in a long list
        # are lost to SOEM, not the device).
        body = bytearray(essential + text + pdos)
    if dc:
        body += _category(sii_category.DC, bytes(dc))
    ours = {sii_category.STRINGS, sii_category.GENERAL, sii_category.FMMU, sii_category.SYNCM,
            sii_category.TXPDO, sii_category.RXPDO, sii_category.DC}  # fmt: skip
    for number, data in device.eeprom.categories:
        if number in ours:
            continue  # made from the ESI above
        body += _category(number, data)
    body += struct.pack("<H", sii_category.END)
    return bytes(body)


# --------------------------------------------------------------------------------------------
# Decoder


class SiiFormatError(ConfigError):
    """The bytes are not a valid SII image; says where (byte offset) and why."""


def parse_sii(data: bytes) -> SiiInfo:
    """Decode an SII image (at least the 128-byte header; categories as far as present).

    A category list that runs past the data ends the decoding (a master may read only the
    first part of the EEPROM); malformed categories raise :class:`SiiFormatError`.
    """
    if len(data) < HEADER_BYTES:
        raise SiiFormatError(
            f"SII image too short: {len(data)} bytes, the header alone is {HEADER_BYTES}"
        )
    w = struct.unpack_from("<8H", data, 0)
    vendor, product, revision, serial = struct.unpack_from("<IIII", data, 2 * sii_word.VENDOR_ID)
    boot = struct.unpack_from("<HHHH", data, 2 * sii_word.BOOT_RX_MBX_OFFSET)
    std = struct.unpack_from("<HHHH", data, 2 * sii_word.STD_RX_MBX_OFFSET)
    (protocols,) = struct.unpack_from("<H", data, 2 * sii_word.MBX_PROTOCOL)
    size_word, version = struct.unpack_from("<HH", data, 2 * sii_word.SIZE)
    checksum = w[sii_word.CHECKSUM] & 0xFF
    strings: list[str] = []
    general_raw: bytes | None = None
    fmmus: tuple[str, ...] = ()
    sms: list[SiiSyncManager] = []
    tx: list[SiiPdo] = []
    rx: list[SiiPdo] = []
    dcs: list[SiiDc] = []
    cats: list[int] = []
    pdo_raw: list[tuple[int, bytes]] = []
    dc_raw = b""
    for pos, ctype, body in sii_categories(data):
        cats.append(ctype)
        if ctype == sii_category.STRINGS:
            strings = _parse_strings(body, pos)
        elif ctype == sii_category.GENERAL:
            if len(body) < sii_general.MIN_LEN:
                raise SiiFormatError(f"SII GENERAL category at byte {pos} is {len(body)} bytes")
            general_raw = body
        elif ctype == sii_category.FMMU:
            fmmus = tuple(FMMU_ROLE.get(b, "") for b in body if b != sii_fmmu.PADDING)
        elif ctype == sii_category.SYNCM:
            for start_addr, length, ctrl, _status, enable, smtype in parse_sii_syncms(body):
                sms.append(
                    SiiSyncManager(start_addr, length, ctrl, enable, SM_ROLE.get(smtype, ""))
                )
        elif ctype in (sii_category.TXPDO, sii_category.RXPDO):
            pdo_raw.append((ctype, body))
        elif ctype == sii_category.DC:
            dc_raw = body

    def s(i: int) -> str:
        return strings[i - 1] if 1 <= i <= len(strings) else ""

    for ctype, body in pdo_raw:
        (tx if ctype == sii_category.TXPDO else rx).extend(_parse_pdos(body, s))
    for c0, sh0, sh1, f1, aa, f0, ni, di in parse_sii_dcs(dc_raw):
        dcs.append(SiiDc(c0, sh0, sh1, f1, aa, f0, s(ni), s(di)))
    general = None
    if general_raw is not None:
        g = general_raw
        general = SiiGeneral(
            group=s(g[sii_general.GROUP]),
            image=s(g[sii_general.IMAGE]),
            order=s(g[sii_general.ORDER]),
            name=s(g[sii_general.NAME]),
            coe_details=g[sii_general.COE_DETAILS],
            foe_details=g[sii_general.FOE_DETAILS],
            eoe_details=g[sii_general.EOE_DETAILS],
            flags=g[sii_general.FLAGS],
            current_on_ebus_ma=struct.unpack_from("<h", g, sii_general.CURRENT_ON_EBUS)[0],
            physical_ports=struct.unpack_from("<H", g, sii_general.PHYSICAL_PORTS)[0],
        )
    return SiiInfo(
        pdi_control=w[sii_word.PDI_CONTROL],
        pdi_config=w[sii_word.PDI_CONFIG],
        alias=w[sii_word.CONFIGURED_ALIAS],
        checksum=checksum,
        checksum_ok=sii_checksum(data[0:CHECKSUMMED]) == checksum,
        vendor_id=vendor,
        product_code=product,
        revision=revision,
        serial=serial,
        bootstrap_mailbox=boot,
        mailbox=std,
        mailbox_protocols=protocols,
        eeprom_bytes=(size_word + 1) * 128,
        version=version,
        strings=tuple(strings),
        general=general,
        fmmus=fmmus,
        sync_managers=tuple(sms),
        tx_pdos=tuple(tx),
        rx_pdos=tuple(rx),
        dc=tuple(dcs),
        categories=tuple(cats),
    )


def _parse_strings(body: bytes, pos: int) -> list[str]:
    if not body:
        return []
    count, off, out = body[0], 1, []
    for i in range(count):
        if off >= len(body):
            raise SiiFormatError(f"SII STRINGS category at byte {pos}: string {i + 1} missing")
        n = body[off]
        if off + 1 + n > len(body):
            raise SiiFormatError(f"SII STRINGS category at byte {pos}: string {i + 1} truncated")
        out.append(body[off + 1 : off + 1 + n].decode("latin-1"))
        off += 1 + n
    return out


def _parse_pdos(body: bytes, s: object) -> list[SiiPdo]:
    assert callable(s)
    pdos, truncated = parse_sii_pdos(body)
    if truncated is not None:
        raise SiiFormatError(f"SII PDO {truncated:#06x}: entry list truncated")
    return [
        SiiPdo(
            index,
            sm,
            s(name_idx),
            flags,
            tuple(SiiPdoEntry(ei, es, s(en), edt, ebits) for ei, es, en, edt, ebits in entries),
        )
        for index, sm, name_idx, flags, entries in pdos
    ]
