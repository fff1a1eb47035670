"""Slave specs for the simulator: one ``_native.SlaveSpec`` per slave, built from the bus
config and the ESI.

``SlaveSpec`` is the typed contract with ``SimNetwork.add_slave`` (a frozen class with a
keyword-only constructor, documented at the top of ``crates/py/src/sim_bindings.rs``, checked
when made): identity, the SII EEPROM image, the CoE dictionary
(objects and entries with their default values), the firmware model and its parameters, clock
drift and propagation delay, where the slave is connected (``upstream``), DC capability, and
the standard mailbox, a Sercos drive's IDN dictionary (SoE) and the FoE file store
(``foe_spec``, from the slave's ``sim: {foe: ...}``).
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

from ether_ros._native import FoeSpec, MailboxSpec, SlaveSpec
from ether_ros._native.protocol import coe, soe
from ether_ros.config import types as dt
from ether_ros.config.bus import BusConfig, SimFoeConfig, SlaveConfig
from ether_ros.config.cia402 import AXIS_STRIDE, MAX_AXES, MODES, SUPPORTED_MODES, offered_modes
from ether_ros.config.esi import EsiDevice, OdObject, Pdo, PdoEntry
from ether_ros.config.process import pdo_sync_manager
from ether_ros.config.sii import SM_TYPE, build_sii
from ether_ros.errors import ConfigError

# Serial numbers of simulated slaves when the config gives none: recognisable, and unique
# along the bus (0x5E000000 + position).
SERIAL_BASE = 0x5E00_0000


def mailbox_spec(device: EsiDevice) -> MailboxSpec | None:
    """Standard mailbox placement from the ESI's mailbox SyncManagers (None without mailbox)."""
    out, inp = device.sm("MBoxOut"), device.sm("MBoxIn")
    if device.mailbox is None or out is None or inp is None:
        return None
    return MailboxSpec(
        rx_offset=out.start,
        rx_size=out.default_size,
        tx_offset=inp.start,
        tx_size=inp.default_size,
    )


def foe_spec(
    foe: SimFoeConfig | None, device: EsiDevice, *, slave: str, base: Path | None = None
) -> FoeSpec | None:
    """The FoE store of a slave from its ``sim: {foe: ...}`` (None: the simulator's default,
    an empty store). A file's ``path`` is read relative to ``base`` (the bus config's
    directory). A store for a device whose ESI does not announce FoE, a file named twice, a
    file that cannot be read or files beyond the capacity are a ``ConfigError`` naming the
    slave."""
    if foe is None:
        return None
    where = f"slave '{slave}': sim.foe"
    if device.mailbox is None or not device.mailbox.foe:
        raise ConfigError(f"{where}: the device's ESI does not announce FoE (<Mailbox><FoE/>)")
    files: list[tuple[str, bytes]] = []
    for f in foe.files:
        if any(name == f.name for name, _ in files):
            raise ConfigError(f"{where}: file '{f.name}' is given twice")
        if f.text is not None:
            data = f.text.encode()
        elif f.hex is not None:
            data = bytes.fromhex(f.hex)
        else:
            p = Path(f.path or "")
            p = p if p.is_absolute() or base is None else base / p
            try:
                data = p.read_bytes()
            except OSError as exc:
                raise ConfigError(f"{where}: file '{f.name}': cannot read {p}: {exc}") from None
        files.append((f.name, data))
    try:
        return FoeSpec(
            capacity=foe.capacity,
            password=foe.password,
            files=files,
            firmware=foe.firmware,
            busy=foe.busy,
        )
    except ValueError as exc:
        raise ConfigError(f"{where}: {exc}") from None


def loopback_pairs(device: EsiDevice) -> list[tuple[int, int, int, int]]:
    """Output → input links of the ``loopback`` model: each output entry (of any RxPDO, in the
    ESI's order, each entry once) with the first input entry not yet taken (of any TxPDO) of
    the same data type and bit length. Virtual PDOs (ESC registers, not the dictionary) are not
    paired."""
    outputs = _pdo_entries(tuple(p for p in device.rx_pdos if not p.virtual))
    free = _pdo_entries(tuple(p for p in device.tx_pdos if not p.virtual))
    pairs: list[tuple[int, int, int, int]] = []
    for out in outputs:
        for k, inp in enumerate(free):
            if (inp.data_type, inp.bit_length) == (out.data_type, out.bit_length):
                pairs.append((out.index, out.subindex, inp.index, inp.subindex))
                del free[k]
                break
    return pairs


def _pdo_entries(pdos: tuple[Pdo, ...]) -> list[PdoEntry]:
    seen: set[tuple[int, int]] = set()
    out: list[PdoEntry] = []
    for p in pdos:
        for e in p.entries:
            if not e.is_padding and (e.index, e.subindex) not in seen:
                seen.add((e.index, e.subindex))
                out.append(e)
    return out


def is_mapping_object(index: int) -> bool:
    """A PDO mapping object: 0x1600..0x17FF (RxPDOs) or 0x1A00..0x1BFF (TxPDOs)."""
    return (
        coe.RXPDO_MAPPING <= index < coe.RXPDO_MAPPING + 0x200
        or coe.TXPDO_MAPPING <= index < coe.TXPDO_MAPPING + 0x200
    )


#: Objects 0x1D00..0x1DFF in a Virtual PDO name ESC registers (0x1D09:0x90 is 0x0990): they
#: live in the ESC's memory, not in the dictionary.
ESC_REGISTER_OBJECTS = range(0x1D00, 0x1E00)


def _process_entries(device: EsiDevice) -> list[tuple[Any, ...]]:
    """Dictionary entries for PDO entries the ESI's dictionary lacks (a device without CoE has
    no dictionary at all; vendors' dictionaries often leave objects out): the simulated slave
    needs a place to keep their values. Both the ESI's PDOs and the default contents of the
    dictionary's own mapping objects (which may name other objects) are looked at."""
    rows: list[tuple[Any, ...]] = []
    seen: set[tuple[int, int]] = set()

    def add(index: int, sub: int, name: str, code: int, bits: int) -> None:
        if index == 0 or index in ESC_REGISTER_OBJECTS or not 0 < bits <= MAX_ENTRY_BITS:
            return
        if (index, sub) in seen or device.od_entry(index, sub) is not None:
            return
        seen.add((index, sub))
        rows.append((index, sub, name, code, bits, "rw", True, None))

    pdos = [p for p in (*device.rx_pdos, *device.tx_pdos) if not p.virtual]
    for e in _pdo_entries(tuple(pdos)):
        add(e.index, e.subindex, e.name, e.data_type, e.bit_length)
    for obj in device.objects:
        if not is_mapping_object(obj.index):
            continue
        for entry in obj.entries:
            if entry.subindex == 0 or len(entry.default) != 4:
                continue
            value = int.from_bytes(entry.default, "little")
            index, sub, bits = value >> 16, (value >> 8) & 0xFF, value & 0xFF
            add(index, sub, f"{index:#06x}:{sub:02x}", _UNSIGNED_BY_BITS.get(bits, 0), bits)
    return rows


def _fill_empty_mappings(device: EsiDevice, rows: list[tuple[Any, ...]]) -> list[tuple[Any, ...]]:
    """Mapping objects as CoE defines them (ETG.1000.6: subindex 0 the count, then UNSIGNED32
    entries; an ESI that types them otherwise, as Elmo's DT1A00 with a UINT, is read so), and
    one the dictionary declares without default contents (Elmo's 0x1600 has no ``<Info>``)
    holding what the ESI's PDO of that index maps: that is the device's content (a ``Fixed``
    PDO is never written by a master). The same for an empty PDO assignment object."""
    out = [
        (*r[:3], dt.UINT32.code, 32, *r[5:7], bytes(r[7][:4]).ljust(4, b"\0"))
        if is_mapping_object(r[0]) and r[1] > 0 and r[4] != 32
        else r
        for r in rows
    ]
    by_key = {(r[0], r[1]): k for k, r in enumerate(out)}
    # Subindex 0 of a PDO assignment or mapping object is its count (ETG.1000.6); an ESI that
    # gives the largest subindex there instead (SOES's "Max SubIndex" 8 with two PDOs
    # assigned) counts only the entries before the first empty one (a PDO index or mapping
    # of 0 means nothing).
    for (index, sub), k in list(by_key.items()):
        assignment = SM_ASSIGN_BASE <= index < SM_ASSIGN_BASE + 0x20
        if sub != 0 or not (is_mapping_object(index) or assignment):
            continue
        count = out[k][7][0] if out[k][7] else 0
        used = 0
        while used < count:
            entry = by_key.get((index, used + 1))
            if entry is None or not any(out[entry][7]):
                break
            used += 1
        if used < count:
            out[k] = (*out[k][:7], bytes([used]))
    pdos = {p.index: p for p in (*device.rx_pdos, *device.tx_pdos) if not p.virtual}
    for index, pdo in pdos.items():
        count = by_key.get((index, 0))
        if count is None or any(out[count][7]) or not pdo.entries:
            continue
        found = [by_key.get((index, n)) for n in range(1, len(pdo.entries) + 1)]
        subs = [k for k in found if k is not None]
        if len(subs) != len(found):
            continue
        out[count] = (*out[count][:7], bytes([len(pdo.entries)]))
        for row, e in zip(subs, pdo.entries, strict=True):
            out[row] = (*out[row][:7], e.mapping_value.to_bytes(4, "little"))
    # Likewise an assignment object 0x1C10+n left empty (Elmo's 0x1C12 without <Info>), or
    # naming a PDO that neither the dictionary nor the ESI describes (EL3632's 0x1A73): the
    # device has the PDOs its ESI assigns to SM n by default.
    known = {p.index for p in (*device.rx_pdos, *device.tx_pdos)} | {
        r[0] for r in out if is_mapping_object(r[0])
    }
    for sm in device.sync_managers:
        index = SM_ASSIGN_BASE + sm.number
        count = by_key.get((index, 0))
        if count is None or not sm.is_process_data:
            continue
        n = out[count][7][0] if out[count][7] else 0
        assigned = [by_key.get((index, k)) for k in range(1, n + 1)]
        unknown = any(
            k is None or int.from_bytes(out[k][7][:2], "little") not in known for k in assigned
        )
        default = [p.index for p in (*device.default_rx(), *device.default_tx())
                   if not p.virtual and pdo_sync_manager(device, p) == sm.number]  # fmt: skip
        # A modular device (ETG.5001) assigns the PDOs of the modules in its slots itself: its
        # ESI's assignment object lists the head's PDOs only (and may have no room for more).
        values = {int.from_bytes(out[k][7][:2], "little") for k in assigned if k is not None}
        plugged = bool(device.slots) and not set(default) <= values
        if n and not unknown and not plugged:
            continue
        if plugged:
            out = _with_subindices(out, index, min(len(default), 254))
            by_key = {(r[0], r[1]): k for k, r in enumerate(out)}
            count = by_key[(index, 0)]
        found = [by_key.get((index, n)) for n in range(1, len(default) + 1)]
        subs = [k for k in found if k is not None]
        if not default or len(subs) != len(found):
            continue
        out[count] = (*out[count][:7], bytes([len(default)]))
        for row, pdo_index in zip(subs, default, strict=True):
            value = pdo_index.to_bytes(2, "little").ljust(len(out[row][7]), b"\0")
            out[row] = (*out[row][:7], value)
    return out


def _with_subindices(rows: list[tuple[Any, ...]], index: int, n: int) -> list[tuple[Any, ...]]:
    """``rows`` with object ``index`` holding subindices 1..n (new ones as its subindex 1, or
    UNSIGNED16 entries of a PDO assignment, zero), placed after the object's last row."""
    have = {r[1] for r in rows if r[0] == index}
    first = next((r for r in rows if r[0] == index and r[1] == 1), None)
    code, bits, access = (first[3], first[4], first[5]) if first else (dt.UINT16.code, 16, "ro")
    extra = [(index, sub, f"SubIndex {sub:03d}", code, bits, access, False, bytes(bits // 8))
             for sub in range(1, n + 1) if sub not in have]  # fmt: skip
    last = max(k for k, r in enumerate(rows) if r[0] == index)
    return [*rows[: last + 1], *extra, *rows[last + 1 :]]


def _supported_modes(device: EsiDevice, rows: list[tuple[Any, ...]]) -> list[tuple[Any, ...]]:
    """A drive fills in 0x6502 (supported drive modes) itself; an ESI that gives it 0 (a
    placeholder: IS620N, STMBL) leaves the simulated drive with the modes its dictionary
    offers, as the master reads them (``config.cia402.offered_modes``)."""
    out = list(rows)
    for k, r in enumerate(out):
        if SUPPORTED_MODES <= r[0] < SUPPORTED_MODES + MAX_AXES * AXIS_STRIDE and r[1] == 0:
            axis, rest = divmod(r[0] - SUPPORTED_MODES, AXIS_STRIDE)
            if rest or any(r[7] or b""):
                continue
            bits = sum(1 << MODES[m][1] for m in offered_modes(device, axis))
            out[k] = (*r[:7], bits.to_bytes(4, "little"))
    return out


#: The type a dictionary entry gets when only a mapping names it: unsigned of its length.
_UNSIGNED_BY_BITS = {
    1: dt.BOOL.code,
    8: dt.UINT8.code,
    16: dt.UINT16.code,
    32: dt.UINT32.code,
    64: dt.UINT64.code,
}


#: Largest entry the simulator's dictionary holds (a CoE entry's bit length is 16 bits).
MAX_ENTRY_BITS = 0xFFFF
#: Subindices a configurable mapping object offers (the ESI lists only the default entries).
CONFIGURABLE_MAPPING_ENTRIES = 32
#: PDO assignment of SyncManager n: 0x1C10 + n; SM communication types: 0x1C00.
SM_ASSIGN_BASE = coe.SM_PDO_ASSIGN
SM_TYPES = coe.SM_COMM_TYPE


def communication_objects(device: EsiDevice) -> list[tuple[Any, ...]]:
    """The CoE communication objects a slave carries but its ESI dictionary may lack, built
    from the ESI's SyncManagers and PDOs (ETG.1000.6): 0x1C00 (SM communication types), 0x1C10+n
    (PDO assignment of every process-data SM, the default PDOs assigned) and the mapping object
    of every PDO (0x16xx/0x1Axx, its entries). Objects the dictionary has are left alone. Rows
    as ``entries`` of the spec; only for a device with CoE (the others have no dictionary)."""
    mbx = device.mailbox
    if mbx is None or not mbx.coe:
        return []
    rows: list[tuple[Any, ...]] = []

    def missing(index: int) -> bool:
        return device.od_object(index) is None

    u8, u16, u32 = dt.UINT8.code, dt.UINT16.code, dt.UINT32.code
    if missing(SM_TYPES) and device.sync_managers:
        sms = device.sync_managers
        rows.append((SM_TYPES, 0, "SubIndex 000", u8, 8, "ro", False, bytes([len(sms)])))
        for sm in sms:
            kind = 0 if sm.virtual else SM_TYPE.get(sm.role, 0)
            rows.append((SM_TYPES, sm.number + 1, f"SubIndex {sm.number + 1:03d}", u8, 8, "ro",
                         False, bytes([kind])))  # fmt: skip
    for sm in device.sync_managers:
        index = SM_ASSIGN_BASE + sm.number
        if not sm.is_process_data or sm.virtual or not missing(index):
            continue
        direction = "rx" if sm.role == "Outputs" else "tx"
        candidates = [p for p in (device.rx_pdos if direction == "rx" else device.tx_pdos)
                      if not p.virtual]  # fmt: skip
        assigned = [p.index for p in candidates if p.sm is not None
                    and pdo_sync_manager(device, p) == sm.number]  # fmt: skip
        room = min(max(len(assigned), len(candidates), 1), 254)
        access = "rw" if mbx.pdo_assign else "ro"
        rows.append((index, 0, "SubIndex 000", u8, 8, access, False, bytes([len(assigned)])))
        for sub in range(1, room + 1):
            value = assigned[sub - 1] if sub <= len(assigned) else 0
            rows.append((index, sub, f"SubIndex {sub:03d}", u16, 16, access, False,
                         value.to_bytes(2, "little")))  # fmt: skip
    seen: set[int] = set()
    for pdo in (*device.rx_pdos, *device.tx_pdos):
        if pdo.virtual or pdo.index in seen or not missing(pdo.index):
            continue
        seen.add(pdo.index)
        configurable = mbx.pdo_config and not pdo.fixed
        access = "rw" if configurable else "ro"
        room = len(pdo.entries)
        if configurable:
            room = max(room, CONFIGURABLE_MAPPING_ENTRIES)
        room = min(room, 254)
        rows.append((pdo.index, 0, "SubIndex 000", u8, 8, access, False,
                     bytes([len(pdo.entries)])))  # fmt: skip
        for sub in range(1, room + 1):
            value = pdo.entries[sub - 1].mapping_value if sub <= len(pdo.entries) else 0
            rows.append((pdo.index, sub, f"SubIndex {sub:03d}", u32, 32, access, False,
                         value.to_bytes(4, "little")))  # fmt: skip
    return rows


#: One-way delay of a link into a slave's port 0 when the config gives none, by the port's
#: physics (ESI ``Physics``): an E-bus hop (the upstream ESC's forwarding and a few cm of
#: backplane) and a 100BASE-TX hop (two PHYs, the forwarding and a few metres of cable), in
#: the ESC's 10 ns steps. Measured delays of real Beckhoff lines are of this order.
DELAY_EBUS_NS = 150
DELAY_MII_NS = 700


def default_delay_ns(device: EsiDevice) -> int:
    """The link delay into a slave's port 0 from its physics (``K`` E-bus, else MII)."""
    return DELAY_EBUS_NS if device.physics[:1] == "K" else DELAY_MII_NS


def _dictionary(
    device: EsiDevice, sim_device: str
) -> tuple[list[tuple[Any, ...]], list[tuple[Any, ...]]]:
    """The CoE objects and entries (with their ESI defaults) a slave running ``device`` with
    the ``sim_device`` model starts with: the same for every such slave, so built once
    (``_DICTIONARIES``; a thousand-slave bus has three devices). The serial number is each
    slave's own and is put in by ``device_spec``."""
    key = (id(device), sim_device)
    cached = _DICTIONARIES.get(key)
    if cached is not None and cached[0] is device:
        return cached[1], cached[2]
    objects = [(o.index, o.name, o.object_code) for o in device.objects]
    entries = [
        (
            e.index,
            e.subindex,
            e.name,
            e.data_type,
            e.bit_length,
            e.access,
            e.pdo_mappable,
            bytes(e.default),
        )
        for o in device.objects
        for e in o.entries
    ]
    entries = [e for e in entries if e[4] <= MAX_ENTRY_BITS]
    entries = _fill_empty_mappings(device, entries)
    if sim_device == "cia402":
        entries = _supported_modes(device, entries)
    entries += _process_entries(device)
    entries += communication_objects(device)
    known = {o[0] for o in objects}
    names = {SM_TYPES: ("Sync manager type", 8)}
    for r in entries:
        if r[0] in known or r[0] in names:
            continue
        if SM_ASSIGN_BASE <= r[0] < SM_ASSIGN_BASE + 32:
            names[r[0]] = (f"SM{r[0] - SM_ASSIGN_BASE} PDO assignment", 8)
        elif is_mapping_object(r[0]):
            names[r[0]] = (f"PDO mapping {r[0]:#06x}", 9)
        else:
            names[r[0]] = (f"Process data {r[0]:#06x}", 7)
    objects += sorted(
        (index, name, code)
        for index, (name, code) in names.items()
        if any(r[0] == index for r in entries) and index not in known
    )
    _DICTIONARIES[key] = (device, objects, entries)
    return objects, entries


# (id(device), sim_device) -> (device, objects, entries); the device is kept so its id stays
# its own.
_DICTIONARIES: dict[
    tuple[int, str], tuple[EsiDevice, list[tuple[Any, ...]], list[tuple[Any, ...]]]
] = {}


def idn_rows(device: EsiDevice) -> list[tuple[Any, ...]]:
    """The ``idns`` of the spec of a drive with SoE: its IDN dictionary (``EsiDevice.idns``)
    as rows ``(idn, name, data_type, bit_length, default)``, and every IDN its PDOs map that
    the dictionary lacks (most AX5000 ESIs name a dictionary file that is not at hand), typed
    as the PDO entry. The simulator derives each IDN's attribute from type and length and adds
    the configuration lists S-0-0016/S-0-0024 from the PDOs. A device without SoE has none."""
    if device.mailbox is None or not device.mailbox.soe:
        return []
    cached = _IDNS.get(id(device))
    if cached is not None and cached[0] is device:
        return cached[1]
    rows: list[tuple[Any, ...]] = []
    for obj in device.idns:
        rows.append(_idn_row(obj))
    known = {o.index for o in device.idns}
    pdos = tuple(p for p in (*device.rx_pdos, *device.tx_pdos) if not p.virtual)
    for e in _pdo_entries(pdos):
        if e.index not in known:
            known.add(e.index)
            rows.append((e.index, e.name, e.data_type, e.bit_length, None))
    _IDNS[id(device)] = (device, rows)
    return rows


def _idn_row(obj: OdObject) -> tuple[Any, ...]:
    """One IDN of a Sercos dictionary: a VAR is its one entry; an ARRAY is a Sercos list
    (subindex 0 the current length, 1 the maximum length in bytes, then the items), its value
    the whole list element, the maximum at least what the object's size holds (Beckhoff's
    dictionaries give 0 there); a RECORD (bit fields, structures) is operation data of the
    object's size, zero (its members' bit offsets are not kept)."""
    entries = sorted(obj.entries, key=lambda e: e.subindex)
    if obj.object_code == coe.OBJECT_VAR and entries:
        e = entries[0]
        return (obj.index, obj.name, e.data_type, e.bit_length, bytes(e.default))
    if obj.object_code == coe.OBJECT_ARRAY and len(entries) >= 2:
        items = b"".join(bytes(e.default).ljust((e.bit_length + 7) // 8, b"\0")
                         for e in entries[2:])  # fmt: skip
        current = int.from_bytes(bytes(entries[0].default)[:2], "little")
        maximum = int.from_bytes(bytes(entries[1].default)[:2], "little")
        room = max(maximum, obj.bit_size // 8 - soe.LIST_HEADER_LEN, current)
        value = current.to_bytes(2, "little") + room.to_bytes(2, "little") + items[:current]
        return (obj.index, obj.name, 0, obj.bit_size, value)
    return (obj.index, obj.name, 0, obj.bit_size, None)


# id(device) -> (device, rows), as _DICTIONARIES.
_IDNS: dict[int, tuple[EsiDevice, list[tuple[Any, ...]]]] = {}

# The identity object's serial number (0x1018:4): the ESI can't know it, each slave has its own.
_SERIAL_ENTRY = (coe.IDENTITY, 4)


def device_spec(
    device: EsiDevice,
    *,
    name: str,
    sim_device: str | None = None,
    params: dict[str, float] | None = None,
    alias: int = 0,
    serial: int = 0,
    drift_ppm: float | None = None,
    delay_ns: int | None = None,
    esc: str | None = None,
    lrw: bool | None = None,
    upstream: tuple[int, int] | None = None,
    foe: FoeSpec | None = None,
) -> SlaveSpec:
    """The ``add_slave`` spec of one slave running ``device``. ``sim_device``, ``drift_ppm``,
    ``esc`` and ``lrw`` None: ``SlaveSpec``'s defaults (no firmware model, no drift, an
    ET1100, LRW supported); ``delay_ns`` None: the device's physics (``default_delay_ns``);
    ``upstream`` None: port 1 of the slave before it. ``alias`` and ``serial`` go into the SII
    image too, so they are given here. ``foe``: the FoE store (``foe_spec``; None: an empty
    one)."""
    objects, entries = _dictionary(device, sim_device or "none")
    entries = [
        (*e[:7], _default(e[7], serial, e[4])) if (e[0], e[1]) == _SERIAL_ENTRY else e
        for e in entries
    ]
    return SlaveSpec(
        name=name,
        vendor_id=device.vendor_id,
        product_code=device.product_code,
        revision=device.revision,
        serial=serial,
        alias=alias,
        sii=build_sii(device, alias=alias, serial=serial),
        objects=list(objects),
        entries=entries,
        idns=idn_rows(device),
        device=sim_device,
        params={k: float(v) for k, v in (params or {}).items()},
        drift_ppm=drift_ppm,
        delay_ns=int(default_delay_ns(device) if delay_ns is None else delay_ns),
        upstream=upstream,
        dc_supported=device.dc_supported,
        dc_required=device.sync0_required,
        mailbox=mailbox_spec(device),
        esc=esc,
        lrw=lrw,
        loopback_links=loopback_pairs(device) if sim_device == "loopback" else [],
        safeop_op_timeout_ms=device.timeouts.safeop_op_ms,
        foe=foe,
    )


def _default(esi_default: bytes, override: int | None, bit_length: int) -> bytes:
    if override is None:
        return bytes(esi_default)
    nbytes = (bit_length + 7) // 8
    return (override & ((1 << (8 * nbytes)) - 1)).to_bytes(nbytes, "little")


def slave_spec(
    slave: SlaveConfig,
    position: int,
    upstream: tuple[int, int] | None = None,
    base: Path | None = None,
) -> SlaveSpec:
    """The spec of a configured slave at ``position`` on the simulated bus; ``upstream``:
    (parent position, port) where its port 0 is connected (None: the slave before it);
    ``base``: the directory the paths of its FoE files are relative to."""
    serial = slave.sim.serial if slave.sim.serial is not None else SERIAL_BASE + position
    return device_spec(
        slave.esi,
        name=slave.name,
        sim_device=slave.sim_device,
        params=slave.sim.params,
        alias=slave.alias or 0,
        serial=serial,
        drift_ppm=slave.sim.drift_ppm,
        delay_ns=slave.sim.delay_ns,
        esc=slave.sim.esc,
        lrw=slave.sim.lrw,
        upstream=upstream,
        foe=foe_spec(slave.sim.foe, slave.esi, slave=slave.name, base=base),
    )


def bus_order(cfg: BusConfig) -> list[SlaveConfig]:
    """The slaves in the order they sit on the wire: by position; slaves addressed by alias
    only keep their place in the list relative to the others."""
    if all(s.position is not None for s in cfg.slaves):
        ordered = sorted(cfg.slaves, key=lambda s: s.position or 0)
        positions = [s.position for s in ordered]
        if positions != list(range(len(ordered))):
            raise ConfigError(
                f"{cfg.source}: the simulator needs slave positions 0..{len(ordered) - 1} without"
                f" gaps, got {positions}"
            )
        return ordered
    return list(cfg.slaves)


def network_specs(cfg: BusConfig) -> list[SlaveSpec]:
    """Specs for every slave of ``cfg`` in bus order, each connected where ``connected_to``
    says (default: port 1 of the slave before it)."""
    slaves = bus_order(cfg)
    base = cfg.source.parent if cfg.source is not None else None
    if not cfg.declares_topology:
        return [slave_spec(s, i, base=base) for i, s in enumerate(slaves)]
    links = cfg.tree()
    return [
        slave_spec(s, i, (link.parent, link.port) if link.parent is not None else None, base)
        for i, (s, link) in enumerate(zip(slaves, links, strict=True))
    ]
