"""Look into a bus without running it, like IgH's ``ethercat`` tool: states, registers, SII,
PDOs, the object dictionary, SDO upload/download, an ESI from the SII, the topology.

An :class:`Inspector` owns an engine on an interface (or an in-process simulator) and an
acyclic worker over it (``master/worker.py``); it scans without resetting the slaves (station
addresses 0x1001 + position, as a running ether_ros master uses too). Only commands that need
the mailbox change anything, and they do it through the slave's state machine in its inspection
mode (``master/slave_fsm.py``: ``inspect``), the one bring-up of the master: a slave in INIT (or
with an AL error) gets its mailbox SyncManagers and goes to PREOP, as the IgH master does before
any SDO access; a slave already in PREOP or above keeps its state.
"""

from __future__ import annotations

import re
import statistics
import struct
import time
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from ether_ros._native.protocol import coe as coe_facts
from ether_ros._native.protocol import (
    esi_type_name,
    format_address,
    parse_address,
    parse_index,
    reg,
)
from ether_ros.claim import InterfaceClaim, OwnerClient, describe_owner, hex_bytes
from ether_ros.config import types as dt
from ether_ros.config.esi import EsiDevice
from ether_ros.config.sii import SiiInfo, parse_sii
from ether_ros.errors import BusError, EtherRosError, LinkError, MailboxTimeout
from ether_ros.master import slave_fsm
from ether_ros.master.al import AlState, AlStateMachine, AlStatus, SlaveRef, al_code_text
from ether_ros.master.link import open_engine
from ether_ros.master.scan import FoundSlave, bus_tree, scan
from ether_ros.master.slave import Slave
from ether_ros.master.worker import AcyclicWorker


class InspectError(EtherRosError):
    """An inspection request names something that is not there or does not fit."""


ESC_REGISTER_SPACE = reg.PDRAM  # registers; process data RAM follows up to 0xFFFF
STATE_NAMES = {s.name: s for s in AlState}


@dataclass(frozen=True)
class ObjectRef:
    index: int
    subindex: int
    name: str = ""
    dtype: dt.DataType | None = None
    bit_length: int = 0


def parse_int(text: str, what: str) -> int:
    try:
        return int(text.replace("_", ""), 0)
    except ValueError:
        raise InspectError(f"{what}: {text!r} is not a number (decimal or 0x hex)") from None


def parse_register(text: str) -> int:
    """An ESC register address (``0x0130``, ``0130``, ``130``): hexadecimal with or without
    ``0x``, the one rule for a bare index (``protocol.parse_index``): ``130`` is 0x0130."""
    try:
        return parse_index(text)
    except ValueError as exc:
        raise InspectError(f"register address: {exc}") from None


def parse_value(text: str, dtype: dt.DataType) -> object:
    """User text → a value of ``dtype`` (checked by the encoder afterwards)."""
    raw = text.strip()
    if dtype.kind == "bool":
        lowered = raw.lower()
        if lowered in ("true", "on", "yes", "1"):
            return True
        if lowered in ("false", "off", "no", "0"):
            return False
        raise InspectError(f"{dtype.name} needs true/false or 1/0, got {text!r}")
    if dtype.kind in ("int", "uint"):
        return parse_int(raw, f"{dtype.name} value")
    if dtype.kind == "real":
        try:
            return float(raw)
        except ValueError:
            raise InspectError(f"{dtype.name} needs a number, got {text!r}") from None
    if dtype.kind == "bytes":
        try:
            return bytes.fromhex(raw.removeprefix("0x"))
        except ValueError:
            raise InspectError(f"{dtype.name} needs hex bytes, got {text!r}") from None
    return raw


def data_type(name: str) -> dt.DataType:
    t = dt.config_type(name)
    if t is None:
        raise InspectError(
            f"unknown data type {name!r} (uint8, int16, uint32, real32, bool, "
            "string, ... or an ESI name such as UINT)"
        )
    return t


class Inspector:
    """A bus opened for inspection: scanned, addressed, not configured, not cyclic."""

    def __init__(
        self,
        engine: Any,
        devices: Sequence[EsiDevice] = (),
        names: dict[int, str] | None = None,
        interface: str = "",
    ) -> None:
        self.engine = engine
        self.interface = interface
        self.worker = AcyclicWorker(engine)
        self.dg = self.worker.service()
        self.al = AlStateMachine(self.dg)
        self.devices = list(devices)
        self.found: list[FoundSlave] = scan(self.dg, reset=False)
        self.names = names or {}
        # Slaves taken to PREOP by their state machine, by position (their mailbox set up).
        self._inspected: dict[int, Slave] = {}
        self.claim: InterfaceClaim | None = None

    @classmethod
    def open(
        cls,
        interface: str | None = None,
        link: Any = None,
        config: str | None = None,
        esi: Sequence[str] = (),
        link_kind: str | None = None,
    ) -> Inspector:
        from ether_ros import _native
        from ether_ros.config import load_bus_config
        from ether_ros.config.esi import load_esi_paths

        devices: list[EsiDevice] = []
        names: dict[int, str] = {}
        cfg = None
        if config:
            cfg = load_bus_config(config)
            devices.extend(cfg.esi_devices)
            interface = interface or cfg.bus.interface
        if esi:
            devices.extend(load_esi_paths(esi))
        claim = None
        if link is not None:
            engine = _native.Engine.open_sim(link)
        else:
            if not interface:
                raise LinkError(
                    "no network interface: give --interface (or --config with bus.interface)"
                )
            running = OwnerClient.find(interface, "master")
            if running is not None:
                # A master runs on it: ask that master, never open the interface beside it.
                remote = RemoteInspector(running, devices, names, interface)
                if cfg is not None:
                    remote.names = _configured_names(remote.found, cfg)
                return remote
            # Inspecting, this process is the interface's master: no other may start meanwhile.
            claim = InterfaceClaim.take(interface, "master")
            kind = link_kind or (cfg.bus.link if cfg is not None else "packet")
            try:
                engine = open_engine(
                    interface, kind, cfg.bus.busy_poll_us if cfg is not None else 0
                )
            except BaseException:
                claim.release()
                raise
        try:
            inspector = cls(engine, devices, names, interface or "in-process")
            inspector.claim = claim
            if cfg is not None:
                inspector.names = _configured_names(inspector.found, cfg)
        except BaseException:
            engine.close()
            if claim is not None:
                claim.release()
            raise
        return inspector

    def close(self) -> None:
        self.engine.close()
        if self.claim is not None:
            self.claim.release()

    def __enter__(self) -> Inspector:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    # ---- slaves ---------------------------------------------------------------------------

    def name_of(self, f: FoundSlave) -> str:
        return self.names.get(f.position) or f.name or f"slave{f.position}"

    def slave(self, which: str | int) -> FoundSlave:
        """A slave by position (``2``), alias (``#7``) or configured name."""
        text = str(which).strip()
        if text.startswith("#"):
            alias = parse_int(text[1:], "alias")
            hits = [f for f in self.found if f.alias == alias]
        elif re.fullmatch(r"\d+", text):
            hits = [f for f in self.found if f.position == int(text)]
        else:
            hits = [f for f in self.found if self.names.get(f.position) == text]
        if len(hits) != 1:
            known = ", ".join(f"{f.position} ({self.name_of(f)})" for f in self.found) or "none"
            raise InspectError(f"no slave {text!r} on the bus (slaves: {known})")
        return hits[0]

    def selected(self, which: str | int | None) -> list[FoundSlave]:
        return list(self.found) if which is None else [self.slave(which)]

    def ref(self, f: FoundSlave) -> SlaveRef:
        return SlaveRef(f.position, f.station, self.name_of(f))

    def device(self, f: FoundSlave) -> EsiDevice | None:
        """The ESI device with this slave's identity (exact revision preferred)."""
        candidates = [
            d
            for d in self.devices
            if d.vendor_id == f.vendor_id and d.product_code == f.product_code
        ]
        exact = [d for d in candidates if d.revision == f.revision]
        matches = exact or candidates
        return matches[0] if matches else None

    # ---- AL states ------------------------------------------------------------------------

    def states(self, which: str | int | None = None) -> list[dict[str, Any]]:
        slaves = self.selected(which)
        statuses = self.al.read([self.ref(f) for f in slaves])
        return [
            _state_entry(self.name_of(f), f, st) for f, st in zip(slaves, statuses, strict=True)
        ]

    def request_state(self, state: str, which: str | int | None = None) -> list[dict[str, Any]]:
        target = STATE_NAMES.get(state.upper().replace("-", ""))
        if target is None:
            raise InspectError(f"unknown state {state!r} (INIT, PREOP, BOOT, SAFEOP, OP)")
        slaves = self.selected(which)
        if target in (AlState.SAFEOP, AlState.OP):
            # Without PDO, SyncManager and FMMU setup a slave refuses SAFEOP; say how instead
            # of letting it fail with an AL code the user cannot act on.
            raise InspectError(
                f"{target.name} needs the process data configured: use "
                "`ether-ros run` or the Bus API for that; `states` goes to INIT, "
                "PREOP or BOOT"
            )
        if target == AlState.PREOP:
            # INIT (or an AL error) → PREOP through each slave's state machine; a slave in
            # SAFEOP or OP is then asked down to PREOP like the others.
            self._to_preop(slaves)
        self.al.transition([self.ref(f) for f in slaves], target)
        if target != AlState.PREOP:
            self._inspected.clear()  # a slave back in INIT has its mailbox set up anew
        return self.states(which)

    # ---- registers ------------------------------------------------------------------------

    def reg_read(self, which: str | int, address: int, length: int) -> bytes:
        f = self.slave(which)
        _check_register(address, length)
        data, wkc = self.dg.fprd(f.station, address, length)
        if wkc != 1:
            raise BusError(f"slave {f.position}: no answer reading 0x{address:04X}")
        return bytes(data)

    def reg_write(self, which: str | int, address: int, data: bytes) -> None:
        f = self.slave(which)
        _check_register(address, len(data))
        if self.dg.fpwr(f.station, address, data) != 1:
            raise BusError(f"slave {f.position}: write to 0x{address:04X} not acknowledged")

    # ---- SII ------------------------------------------------------------------------------

    def sii(self, which: str | int) -> tuple[bytes, SiiInfo]:
        f = self.slave(which)
        return f.sii, f.header

    # ---- mailbox / CoE --------------------------------------------------------------------

    def _to_preop(self, slaves: Sequence[FoundSlave]) -> list[Slave]:
        """``slaves`` to PREOP with their mailboxes set up, through their state machines
        (``slave_fsm.inspect``, in parallel): the one bring-up of the master."""
        out = [
            self._inspected.get(f.position)
            or Slave.unconfigured(f, self.device(f), self.name_of(f))
            for f in slaves
        ]
        todo = [s for s in out if s.position not in self._inspected]
        slave_fsm.inspect(self.worker, todo)
        for s in todo:
            self._inspected[s.position] = s
        return out

    def sdo_client(self, which: str | int) -> Any:
        """The slave's SDO client; a slave in INIT is taken to PREOP first."""
        f = self.slave(which)
        known = self._inspected.get(f.position)
        if known is not None and known.sdo is not None:
            return known.sdo
        device = self.device(f)
        if not f.header.has_coe and not (device is not None and device.mailbox is not None):
            raise InspectError(f"{self.ref(f)}: has no CoE mailbox")
        (s,) = self._to_preop([f])
        if s.sdo is None:
            what = "no mailbox" if s.mailbox is None else "no CoE mailbox"
            raise InspectError(f"{self.ref(f)}: has {what}")
        with self.worker.mailbox(s.station).lock:
            _sync_mailbox_counter(s.sdo_client)
        return s.sdo

    def resolve_object(
        self, which: str | int, spec: str, type_name: str | None = None
    ) -> ObjectRef:
        """An object address (``0x7030:03``, ``7030:3``, ``0x1600:0a``: both parts hexadecimal,
        the one grammar of ``ether_ros._native.protocol.parse_address``) or a name from the ESI
        dictionary (``a_ellipse100`` or ``TrajectoryParameters.a_ellipse100``)."""
        f = self.slave(which)
        device = self.device(f)
        forced = data_type(type_name) if type_name else None
        try:
            address = parse_address(spec)
        except ValueError as exc:
            raise InspectError(f"object {exc}") from None
        if address is not None:
            index, sub = address
            entry = device.od_entry(index, sub) if device else None
            if entry is None and forced is None:
                return self._describe_on_slave(f, index, sub)
            return _object_ref(index, sub, entry, forced)
        if device is None:
            raise InspectError(
                f"{spec!r} is not index:subindex and there is no ESI for "
                f"{self.ref(f)} to look names up in (give --config or --esi)"
            )
        obj_name, _, entry_name = spec.rpartition(".")
        hits = []
        for obj in device.objects:
            for e in obj.entries:
                if e.name == entry_name and (not obj_name or obj.name == obj_name):
                    hits.append(e)
        if not hits:
            raise InspectError(f"no object {spec!r} in the dictionary of {self.ref(f)}")
        if len(hits) > 1:
            where = ", ".join(format_address(e.index, e.subindex) for e in hits)
            raise InspectError(f"{spec!r} is ambiguous ({where}); use index:subindex")
        e = hits[0]
        return _object_ref(e.index, e.subindex, e, forced)

    def _describe_on_slave(self, f: FoundSlave, index: int, sub: int) -> ObjectRef:
        """Name and type of an object without an ESI: from the SII's PDO entries, else from
        the slave's SDO information service; untyped when neither knows it."""
        e = self._sii_entry(f, index, sub)
        if e is not None and e.data_type in dt.BY_CODE:
            return ObjectRef(index, sub, e.name, dt.BY_CODE[e.data_type], e.bit_length)
        if f.header.general and f.header.general.coe_details & 0x02:
            try:
                d = self.sdo_client(f.position).entry_description(index, sub)
            except EtherRosError:
                return ObjectRef(index, sub)
            return ObjectRef(index, sub, d.name, dt.BY_CODE.get(d.data_type), d.bit_length)
        return ObjectRef(index, sub)

    @staticmethod
    def _sii_entry(f: FoundSlave, index: int, sub: int) -> Any:
        for pdo in (*f.header.rx_pdos, *f.header.tx_pdos):
            for e in pdo.entries:
                if (e.index, e.subindex) == (index, sub):
                    return e
        return None

    def upload(
        self, which: str | int, spec: str, type_name: str | None = None
    ) -> tuple[ObjectRef, bytes, object]:
        ref = self.resolve_object(which, spec, type_name)
        data: bytes = self.sdo_client(which).upload(ref.index, ref.subindex)
        value: object = data
        if ref.dtype is not None:
            bits = ref.bit_length or 8 * len(data)
            if ref.dtype.kind in ("string", "bytes"):
                bits = 8 * len(data)
            value = dt.decode_value(ref.dtype, data[: (bits + 7) // 8], bits)
        return ref, data, value

    def download(
        self, which: str | int, spec: str, text: str, type_name: str | None = None
    ) -> tuple[ObjectRef, bytes]:
        ref = self.resolve_object(which, spec, type_name)
        if ref.dtype is None:
            raise InspectError(
                f"the type of {format_address(ref.index, ref.subindex)} is unknown "
                "(not in the ESI dictionary): give --type"
            )
        value = parse_value(text, ref.dtype)
        bits = ref.bit_length
        if ref.dtype.kind in ("string", "bytes") or not bits:
            bits = 8 * len(value if isinstance(value, bytes) else str(value).encode())
        try:
            data = dt.encode_value(ref.dtype, value, bits)
        except ValueError as exc:
            raise InspectError(
                f"{format_address(ref.index, ref.subindex)} ({ref.name or ref.dtype.name}): {exc}"
            ) from None
        self.sdo_client(which).download(ref.index, ref.subindex, data)
        return ref, data

    def dictionary(self, which: str | int) -> tuple[str, list[dict[str, Any]]]:
        """The object dictionary: by SDO information when the slave offers it, else the ESI.

        Returns (source, objects) with source ``"sdo-info"`` or ``"esi"``."""
        f = self.slave(which)
        info_supported = bool(f.header.general and f.header.general.coe_details & 0x02)
        if info_supported:
            try:
                return "sdo-info", self._dictionary_by_sdo_info(which)
            except EtherRosError:
                if self.device(f) is None:
                    raise
        device = self.device(f)
        if device is None:
            raise InspectError(
                f"{self.ref(f)}: no SDO information service and no ESI (give --config or --esi)"
            )
        objects = []
        for obj in device.objects:
            objects.append(
                {
                    "index": obj.index,
                    "name": obj.name,
                    "object_code": {7: "VAR", 8: "ARRAY", 9: "RECORD"}.get(obj.object_code, "?"),
                    "entries": [
                        {
                            "subindex": e.subindex,
                            "name": e.name,
                            "type": esi_type_name(e.data_type) or e.type_name,
                            "bit_length": e.bit_length,
                            "access": e.access,
                            "pdo_mapping": e.pdo_mapping,
                        }
                        for e in obj.entries
                    ],
                }
            )
        return "esi", objects

    def _dictionary_by_sdo_info(self, which: str | int) -> list[dict[str, Any]]:
        client = self.sdo_client(which)
        objects = []
        for index in client.object_list():
            desc = client.object_description(index)
            entries = []
            for sub in range(desc.max_subindex + 1):
                try:
                    e = client.entry_description(index, sub)
                except EtherRosError:
                    continue  # a gap in a record
                mapping = ("R" if e.rx_mappable else "") + ("T" if e.tx_mappable else "")
                entries.append(
                    {
                        "subindex": sub,
                        "name": e.name,
                        "type": esi_type_name(e.data_type) or f"0x{e.data_type:04X}",
                        "bit_length": e.bit_length,
                        "access": e.access_text,
                        "pdo_mapping": mapping,
                    }
                )
            objects.append(
                {
                    "index": index,
                    "name": desc.name,
                    "object_code": desc.object_code_name,
                    "entries": entries,
                }
            )
        return objects

    # ---- PDOs -----------------------------------------------------------------------------

    def pdos(self, which: str | int) -> dict[str, Any]:
        """SyncManagers and PDOs: the assignment read over CoE (0x1C12/0x1C13 and the mapping
        objects) when the slave has CoE, else what its SII lists."""
        f = self.slave(which)
        h = f.header
        sms = [
            {
                "index": i,
                "start": sm.start,
                "length": sm.length,
                "control": sm.control,
                "enable": sm.enable,
                "role": sm.role,
            }
            for i, sm in enumerate(h.sync_managers)
        ]
        source = "sii"
        rx = [_sii_pdo(p) for p in h.rx_pdos]
        tx = [_sii_pdo(p) for p in h.tx_pdos]
        if h.has_coe:
            try:
                rx = self._pdos_by_coe(which, coe_facts.RXPDO_ASSIGN)
                tx = self._pdos_by_coe(which, coe_facts.TXPDO_ASSIGN)
                source = "coe"
            except EtherRosError:
                source = "sii"  # the slave does not expose its assignment: the SII is all
        return {
            "position": f.position,
            "name": self.name_of(f),
            "source": source,
            "sync_managers": sms,
            "rx_pdos": rx,
            "tx_pdos": tx,
        }

    def _pdos_by_coe(self, which: str | int, assign_index: int) -> list[dict[str, Any]]:
        client = self.sdo_client(which)
        f = self.slave(which)
        device = self.device(f)
        count = client.upload(assign_index, 0)[0]
        pdos = []
        for i in range(1, count + 1):
            pdo_index = struct.unpack("<H", client.upload(assign_index, i)[:2])[0]
            n = client.upload(pdo_index, 0)[0]
            entries = []
            for k in range(1, n + 1):
                (value,) = struct.unpack("<I", client.upload(pdo_index, k)[:4])
                index, sub, bits = value >> 16, (value >> 8) & 0xFF, value & 0xFF
                od = device.od_entry(index, sub) if device and index else None
                if od is None and index:
                    od = self._sii_entry(f, index, sub)
                entries.append(
                    {
                        "index": index,
                        "subindex": sub,
                        "bit_length": bits,
                        "name": od.name if od else ("(gap)" if index == 0 else ""),
                        "type": (esi_type_name(od.data_type) or "") if od else "",
                    }
                )
            pdo_desc = device.pdo(pdo_index) if device else None
            sii_pdos = [p for p in (*f.header.rx_pdos, *f.header.tx_pdos) if p.index == pdo_index]
            pdo_name = pdo_desc.name if pdo_desc else (sii_pdos[0].name if sii_pdos else "")
            pdos.append({"index": pdo_index, "name": pdo_name, "entries": entries})
        return pdos

    # ---- topology and link ----------------------------------------------------------------

    def topology(self) -> list[dict[str, Any]]:
        """Each slave with its open ports (DL status 0x0110, read by the scan), the slave it
        hangs on (``parent``, None: the master) and that slave's ``port``: the tree the frame
        walks depth first in port order 0, 3, 1, 2."""
        tree = bus_tree(self.found)
        return [
            {
                "position": f.position,
                "name": self.name_of(f),
                "open_ports": [p for p in range(4) if f.open_ports >> p & 1],
                "parent": link.parent,
                "port": link.port,
            }
            for f, link in zip(self.found, tree, strict=True)
        ]

    def graph_dot(self) -> str:
        """The tree as a Graphviz DOT graph; each edge between slaves is labelled with the
        parent's port it leaves from (every slave is entered on its port 0)."""
        nodes = self.topology()
        lines = [
            "digraph ethercat {",
            "  rankdir=LR;",
            "  node [shape=box];",
            f'  master [label="master\\n{self.interface}", shape=ellipse];',
        ]
        for n in nodes:
            f = self.found[n["position"]]
            lines.append(
                f'  slave{n["position"]} [label="{n["position"]}: {n["name"]}\\n'
                f'0x{f.vendor_id:08X}:0x{f.product_code:08X}"];'
            )
        for n in nodes:
            if n["parent"] is None:
                lines.append(f"  master -> slave{n['position']};")
            else:
                lines.append(
                    f'  slave{n["parent"]} -> slave{n["position"]} [label="port {n["port"]}"];'
                )
        lines.append("}")
        return "\n".join(lines) + "\n"

    def link_statistics(self, probes: int = 100) -> dict[str, Any]:
        """Interface counters, the engine's counters and a round-trip measurement with
        ``probes`` broadcast reads (each one frame)."""
        rtts = []
        for _ in range(probes):
            t0 = time.perf_counter_ns()
            self.dg.brd(reg.TYPE, 2)
            rtts.append((time.perf_counter_ns() - t0) / 1000.0)
        sys_stats = _interface_counters(self.interface)
        engine_stats = {}
        get = getattr(self.engine, "stats", None)
        if get is not None:
            try:
                engine_stats = dict(get())
            except EtherRosError:
                engine_stats = {}
        return {
            "interface": self.interface,
            "slaves": len(self.found),
            "round_trip_us": {
                "probes": probes,
                "min": min(rtts),
                "median": statistics.median(rtts),
                "max": max(rtts),
            },
            "interface_stats": sys_stats,
            "engine": engine_stats,
        }


def _configured_names(found: Sequence[FoundSlave], cfg: Any) -> dict[int, str]:
    """Position → configured name, the found slaves matched against the configuration."""
    from ether_ros.master.scan import match_configuration
    from ether_ros.master.setup import expected_of as _expected

    expected = [_expected(s, i) for i, s in enumerate(cfg.slaves)]
    positions = match_configuration(found, expected)
    return {p: e.name for p, e in zip(positions, expected, strict=True)}


class RemoteInspector(Inspector):
    """Inspection beside a running master: every request goes to that master (``ether_ros
    .claim``, ``master/service.py``), which carries it out on its own acyclic path and its own
    mailbox clients; nothing here touches the wire. What would disturb the running bus — a
    state change, a register write, an SDO download while its control lease refuses it — is
    refused with the reason."""

    def __init__(
        self,
        client: OwnerClient,
        devices: Sequence[EsiDevice] = (),
        names: dict[int, str] | None = None,
        interface: str = "",
    ) -> None:
        self.client = client
        self.engine = None
        self.interface = interface
        self.devices = list(devices)
        self._inspected = {}
        self.claim = None
        self.found = []
        running: dict[int, str] = {}
        for entry in client.request("found"):
            image = bytes.fromhex(entry["sii"])
            self.found.append(
                FoundSlave(
                    position=entry["position"],
                    station=entry["station"],
                    alias=entry["alias"],
                    esc_type=entry["esc_type"],
                    esc_features=entry["esc_features"],
                    sii=image,
                    header=parse_sii(image),
                    dl_status=entry["dl_status"],
                )
            )
            running[entry["position"]] = entry["name"]
        # The running master's names unless the user gave a configuration of their own.
        self.names = names or running

    @property
    def owner(self) -> str:
        return describe_owner(self.client.owner)

    def close(self) -> None:
        self.client.close()

    def states(self, which: str | int | None = None) -> list[dict[str, Any]]:
        wanted = {f.position for f in self.selected(which)}
        out = []
        for st in self.client.request("states"):
            if st["position"] not in wanted:
                continue
            f = self.slave(st["position"])
            out.append(
                {
                    "position": f.position,
                    "name": self.name_of(f),
                    "state": st["state"],
                    "error": bool(st["error"]),
                    "al_status_code": st["code"],
                    "al_status_text": st["text"],
                }
            )
        return out

    def request_state(self, state: str, which: str | int | None = None) -> list[dict[str, Any]]:
        raise InspectError(
            f"{self.interface} is driven by a running master ({self.owner}): its slaves' states "
            "are that master's to change (stop it first, or use its node's services)"
        )

    def reg_read(self, which: str | int, address: int, length: int) -> bytes:
        f = self.slave(which)
        _check_register(address, length)
        return hex_bytes(
            self.client.request("reg_read", position=f.position, address=address, length=length)
        )

    def reg_write(self, which: str | int, address: int, data: bytes) -> None:
        raise InspectError(
            f"{self.interface} is driven by a running master ({self.owner}): register writes "
            "beside it are refused (they would change what that master configured)"
        )

    def sdo_client(self, which: str | int) -> Any:
        return _RemoteSdo(self.client, self.slave(which).position)

    def _dictionary_by_sdo_info(self, which: str | int) -> list[dict[str, Any]]:
        raise InspectError("the SDO information service is not asked beside a running master")

    def _describe_on_slave(self, f: FoundSlave, index: int, sub: int) -> ObjectRef:
        """Name and type as the running master's ESI describes the entry, else from the SII."""
        e = self.client.request("entry", position=f.position, index=index, subindex=sub)
        if e is not None and e["data_type"] in dt.BY_CODE:
            return ObjectRef(index, sub, e["name"], dt.BY_CODE[e["data_type"]], e["bit_length"])
        return super()._describe_on_slave(f, index, sub)

    def link_statistics(self, probes: int = 100) -> dict[str, Any]:
        """The running master's own counters (no probe frames are sent beside it)."""
        stats = self.client.request("stats")
        rtt = stats.get("rtt") or {}
        return {
            "interface": self.interface,
            "slaves": len(self.found),
            "master": self.client.owner,
            "round_trip_us": {
                "probes": int(rtt.get("count", 0)),
                "min": float(rtt.get("min", 0)) / 1000.0,
                "median": float(rtt.get("p50", 0)) / 1000.0,
                "max": float(rtt.get("max", 0)) / 1000.0,
            },
            "interface_stats": _interface_counters(self.interface),
            "engine": {k: v for k, v in stats.items() if isinstance(v, int | float)},
        }


class _RemoteSdo:
    """SDO upload and download of one slave, carried out by the running master."""

    def __init__(self, client: OwnerClient, position: int) -> None:
        self.client = client
        self.position = position

    def upload(self, index: int, subindex: int) -> bytes:
        return hex_bytes(
            self.client.request("upload", position=self.position, index=index, subindex=subindex)
        )

    def download(self, index: int, subindex: int, data: bytes) -> None:
        self.client.request(
            "download", position=self.position, index=index, subindex=subindex, data=data.hex()
        )

    def entry_description(self, index: int, subindex: int) -> Any:
        raise InspectError("the SDO information service is not asked beside a running master")


def _interface_counters(interface: str) -> dict[str, Any]:
    """The interface's state and counters from /sys/class/net."""
    sys_stats: dict[str, Any] = {}
    base = Path("/sys/class/net") / interface
    if base.is_dir():
        for name in ("operstate", "mtu", "address", "speed"):
            try:
                sys_stats[name] = (base / name).read_text().strip()
            except OSError:
                continue
        for counter in sorted((base / "statistics").glob("*")):
            try:
                sys_stats[counter.name] = int(counter.read_text())
            except (OSError, ValueError):
                continue
    return sys_stats


def _sync_mailbox_counter(client: Any) -> None:
    """Make sure the slave takes our next mailbox message.

    A slave drops a message whose counter equals the one of the message before (it takes it
    for a repetition). A new process starts counting at 1 again, and the slave may still
    remember 1 from the previous command: the first request would then vanish. A harmless
    read of 0x1000 (device type) with a short timeout, repeated with the next counter until
    the slave answers (with data or an abort: both mean it took the message), settles that.
    """
    saved, client.timeout_s = client.timeout_s, 0.3
    try:
        for _attempt in range(3):
            try:
                client.upload(coe_facts.DEVICE_TYPE, 0)
                return
            except MailboxTimeout:
                continue  # the message may have vanished as a repeat: try the next counter
            except EtherRosError:
                return  # an abort is an answer: the counter was accepted
    finally:
        client.timeout_s = saved


def _check_register(address: int, length: int) -> None:
    if not 0 <= address <= 0xFFFF:
        raise InspectError(f"register address 0x{address:X} is outside 0x0000..0xFFFF")
    if not 1 <= length <= 1024:
        raise InspectError(f"length {length} is outside 1..1024 bytes")
    if address + length > 0x10000:
        raise InspectError(f"0x{address:04X} + {length} bytes runs past 0xFFFF")


def _object_ref(index: int, sub: int, entry: Any, forced: dt.DataType | None) -> ObjectRef:
    if forced is not None:
        return ObjectRef(index, sub, entry.name if entry else "", forced, forced.bit_length)
    if entry is None:
        return ObjectRef(index, sub)
    return ObjectRef(index, sub, entry.name, dt.BY_CODE.get(entry.data_type), entry.bit_length)


def _sii_pdo(p: Any) -> dict[str, Any]:
    return {
        "index": p.index,
        "name": p.name,
        "sm": p.sm,
        "entries": [
            {
                "index": e.index,
                "subindex": e.subindex,
                "bit_length": e.bit_length,
                "name": e.name,
                "type": esi_type_name(e.data_type) or "",
            }
            for e in p.entries
        ],
    }


def _state_entry(name: str, f: FoundSlave, st: AlStatus) -> dict[str, Any]:
    return {
        "position": f.position,
        "name": name,
        "state": st.name,
        "error": st.error,
        "al_status_code": st.code,
        "al_status_text": al_code_text(st.code) if st.error else "",
    }


# ---- ESI from SII ------------------------------------------------------------------------


def esi_from_sii(info: SiiInfo, vendor_name: str = "") -> str:
    """An ETG.2000 EtherCATInfo document describing the device as its SII does."""
    from lxml import etree

    root = etree.Element("EtherCATInfo", Version="1.6")
    vendor = etree.SubElement(root, "Vendor")
    etree.SubElement(vendor, "Id").text = f"#x{info.vendor_id:08X}"
    etree.SubElement(vendor, "Name").text = vendor_name or f"Vendor {info.vendor_id:#x}"
    desc = etree.SubElement(root, "Descriptions")
    group_type = (info.general.group if info.general else "") or "Unknown"
    groups = etree.SubElement(desc, "Groups")
    group = etree.SubElement(groups, "Group")
    etree.SubElement(group, "Type").text = group_type
    etree.SubElement(group, "Name").text = group_type
    devices = etree.SubElement(desc, "Devices")
    dev = etree.SubElement(devices, "Device", Physics=_physics(info))
    order = (info.general.order if info.general else "") or info.name or "device"
    etree.SubElement(
        dev, "Type", ProductCode=f"#x{info.product_code:08X}", RevisionNo=f"#x{info.revision:08X}"
    ).text = order
    etree.SubElement(dev, "Name").text = info.name or order
    etree.SubElement(dev, "GroupType").text = group_type
    for fmmu in info.fmmus:
        etree.SubElement(dev, "Fmmu").text = fmmu
    for sm in info.sync_managers:
        etree.SubElement(
            dev,
            "Sm",
            StartAddress=f"#x{sm.start:04X}",
            ControlByte=f"#x{sm.control:02X}",
            DefaultSize=str(sm.length),
            Enable=str(1 if sm.enable & 1 else 0),
        ).text = sm.role
    for tag, pdos in (("RxPdo", info.rx_pdos), ("TxPdo", info.tx_pdos)):
        for p in pdos:
            attrs = {"Fixed": "1"}
            if p.sm != 0xFF:
                attrs["Sm"] = str(p.sm)
            el = etree.SubElement(dev, tag, attrs)
            etree.SubElement(el, "Index").text = f"#x{p.index:04X}"
            etree.SubElement(el, "Name").text = p.name
            for e in p.entries:
                entry = etree.SubElement(el, "Entry")
                etree.SubElement(entry, "Index").text = f"#x{e.index:04X}"
                if e.index:
                    etree.SubElement(entry, "SubIndex").text = str(e.subindex)
                etree.SubElement(entry, "BitLen").text = str(e.bit_length)
                if e.index:
                    etree.SubElement(entry, "Name").text = e.name
                    etree.SubElement(entry, "DataType").text = esi_type_name(e.data_type) or "USINT"
    if info.mailbox[1] and info.mailbox[3]:
        mbx = etree.SubElement(dev, "Mailbox")
        if info.mailbox_protocols & 0x04:
            details = info.general.coe_details if info.general else 0
            flags = (
                ("SdoInfo", 0x02),
                ("PdoAssign", 0x04),
                ("PdoConfig", 0x08),
                ("PdoUpload", 0x10),
                ("CompleteAccess", 0x20),
            )
            attrs = {name: "1" for name, bit in flags if details & bit}
            etree.SubElement(mbx, "CoE", attrs)
        if info.mailbox_protocols & 0x08:
            etree.SubElement(mbx, "FoE")
        if info.mailbox_protocols & 0x02:
            etree.SubElement(mbx, "EoE")
    if info.dc:
        dc = etree.SubElement(dev, "Dc")
        for mode in info.dc:
            op = etree.SubElement(dc, "OpMode")
            etree.SubElement(op, "Name").text = mode.name or "DC"
            etree.SubElement(op, "Desc").text = mode.description or mode.name or "DC"
            etree.SubElement(op, "AssignActivate").text = f"#x{mode.assign_activate:04X}"
            sync0 = etree.SubElement(op, "CycleTimeSync0", Factor=str(mode.sync0_cycle_factor))
            sync0.text = str(mode.cycle_time_sync0)
            etree.SubElement(op, "ShiftTimeSync0").text = str(mode.shift_time_sync0)
    eeprom = etree.SubElement(dev, "Eeprom")
    etree.SubElement(eeprom, "ByteSize").text = str(info.eeprom_bytes or 2048)
    config = struct.pack("<HHHH", info.pdi_control, info.pdi_config, 0, 0)
    etree.SubElement(eeprom, "ConfigData").text = config.hex().upper()
    return etree.tostring(root, pretty_print=True, xml_declaration=True, encoding="utf-8").decode()


def _physics(info: SiiInfo) -> str:
    if info.general is None:
        return "YY"
    letters = {1: "Y", 3: "K"}  # MII, EBUS
    out = ""
    for p in range(4):
        kind = (info.general.physical_ports >> (4 * p)) & 0xF
        if kind == 0:
            break
        out += letters.get(kind, "Y")
    return out or "YY"
